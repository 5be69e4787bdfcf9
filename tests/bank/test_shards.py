"""Banks as append-only shards: a killed run loses at most the chunk in flight
and resumes to the same worlds; appends write only the new shard; one corrupt
shard is named and the others stay readable; banks of the orbax format load."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli

REPO = pathlib.Path(__file__).resolve().parents[2]
TINY = REPO / "tests" / "refine_scenes" / "tiny.yaml"


def same_worlds(a, b):
  """Bit-identical worlds, ids and order included."""
  assert a.world_ids.tolist() == b.world_ids.tolist()
  for name in mwbx.Bank.ROW_ARRAYS:
    np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
  for i in a.world_ids:
    np.testing.assert_array_equal(a.qpos_frames(int(i)), b.qpos_frames(int(i)))


def _manifest(path):
  return json.loads((path / "manifest.json").read_text())


def test_killed_run_resumes_to_the_same_bank(tmp_path):
  out = tmp_path / "bank"
  argv = [sys.executable, "-m", "mwbx.cli", "sample", str(TINY), "--worlds", "64", "--chunk-size", "2",
          "--backend", "native", "--out", str(out)]
  proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
  try:
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and proc.poll() is None:
      if (out / "manifest.json").exists() and _manifest(out)["shards"]:
        break
      time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)  # no chance to clean up
    proc.wait(timeout=600)
  finally:
    if proc.poll() is None:
      proc.kill()
  manifest = _manifest(out)
  assert not manifest["runs"][-1]["finished"], "the run finished before it could be killed"
  saved = sum(entry["worlds"] for entry in manifest["shards"])
  assert 0 < saved < 64
  partial = mwbx.Bank.load(out)  # what was written is a readable bank
  assert partial.n_worlds == saved
  again = subprocess.run(argv, capture_output=True, text=True, timeout=1200)
  assert again.returncode == 0, again.stderr
  assert f"resuming: {saved} of 64 worlds done" in again.stderr
  resumed = mwbx.Bank.load(out)
  runs = _manifest(out)["runs"]  # the killed run, taken over by the resuming one
  assert len(runs) == 2 and runs[0]["superseded"] and all(r["finished"] for r in runs)
  whole = mwbx.sample(mwbx.load_config(TINY), 64, jax.random.key(0), backend="native")
  order = np.argsort(resumed.world_ids)
  same_worlds(resumed._take(order), whole)
  # once finished, the same command appends a new run
  more = subprocess.run(argv[:6] + ["4"] + argv[7:], capture_output=True, text=True, timeout=1200)
  assert more.returncode == 0, more.stderr
  assert mwbx.Bank.load(out).world_ids.max() == 67


def test_interrupt_keeps_finished_chunks(tmp_path, capsys, monkeypatch):
  out = tmp_path / "bank"
  real = mwbx.Sampler.run_chunks

  def interrupted(self, *args, **kwargs):  # Ctrl-C after the second chunk
    for k, item in enumerate(real(self, *args, **kwargs)):
      if k == 2:
        raise KeyboardInterrupt
      yield item

  monkeypatch.setattr(mwbx.Sampler, "run_chunks", interrupted)
  argv = ["sample", str(TINY), "--worlds", "10", "--chunk-size", "2", "--backend", "native", "--out", str(out)]
  assert cli.main(argv) == 130
  assert "4 worlds of this run are saved" in capsys.readouterr().err
  assert mwbx.Bank.load(out).n_worlds == 4
  monkeypatch.setattr(mwbx.Sampler, "run_chunks", real)
  assert cli.main(argv) == 0
  assert "resuming: 4 of 10 worlds done" in capsys.readouterr().err
  assert mwbx.Bank.load(out).world_ids.tolist() == list(range(10))


def test_append_writes_only_the_new_shard(tmp_path):
  config = mwbx.load_config(TINY)
  bank = mwbx.sample(config, 6, jax.random.key(0), backend="native")
  path = tmp_path / "bank"
  bank.save(path)
  first = {f: (f.stat().st_ino, f.stat().st_mtime_ns) for f in (path / "shards").rglob("*.npy")}
  more = mwbx.sample(config, 3, jax.random.key(0), first_world=bank.next_world_id, backend="native")
  bank.append(more).save(path)
  after = {f: (f.stat().st_ino, f.stat().st_mtime_ns) for f in (path / "shards").rglob("*.npy")}
  assert all(after[f] == stamp for f, stamp in first.items())  # old shard untouched
  assert sorted(p.name for p in (path / "shards").iterdir()) == ["00000", "00001"]
  new_files = set(after) - set(first)
  assert new_files and all("00001" in str(f) for f in new_files)
  same_worlds(mwbx.Bank.load(path), bank.append(more))


def test_one_corrupt_shard_is_named_and_the_others_stay_readable(tmp_path, capsys):
  config = mwbx.load_config(TINY)
  bank = mwbx.sample(config, 6, jax.random.key(0), backend="native", chunk_size=2)
  path = tmp_path / "bank"
  bank.save(path)
  more = mwbx.sample(config, 2, jax.random.key(0), first_world=6, backend="native")
  bank.append(more).save(path)
  target = path / "shards" / "00000" / "metrics.npy"
  data = bytearray(target.read_bytes())
  data[-3] ^= 0x10  # one bit in the data, not the header
  target.write_bytes(bytes(data))
  with pytest.raises(mwbx.MwbxError, match=r"shards/00000: corrupt bank: checksum mismatch in metrics"):
    mwbx.Bank.load(path)
  rest = mwbx.Bank.load(path, skip_corrupt=True)
  assert rest.world_ids.tolist() == [6, 7] and rest.run["corrupt_shards"] == ["00000"]
  same_worlds(rest, more)
  assert cli.main(["info", str(path)]) == 2
  err = capsys.readouterr().err
  assert "shards/00000" in err and "metrics" in err and err.count("\n") == 1


def test_banks_of_the_orbax_format_still_load(tmp_path):
  """A format-2 bank (one orbax checkpoint) loads, and saving it writes shards."""
  import orbax.checkpoint as ocp
  from mwbx.bank import checks, legacy
  bank = mwbx.sample(mwbx.load_config(TINY), 3, jax.random.key(0), backend="native")
  path = tmp_path / "old"
  store_arrays, store_meta = bank.qpos_store.state()
  tree = {name: np.asarray(getattr(bank, name)) for name in mwbx.Bank.ROW_ARRAYS}
  tree["body_ids"] = np.asarray(bank.body_ids)
  tree.update({f"qpos_{k}": np.asarray(v) for k, v in store_arrays.items()})
  meta = {"format": 2, "qpos_store": store_meta, "body_names": list(bank.body_names),
          "objects": {k: list(v) for k, v in bank.objects.items()}, "groups": {},
          "metric_names": list(bank.metric_names), "record_fps": bank.record_fps,
          "query_fps": bank.query_fps, "timestep": bank.timestep, "config": bank.config,
          "mjcf_text": bank.mjcf_text, "digest": bank.digest, "lineage": {}, "run": {"seed": 0},
          "next_id": 3, "checksums": {k: checks.crc32(v) for k, v in tree.items()}}
  with legacy._manager(path) as manager:
    manager.save(1, args=ocp.args.Composite(bank=ocp.args.StandardSave(tree), meta=ocp.args.JsonSave(meta)))
    manager.wait_until_finished()
  loaded = mwbx.Bank.load(path)
  same_worlds(loaded, bank)
  loaded.save(path)
  assert (path / "manifest.json").exists()
  same_worlds(mwbx.Bank.load(path), bank)
