"""The library sampling run (mwbx.sample_run) that `mwbx sample` wraps: a run
stopped after its first shard is resumed from Python, and the bank it makes
is, world for world, the one an uninterrupted run makes."""

import numpy as np
import pytest

import mwbx
from mwbx.batch_sim import RunInterrupted

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


def test_a_run_into_another_scenes_bank_is_refused(tiny_config, quickstart_config, tmp_path):
  mwbx.sample_run(tiny_config, tmp_path / "bank", n_worlds=2, backend="native")
  with pytest.raises(mwbx.MwbxError, match="holds a bank of a different config or MJCF"):
    mwbx.sample_run(quickstart_config, tmp_path / "bank", n_worlds=2, backend="native")
