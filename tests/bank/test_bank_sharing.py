"""Several processes share one bank directory (mwbx/bank/saving.py,
mwbx/bank/runs.py): a stale save keeps what others appended, concurrent
`mwbx sample` and `mwbx refine` runs get distinct ids and lose nothing, a
live run is never resumed by another, a scene-version save never deletes
others' worlds nor leaves the path without a bank; a full disk, a corrupt
shard and a crafted manifest end in one clear message. The writers are real
processes (`python -m mwbx.cli ...`), started together."""

from __future__ import annotations

import copy
import dataclasses
import fcntl
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.bank import shards
from mwbx.errors import MwbxError

REPO = pathlib.Path(__file__).resolve().parents[2]
TINY = REPO / "tests" / "scenes" / "tiny.yaml"
QUERY = ("camera: {eye: [0, -3, 1], target: [0, 0, 0.4], up: [0, 0, 1], fovy: 60, aspect: 1}\n"
         "queries:\n  - {box: [0, 0, 1, 1], bodies: [ball]}\n")


def _mwbx(*args: str) -> list[str]:
  return [sys.executable, "-m", "mwbx.cli", *args]


def _sample_argv(out, worlds: int, chunk: int = 4) -> list[str]:
  return _mwbx("sample", str(TINY), "--worlds", str(worlds), "--chunk-size", str(chunk), "--backend", "native",
               "--out", str(out))


def _together(argvs, timeout=1200):
  """Runs the commands as concurrent processes; their (returncode, stdout, stderr)."""
  procs = [subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for a in argvs]
  try:
    return [_finish(p, timeout) for p in procs]
  finally:
    for p in procs:
      if p.poll() is None:
        p.kill()
        p.wait()


def _finish(proc, timeout):
  out, err = proc.communicate(timeout=timeout)
  return proc.returncode, out, err


def _manifest(path):
  return json.loads((pathlib.Path(path) / "manifest.json").read_text())


@pytest.fixture
def small_bank(tiny_native, tmp_path):
  """A saved bank of 4 worlds of tests/scenes/tiny.yaml (ids 0..3), in two shards."""
  out = tmp_path / "bank"
  bank, _ = tiny_native.run(4, jax.random.key(0))
  bank._take(np.arange(2)).save(out)
  bank.save(out)
  return out


def test_a_stale_save_keeps_the_worlds_another_process_appended(small_bank):
  stale = mwbx.Bank.load(small_bank)  # e.g. open in `mwbx browse`
  done = subprocess.run(_sample_argv(small_bank, 8), capture_output=True, text=True, timeout=1200)
  assert done.returncode == 0, done.stderr
  assert mwbx.Bank.load(small_bank).n_worlds == 12
  stale.save(small_bank)  # what *Save bank* does
  assert sorted(mwbx.Bank.load(small_bank).world_ids.tolist()) == list(range(12))
  assert _manifest(small_bank)["dropped"] == []
  # A drop drops only what it was asked to.
  stale.drop([1]).save(small_bank)
  kept = mwbx.Bank.load(small_bank)
  assert sorted(kept.world_ids.tolist()) == [0] + list(range(2, 12))
  assert _manifest(small_bank)["dropped"] == [1]


def test_new_worlds_whose_ids_another_writer_took_are_renumbered(small_bank, tiny_native):
  stale = mwbx.Bank.load(small_bank)
  other = mwbx.Bank.load(small_bank)
  more, _ = tiny_native.run(2, jax.random.key(5))
  ours = stale.append(more)  # ids 4, 5
  theirs = other.append(more)  # ids 4, 5 too
  theirs.save(small_bank)
  saved = ours.save(small_bank)
  assert saved.world_ids.tolist()[-2:] == [6, 7]  # the bank returned says what is on disk
  bank = mwbx.Bank.load(small_bank)
  assert sorted(bank.world_ids.tolist()) == list(range(8))
  np.testing.assert_array_equal(bank.qpos_frames(6), bank.qpos_frames(4))  # the same draws, twice
  saved.save(small_bank)  # nothing new: nothing written again
  assert mwbx.Bank.load(small_bank).n_worlds == 8


def _state(bank):
  return (bank.world_ids.tolist(), bank.parent_world.tolist(), sorted(bank.lineage), bank.next_id,
          bank.origin and (bank.origin.path, bank.origin.ids.tolist()))


def _shards(path):
  return [e["name"] for e in _manifest(path)["shards"]]


def test_saving_returns_the_bank_as_saved_and_leaves_the_bank_as_it_was(small_bank, tiny_native):
  # Saving renumbered, and moved next_id and the origin of, the bank it was given.
  more, _ = tiny_native.run(2, jax.random.key(5))
  other = mwbx.Bank.load(small_bank).append(more)  # ids 4, 5
  mine = mwbx.Bank.load(small_bank).append(more)  # ids 4, 5 too
  mine = mine.append(mine._take(np.array([4, 5])))  # 6, 7: made children of 4 and 5
  mine = dataclasses.replace(mine, parent_world=np.array([-1] * 6 + [4, 5]),
                             lineage={"6": {"parent": 4}, "7": {"parent": 5}})
  before = _state(mine)
  first = other.save(small_bank)
  assert _state(other)[:4] == ([0, 1, 2, 3, 4, 5], [-1] * 6, [], 6)
  assert first.origin.ids.tolist() == list(range(6)) and first.next_id == 6
  saved = mine.save(small_bank)  # 4..7 are taken: renumbered 6..9
  assert _state(mine) == before
  assert saved.world_ids.tolist() == list(range(4)) + [6, 7, 8, 9] and saved.next_id == 10
  assert saved.parent_world.tolist()[-2:] == [6, 7] and saved.lineage["8"] == {"parent": 6}
  assert saved.origin.path == str(small_bank) and saved.origin.ids.tolist() == list(range(4)) + [6, 7, 8, 9]
  loaded = mwbx.Bank.load(small_bank)
  assert sorted(loaded.world_ids.tolist()) == list(range(10)) and loaded.lineage["9"] == {"parent": 7}
  shards = _shards(small_bank)
  # Saving either bank again writes nothing: the first save's worlds are found on disk.
  assert _state(saved.save(small_bank)) == _state(saved)
  again = mine.save(small_bank)
  assert _state(again) == _state(saved) and _state(mine) == before
  assert _shards(small_bank) == shards and mwbx.Bank.load(small_bank).n_worlds == 10
  # A bank made from the original writes only its own new worlds.
  grown = mine.append(more).save(small_bank)
  assert grown.world_ids.tolist()[-6:] == [6, 7, 8, 9, 10, 11] and mwbx.Bank.load(small_bank).n_worlds == 12
  # A bank sampled elsewhere, its ids taken there: renumbered once, however often it is saved.
  fresh, _ = tiny_native.run(2, jax.random.key(9))
  ids = fresh.world_ids.tolist()
  placed = fresh.save(small_bank)
  assert fresh.world_ids.tolist() == ids == [0, 1] and fresh.origin is None
  assert placed.world_ids.tolist() == [12, 13] and fresh.save(small_bank).world_ids.tolist() == [12, 13]
  assert mwbx.Bank.load(small_bank).n_worlds == 14


def test_a_save_changes_no_field_of_the_bank_and_marks_its_shard_on_disk(small_bank, tiny_native):
  # Saving recorded what it wrote in a memo inside the bank it was given.
  more, _ = tiny_native.run(2, jax.random.key(5))
  mine = mwbx.Bank.load(small_bank).append(more)  # ids 4, 5
  mwbx.Bank.load(small_bank).append(more).save(small_bank)  # another writer takes 4, 5 first
  before = {f.name: getattr(mine, f.name) for f in dataclasses.fields(mine)}
  contents = {name: copy.deepcopy(value) for name, value in before.items() if isinstance(value, (dict, list))}
  saved = mine.save(small_bank)
  for name, value in before.items():
    assert getattr(mine, name) is value, name
  for name, value in contents.items():
    assert getattr(mine, name) == value, name
  assert saved.world_ids.tolist() == [0, 1, 2, 3, 6, 7] and saved.save_token != mine.save_token
  assert saved.origin.renamed == {4: 6, 5: 7} and [saved.origin.id_on_disk(i) for i in (0, 4, 5)] == [0, 6, 7]
  assert mwbx.Bank.load(small_bank).origin.renamed == {}
  mark = _manifest(small_bank)["shards"][-1]["saved_by"]
  assert mark == {"token": mine.save_token, "renumbered": [[6, 4], [7, 5]]}
  # The record is the directory's: a bank of the same family finds its worlds there, another does not.
  family = mine.append(more)
  assert family.save(small_bank).world_ids.tolist() == [0, 1, 2, 3, 6, 7, 8, 9]
  stranger = dataclasses.replace(mine, save_token="another")
  assert stranger.save(small_bank).world_ids.tolist()[-2:] == [10, 11]
  assert mwbx.Bank.load(small_bank).n_worlds == 12
  # A crafted mark is named in one line.
  manifest = _manifest(small_bank)
  manifest["shards"][-1]["saved_by"] = {"token": 3}
  (small_bank / "manifest.json").write_text(json.dumps(manifest))
  with pytest.raises(MwbxError, match=r"shards\[\d+\]\.saved_by: .* is not a save's mark") as err:
    mwbx.Bank.load(small_bank)
  assert "\n" not in str(err.value)


def test_two_sampling_runs_started_together_get_distinct_ids(tmp_path):
  out = tmp_path / "bank"
  results = _together([_sample_argv(out, 8), _sample_argv(out, 8)])
  for rc, _, err in results:
    assert rc == 0, err
    assert "resuming" not in err
  bank = mwbx.Bank.load(out)
  assert sorted(bank.world_ids.tolist()) == list(range(16))
  runs = _manifest(out)["runs"]
  assert len(runs) == 2 and all(r["finished"] and not r.get("superseded") for r in runs)
  assert not any((out / "runs").iterdir())  # liveness locks go with their runs


def test_a_live_run_is_not_resumed_by_another(small_bank):
  long = subprocess.Popen(_sample_argv(small_bank, 40, chunk=2), stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
  try:
    deadline = time.monotonic() + 900
    while time.monotonic() < deadline and long.poll() is None:  # mid-run: a shard written, more to come
      if len(_manifest(small_bank)["shards"]) > 2:
        break
      time.sleep(0.01)
    # Paused (alive, its worlds unfinished) for as long as the second run takes; never inside
    # a manifest update (the bank's lock held here), which would hold the second run up.
    with open(small_bank / ".lock", "a+b") as lock:
      fcntl.flock(lock, fcntl.LOCK_EX)
      os.kill(long.pid, signal.SIGSTOP)
      fcntl.flock(lock, fcntl.LOCK_UN)
    assert long.poll() is None, "the long run finished before the second one started"
    assert sum(e["worlds"] for e in _manifest(small_bank)["shards"]) < 44
    short = subprocess.run(_sample_argv(small_bank, 4), capture_output=True, text=True, timeout=1200)
    assert short.returncode == 0, short.stderr
    assert "resuming" not in short.stderr and "sampling 4 worlds" in short.stderr
    os.kill(long.pid, signal.SIGCONT)
    rc, _, err = _finish(long, 1200)
    assert rc == 0, err
  finally:
    if long.poll() is None:
      os.kill(long.pid, signal.SIGCONT)
      long.kill()
      long.wait()
  bank = mwbx.Bank.load(small_bank)
  assert sorted(bank.world_ids.tolist()) == list(range(4 + 40 + 4))
  assert not any(r.get("superseded") for r in _manifest(small_bank)["runs"])


def test_a_killed_run_is_resumed_once_its_process_is_gone(small_bank):
  argv = _sample_argv(small_bank, 40, chunk=2)
  proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
  try:
    deadline = time.monotonic() + 900
    while time.monotonic() < deadline and proc.poll() is None:
      if len(_manifest(small_bank)["shards"]) > 2:
        break
      time.sleep(0.01)
    proc.kill()
    proc.wait()
  finally:
    if proc.poll() is None:
      proc.kill()
  # What a process killed while writing a shard leaves (SIGKILL skips its clean-up).
  left = small_bank / "shards" / ".tmp-0123456789abcdef"
  left.mkdir(exist_ok=True)
  (left / "world_ids.npy").write_bytes(b"half")
  again = subprocess.run(argv, capture_output=True, text=True, timeout=1200)
  assert again.returncode == 0, again.stderr
  assert "resuming" in again.stderr
  assert sorted(mwbx.Bank.load(small_bank).world_ids.tolist()) == list(range(44))
  assert not list((small_bank / "shards").glob(".tmp-*"))


def test_two_refinements_of_one_bank_at_once_are_both_saved(small_bank):
  argv = lambda seed: _mwbx("refine", str(small_bank), "--world", "0", "--objects", "ball", "--time", "0.3",
                            "--samples", "2", "--seed", str(seed), "--backend", "native")
  results = _together([argv(1), argv(2)])
  printed = []
  for rc, out, err in results:
    assert rc == 0, err
    line = next(x for x in out.splitlines() if x.startswith("refined worlds"))
    first, last = line.split("(ids ")[1].split(",")[0].split("..")
    printed.append((int(first), int(last)))
  bank = mwbx.Bank.load(small_bank)
  assert sorted(bank.world_ids.tolist()) == list(range(8))
  assert sorted(printed) == [(4, 5), (6, 7)]  # each process printed the ids its worlds have on disk
  assert bank.children(0).tolist() == [4, 5, 6, 7]
  for wid in range(4, 8):
    assert bank.lineage[str(wid)]["parent"] == 0


def _version_config(tmp_path) -> pathlib.Path:
  """A later version of tests/scenes/tiny.yaml: a third body after the others."""
  xml = (REPO / "tests" / "scenes" / "tiny.xml").read_text().replace(
      "  </worldbody>", '    <body name="lid" pos="0.8 0.6 0.3">\n      <freejoint/>\n'
      '      <geom type="box" size="0.05 0.05 0.02" mass="0.1"/>\n    </body>\n  </worldbody>')
  (tmp_path / "tiny_lid.xml").write_text(xml)
  config = TINY.read_text().replace("mjcf: tiny.xml", "mjcf: tiny_lid.xml")
  (tmp_path / "tiny_lid.yaml").write_text(config)
  return tmp_path / "tiny_lid.yaml"


def test_a_scene_version_save_never_deletes_worlds_appended_since_the_load(small_bank, tmp_path):
  scene = mwbx.Scene(mwbx.load_config(_version_config(tmp_path)))
  stale = mwbx.Bank.load(small_bank).with_scene(scene)
  done = subprocess.run(_sample_argv(small_bank, 4), capture_output=True, text=True, timeout=1200)
  assert done.returncode == 0, done.stderr
  with pytest.raises(MwbxError, match=r"worlds 4, 5, 6, 7 were added by another process.*nothing was written"):
    stale.save(small_bank)
  assert sorted(mwbx.Bank.load(small_bank).world_ids.tolist()) == list(range(8))


def test_a_scene_version_save_keeps_a_bank_at_the_path_throughout(small_bank, tmp_path, monkeypatch):
  scene = mwbx.Scene(mwbx.load_config(_version_config(tmp_path)))
  bank = mwbx.Bank.load(small_bank).with_scene(scene)
  # A reader process polling the path all along, and a check after every rename this process makes.
  stop = tmp_path / "stop"
  reader = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
      import os, sys
      missing = seen = 0
      while not os.path.exists({str(stop)!r}):
        seen += 1
        missing += not os.path.exists({str(small_bank / 'manifest.json')!r})
      print(missing, seen)
      """)], stdout=subprocess.PIPE, text=True)
  gaps = []
  for name in ("rename", "replace"):
    real = getattr(os, name)

    def checked(a, b, *args, _real=real, **kwargs):
      _real(a, b, *args, **kwargs)
      if not (small_bank / "manifest.json").exists():
        gaps.append((a, b))
    monkeypatch.setattr(os, name, checked)
  try:
    time.sleep(0.5)
    bank.save(small_bank)
  finally:
    monkeypatch.undo()
    stop.write_text("")
    out, _ = reader.communicate(timeout=120)
  assert gaps == []
  missing, seen = map(int, out.split())
  assert seen > 0 and missing == 0
  again = mwbx.Bank.load(small_bank)
  assert again.digest == scene.digest and sorted(again.world_ids.tolist()) == [0, 1, 2, 3]
  assert not [p for p in small_bank.parent.iterdir() if p.name.startswith(".bank.")]  # nothing left beside it


def test_a_full_disk_is_one_line_and_the_next_run_resumes(tmp_path):
  out = tmp_path / "bank"
  argv = ["sample", str(TINY), "--worlds", "8", "--chunk-size", "2", "--backend", "native", "--out", str(out)]
  # ENOSPC injected at the write of the second shard's arrays (no small file system to fill here).
  script = textwrap.dedent(f"""
      import errno, os, sys
      import numpy as np
      from mwbx import cli
      real, folders = np.save, set()
      def save(file, *args, **kwargs):
        folders.add(os.path.dirname(getattr(file, "name", "")))
        if len(folders) > 1:
          raise OSError(errno.ENOSPC, "No space left on device")
        return real(file, *args, **kwargs)
      np.save = save
      sys.exit(cli.main({argv!r}))
      """)
  full = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=1200)
  assert full.returncode == 2, full.stderr
  assert "Traceback" not in full.stderr
  errors = [line for line in full.stderr.splitlines() if "error" in line]
  assert len(errors) == 1 and "no space left on device" in errors[0] and "run the same command" in errors[0]
  assert not [p.name for p in (out / "shards").iterdir() if p.name.startswith(".")]
  saved = mwbx.Bank.load(out).n_worlds
  assert 0 < saved < 8
  again = subprocess.run(_mwbx(*argv), capture_output=True, text=True, timeout=1200)
  assert again.returncode == 0, again.stderr
  assert f"resuming: {saved} of 8 worlds done" in again.stderr
  assert sorted(mwbx.Bank.load(out).world_ids.tolist()) == list(range(8))


def test_a_failed_manifest_write_leaves_no_shard_behind(tmp_path):
  # The third chunk's shard was renamed into place, then its manifest write failed (a full disk): the
  # folder stayed, in no manifest.
  out = tmp_path / "bank"
  argv = ["sample", str(TINY), "--worlds", "8", "--chunk-size", "2", "--backend", "native", "--out", str(out)]
  script = textwrap.dedent(f"""
      import errno, sys
      from mwbx import cli, files
      real, calls = files.write_atomic, [0]
      def write_atomic(path, data, what="file"):
        if what == "bank manifest":
          calls[0] += 1
          if calls[0] == 4:  # the run's record, two shards, then the third shard's manifest
            raise files.MwbxError(f"{{path}}: cannot write {{what}} (no space left on device)")
        return real(path, data, what)
      files.write_atomic = write_atomic
      sys.exit(cli.main({argv!r}))
      """)
  full = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=1200)
  assert full.returncode == 2 and "Traceback" not in full.stderr, full.stderr
  errors = [line for line in full.stderr.splitlines() if "error" in line]
  assert len(errors) == 1 and "4 worlds of this run are saved" in errors[0], errors
  manifest = _manifest(out)
  assert sorted(p.name for p in (out / "shards").iterdir()) == sorted(e["name"] for e in manifest["shards"])
  assert mwbx.Bank.load(out).n_worlds == 4
  again = subprocess.run(_mwbx(*argv), capture_output=True, text=True, timeout=1200)
  assert again.returncode == 0, again.stderr
  assert "resuming: 4 of 8 worlds done" in again.stderr
  assert sorted(mwbx.Bank.load(out).world_ids.tolist()) == list(range(8))


def test_a_shard_in_no_manifest_is_removed_at_the_next_write(small_bank):
  # A writer killed between renaming its shard into place and its manifest write.
  orphan = small_bank / "shards" / "00007"
  shutil.copytree(small_bank / "shards" / "00001", orphan)
  shards.BankDirectory(small_bank).append_run({"id": "r", "seed": 0, "id_ranges": [], "finished": True})
  assert not orphan.exists() and (small_bank / "shards" / "00001").exists()
  assert mwbx.Bank.load(small_bank).n_worlds == 4


def test_commands_open_a_bank_with_a_corrupt_shard_with_skip_corrupt(small_bank, tmp_path, capsys):
  flags = small_bank / "shards" / "00000" / "flags.npy"
  flags.write_bytes(flags.read_bytes()[:20])  # truncated
  assert cli.main(["info", str(small_bank)]) == 2
  assert "--skip-corrupt" in capsys.readouterr().err
  assert cli.main(["info", str(small_bank), "--skip-corrupt"]) == 0
  captured = capsys.readouterr()
  assert "skipped corrupt shards 00000 (worlds 0..1)" in captured.err
  assert "worlds              2 " in captured.out
  queries = tmp_path / "q.yaml"
  queries.write_text(QUERY)
  assert cli.main(["query", str(small_bank), str(queries), "--json", "--skip-corrupt"]) == 0
  captured = capsys.readouterr()
  assert "skipped corrupt shards 00000" in captured.err
  report = json.loads(captured.out)
  assert report["valid_worlds"] == 2 and {w["world"] for w in report["worlds"]} <= {2, 3}
  # A drop from the partial bank keeps the corrupt shard's worlds in the manifest.
  assert cli.main(["drop", str(small_bank), "3", "--skip-corrupt"]) == 0
  manifest = _manifest(small_bank)
  assert manifest["dropped"] == [3] and manifest["shards"][0]["id_ranges"] == [[0, 1]]


def test_info_verify_skip_corrupt_names_every_corrupt_shard(tiny_native, tmp_path, capsys):
  # --verify stopped at the first corrupt shard, even with --skip-corrupt.
  out = tmp_path / "bank"
  bank, _ = tiny_native.run(6, jax.random.key(0))
  for n in (2, 4, 6):
    bank._take(np.arange(n)).save(out)
  assert sorted(p.name for p in (out / "shards").iterdir()) == ["00000", "00001", "00002"]
  flags = out / "shards" / "00000" / "flags.npy"
  flags.write_bytes(flags.read_bytes()[:20])  # truncated: found when the bank opens
  qpos = out / "shards" / "00002" / "qpos_data.npy"
  data = bytearray(qpos.read_bytes())
  data[-1] ^= 0xFF  # one flipped byte: found only by --verify
  qpos.write_bytes(bytes(data))
  assert cli.main(["info", str(out), "--verify"]) == 2
  err = capsys.readouterr().err
  assert "2 corrupt shards" in err and "00000" in err and "00002" in err and len(err.strip().splitlines()) == 1
  assert cli.main(["info", str(out), "--verify", "--skip-corrupt"]) == 1
  captured = capsys.readouterr()
  assert "2 corrupt shards" in captured.err and "00000" in captured.err and "00002" in captured.err
  assert "worlds              2 " in captured.out and "world ids           2..3" in captured.out


def test_duplicate_world_ids_on_disk_are_named_at_load(small_bank):
  manifest = _manifest(small_bank)
  shutil.copytree(small_bank / "shards" / "00000", small_bank / "shards" / "00002")
  manifest["shards"].append(dict(manifest["shards"][0], name="00002"))
  (small_bank / "manifest.json").write_text(json.dumps(manifest))
  with pytest.raises(MwbxError, match=r"world ids 0, 1 are stored more than once \(shards 00000, 00002\)"):
    mwbx.Bank.load(small_bank)


@pytest.mark.parametrize("kind", ["absolute", "dotdot"])
def test_a_manifest_cannot_make_loading_read_outside_the_bank(small_bank, tmp_path, kind):
  outside = tmp_path / "elsewhere"
  shutil.copytree(small_bank / "shards" / "00001", outside)
  manifest = _manifest(small_bank)
  manifest["shards"][1]["name"] = str(outside) if kind == "absolute" else "../../elsewhere"
  (small_bank / "manifest.json").write_text(json.dumps(manifest))
  with pytest.raises(MwbxError, match=r"manifest.json: shards\[1\].name: .* is not a shard name"):
    mwbx.Bank.load(small_bank)


def test_a_crafted_run_id_is_refused_and_removes_nothing(small_bank, tmp_path):
  # A run's id names its lock file, which a later run unlinked: "../../x" reached outside the bank.
  victim = tmp_path / "victimdir" / "victim.lock"
  victim.parent.mkdir()
  victim.write_text("x")
  manifest = _manifest(small_bank)
  manifest["runs"].append({"id": "../../victimdir/victim", "seed": 0, "finished": False,
                           "id_ranges": [[100, 101]]})
  (small_bank / "manifest.json").write_text(json.dumps(manifest))
  done = subprocess.run(_sample_argv(small_bank, 2), capture_output=True, text=True, timeout=1200)
  assert done.returncode == 2 and "is not a run id" in done.stderr, done.stderr
  assert len(done.stderr.strip().splitlines()) == 1 and victim.exists()


def test_a_bank_sampled_elsewhere_keeps_its_worlds_when_saved_over_the_same_ids(small_bank, tiny_native):
  # Worlds with stored ids were taken to be the stored worlds: other worlds were silently not written.
  again, _ = tiny_native.run(4, jax.random.key(0))  # the stored worlds themselves
  again.save(small_bank)
  assert sorted(mwbx.Bank.load(small_bank).world_ids.tolist()) == [0, 1, 2, 3]
  other, _ = tiny_native.run(2, jax.random.key(9))  # ids 0 and 1 again, other worlds
  saved = other.save(small_bank)
  loaded = mwbx.Bank.load(small_bank)
  assert sorted(loaded.world_ids.tolist()) == [0, 1, 2, 3, 4, 5] and saved.world_ids.tolist() == [4, 5]
  np.testing.assert_array_equal(loaded.qpos_frames(4), saved.qpos_frames(4))
  np.testing.assert_array_equal(loaded.qpos_frames(0), again.qpos_frames(0))


def _plant_include(small_bank, tmp_path) -> pathlib.Path:
  """Rewrites the bank's stored MJCF to include a file outside the bank (a crafted manifest)."""
  planted = tmp_path / "planted.xml"
  planted.write_text('<mujoco><worldbody><body name="planted"><geom size="0.1"/></body></worldbody></mujoco>')
  manifest = _manifest(small_bank)
  text = manifest["scene"]["mjcf_text"]
  manifest["scene"]["mjcf_text"] = text.replace("<worldbody>", f'<include file="{planted}"/>\n  <worldbody>', 1)
  (small_bank / "manifest.json").write_text(json.dumps(manifest))
  return planted


def test_a_bank_model_is_built_only_from_the_text_it_stores(small_bank, tmp_path):
  _plant_include(small_bank, tmp_path)
  bank = mwbx.Bank.load(small_bank)
  with pytest.raises(MwbxError, match=r"includes '.*planted.xml', which is not stored with it"):
    bank.model


def test_refine_never_reads_a_file_a_crafted_bank_includes(small_bank, tmp_path, capsys):
  # refine built its scene from the stored text without the check Bank.model makes, and opened the file.
  # First the bank as sampled: its scene is kept for later refinements, and the crafted bank below claims
  # the same digest, so a scene kept by digest would be reused unchecked.
  mwbx.refine(mwbx.Bank.load(small_bank), 0, "ball", t_min=0.1, n_samples=2, key=jax.random.key(1), backend="native")
  _plant_include(small_bank, tmp_path)
  bank = mwbx.Bank.load(small_bank)
  with pytest.raises(MwbxError, match=r"includes '.*planted.xml', which is not stored with it"):
    mwbx.refine(bank, 0, "ball", t_min=0.1, n_samples=2, key=jax.random.key(1), backend="native")
  assert cli.main(["refine", str(small_bank), "--world", "0", "--objects", "ball", "--time", "0.1", "--samples", "2"]) == 2
  err = capsys.readouterr().err
  assert "planted.xml" in err and "not stored with it" in err and len(err.strip().splitlines()) == 1, err
  assert mwbx.Bank.load(small_bank).n_worlds == 4


def _torn_reads(path: pathlib.Path, parse: str, stop: pathlib.Path):
  """A process reading ``path`` in a loop until ``stop`` exists; prints torn reads and reads."""
  return subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
      import json, os, yaml
      torn = reads = 0
      while not os.path.exists({str(stop)!r}):
        try:
          text = open({str(path)!r}).read()
        except FileNotFoundError:
          continue
        reads += 1
        try:
          ok = bool({parse}(text))
        except Exception:
          ok = False
        torn += not ok
      print(torn, reads)
      """)], stdout=subprocess.PIPE, text=True)


def test_query_files_and_the_resolved_config_are_never_seen_half_written(small_bank, tmp_path):
  from mwbx.queries import load_queries
  bank = mwbx.Bank.load(small_bank)
  queries = load_queries(_write(tmp_path / "in.yaml", QUERY), bank=bank)
  target = tmp_path / "saved.yaml"
  queries.save(target)
  config = small_bank / "config.resolved.json"
  stop = tmp_path / "stop"
  readers = [_torn_reads(target, "yaml.safe_load", stop), _torn_reads(config, "json.loads", stop)]
  try:
    time.sleep(0.5)
    for _ in range(300):
      queries.save(target)
      bank.save(small_bank)  # nothing new: rewrites config.resolved.json and scene.xml only
  finally:
    stop.write_text("")
    counts = [r.communicate(timeout=120)[0].split() for r in readers]
  for torn, reads in counts:
    assert int(reads) > 0 and int(torn) == 0
  assert not [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name]


def _write(path: pathlib.Path, text: str) -> pathlib.Path:
  path.write_text(text)
  return path
