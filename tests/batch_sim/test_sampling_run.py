"""The library sampling run (mwbx.sample_run) that `mwbx sample` wraps: a run
stopped after its first shard is resumed from Python, and the bank it makes
is, world for world, the one an uninterrupted run makes."""

import numpy as np
import pytest

import mwbx
from conftest import REPO, TESTS
from mwbx import cli, distributed
from mwbx.batch_sim import RunInterrupted, memory

ARRAYS = ("world_ids", "keys", "flags", "frame_count", "com", "metrics", "perturbations")


def test_a_stopped_run_resumes_from_python_to_the_same_bank(tiny_config, tmp_path):
  straight = mwbx.sample_run(tiny_config, tmp_path / "straight", n_worlds=6, chunk_size=2, backend="native")
  assert straight.summary.worlds == 6 and straight.stored == 6 and straight.resumed is None

  said, reports = [], []

  def stop_after_the_first_shard(progress):
    reports.append(progress)
    if progress.phase == "simulating" and progress.done >= 2 and (tmp_path / "run" / "shards").is_dir():
      raise KeyboardInterrupt

  with pytest.raises(RunInterrupted) as stopped:
    mwbx.sample_run(tiny_config, tmp_path / "run", n_worlds=6, chunk_size=2, backend="native",
                    progress=stop_after_the_first_shard, say=said.append)
  assert 2 <= stopped.value.saved < 6 and reports
  assert any(line.startswith("sampling 6 worlds of") for line in said)
  again = mwbx.sample_run(tiny_config, tmp_path / "run", chunk_size=2, backend="native", say=said.append)
  assert again.resumed == (stopped.value.saved, 6) and again.stored == 6
  assert f"resuming: {stopped.value.saved} of 6 worlds done (seed 0)" in said
  a, b = mwbx.Bank.load(tmp_path / "straight"), mwbx.Bank.load(tmp_path / "run")
  order_a, order_b = np.argsort(a.world_ids), np.argsort(b.world_ids)
  for name in ARRAYS:
    np.testing.assert_array_equal(np.asarray(getattr(a, name))[order_a], np.asarray(getattr(b, name))[order_b])
  for world in range(6):
    np.testing.assert_array_equal(a.qpos_frames(world), b.qpos_frames(world))


def test_a_run_into_another_scenes_bank_is_refused(tiny_config, quickstart_config, tmp_path, capsys):
  bank = tmp_path / "bank"
  mwbx.sample_run(tiny_config, bank, n_worlds=2, backend="native")
  # From Python the messages name sample_run's parameters; `mwbx sample` names its flags.
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.sample_run(quickstart_config, bank, n_worlds=2, backend="native")
  assert str(err.value) == f"{bank}: holds a bank of a different config or MJCF; choose another out"
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.sample_run(tiny_config, bank, n_worlds=2, seed=5, backend="native")
  assert str(err.value) == f"seed: {bank} was sampled with seed 0, not 5"
  assert cli.main(["sample", str(REPO / "configs" / "quickstart.yaml"), "--worlds", "2", "--out", str(bank)]) == 2
  assert "holds a bank of a different config or MJCF; choose another --out" in capsys.readouterr().err
  assert cli.main(["sample", str(TESTS / "scenes" / "tiny.yaml"), "--worlds", "2", "--seed", "5",
                   "--out", str(bank)]) == 2
  assert f"--seed: {bank} was sampled with seed 0, not 5" in capsys.readouterr().err
  assert mwbx.Bank.load(bank).n_worlds == 2


def test_sample_run_names_its_parameters_not_flags(tiny_config, tmp_path, monkeypatch):
  # sample_run said "--worlds"/"--out", flags of `mwbx sample`, to Python callers.
  cases = ((0, "n_worlds: must be at least 1, got 0"),
           (2**32 + 1, "n_worlds: 4,294,967,297 worlds from id 0 would pass the last world id"),
           (10**9, "n_worlds 1000000000: the run's list of world ids"))
  monkeypatch.setenv(memory.ENV_AVAILABLE, str(8 << 30))
  for n_worlds, message in cases:
    with pytest.raises(mwbx.MwbxError) as err:
      mwbx.sample_run(tiny_config, tmp_path / "bank", n_worlds=n_worlds, backend="native")
    assert str(err.value).startswith(message) and "--" not in str(err.value), str(err.value)
  assert "the same out continues the bank" in str(err.value)


def test_joining_processes_names_the_callers_words(tiny_config, tmp_path, capsys):
  for flags, needle in ((None, "num_processes: also give process_id and coordinator HOST:PORT"),
                        (cli.SAMPLE_FLAGS, "--num-processes: also give --process-id and --coordinator HOST:PORT")):
    with pytest.raises(mwbx.MwbxError, match=needle):
      distributed.join(None, 2, None, flags=flags)
  with pytest.raises(mwbx.MwbxError) as err:
    distributed.join("127.0.0.1:1", 2, 5)
  assert str(err.value) == "process_id: must be in 0..1, got 5"
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.sample_run(tiny_config, tmp_path / "bank", n_worlds=2, hosts=mwbx.Hosts(num_processes=2))
  assert str(err.value).startswith("num_processes: also give process_id")
  assert cli.main(["sample", str(TESTS / "scenes" / "tiny.yaml"), "--worlds", "2", "--out", str(tmp_path / "b"),
                   "--num-processes", "2", "--coordinator", "127.0.0.1:1", "--process-id", "2"]) == 2
  assert "--process-id: must be in 0..1, got 2" in capsys.readouterr().err
  assert not (tmp_path / "b").exists() and not (tmp_path / "bank").exists()
