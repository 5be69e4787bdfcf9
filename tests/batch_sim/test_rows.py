"""One road from chunk results to bank rows (mwbx/batch_sim/rows.py), shared by
sampling and refinement."""

from __future__ import annotations

import pathlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx import bank as bank_lib
from mwbx.batch_sim import rows as rows_lib
from mwbx.batch_sim import world
from mwbx.batch_sim.backend import ChunkResult
from mwbx.codec import polyline
from mwbx.refinement import RefineRequest, run_refinement

TINY = pathlib.Path(__file__).parents[1] / "scenes" / "tiny.yaml"


def _chunk(com, frame_count, status, metrics=None, overflow=None):
  w, f, b = com.shape[:3]
  metrics = np.zeros((w, b, 2), np.float32) if metrics is None else metrics
  return ChunkResult(qpos=None, com=com, frame_count=np.asarray(frame_count, np.int32),
                     status=np.asarray(status, np.int32), metrics=metrics,
                     perturbations=np.arange(w, dtype=np.int64), steps=np.arange(w, dtype=np.int64) * 4,
                     compile_seconds=0.0, run_seconds=0.0, contact_overflow=overflow)


def test_status_flags_one_table():
  status = np.array([world.RUNNING, world.AT_REST, world.END_TIME, world.UNSTABLE, world.SIM_ERROR])
  flags = rows_lib.status_flags(status)
  finished = bank_lib.FLAG_FINISHED
  assert flags.dtype == np.uint8
  assert flags.tolist() == [finished, finished | bank_lib.FLAG_AT_REST, finished,
                            finished | bank_lib.FLAG_UNSTABLE, finished | bank_lib.FLAG_SIM_ERROR]
  over = rows_lib.status_flags(status, np.array([0, 1, 0, 0, 1], bool))
  assert (over & bank_lib.FLAG_CONTACT_OVERFLOW).astype(bool).tolist() == [False, True, False, False, True]


@pytest.mark.parametrize("stride", [1, 2, 3, 4, 7])
def test_com_count_counts_the_polyline_points(stride):
  """Points sit at frames 0, stride, 2·stride, …: count those below frame_count.
  (Sampling wrote ``where(n > 0, (n - 1) // s + 1, 0)`` and refinement
  ``(n - 1) // s + 1``; for n >= 0 they agree, n = 0 included: -1 // s = -1.)"""
  counts = np.arange(0, 60)
  expected = [sum(1 for k in range(n) if k % stride == 0) for n in counts]
  assert rows_lib.com_count(counts, stride).tolist() == expected
  assert ((counts - 1) // stride + 1).tolist() == expected


def test_sampled_rows_tail_nan_and_grid():
  rng = np.random.default_rng(0)
  com = rng.normal(size=(3, 9, 2, 3)).astype(np.float32)
  com[2, 4:] = com[2, 3]  # world 2 recorded 4 frames; its tail repeats the last
  com[1, 0, 1, 2] = np.nan
  metrics = np.ones((3, 2, 2), np.float32)
  metrics[0, 1, 0] = np.inf
  rows = rows_lib.rows_from_chunks([_chunk(com, [9, 9, 4], [world.END_TIME, world.AT_REST, world.UNSTABLE],
                                           metrics)], 2, 0.002)
  assert rows.com.shape == (3, 5, 2, 3) and rows.com_count.tolist() == [5, 5, 2]
  assert (rows.com[2, 2:] == rows.com[2, 1]).all()  # past com_count: the last point (frame 2), not frame 3
  assert rows.com[1, 0, 1, 2] == 0.0 and np.isfinite(rows.com).all()
  np.testing.assert_array_equal(rows.com, (np.round(rows.com.astype(np.float64) / 0.002) * 0.002).astype(np.float32))
  assert rows.metrics[0, 1, 0] == 0.0 and rows.metrics.dtype == np.float32
  assert rows.flags[2] & bank_lib.FLAG_UNSTABLE and rows.steps.dtype == np.int32


def test_refined_rows_keep_the_parent_before_t_min_and_for_kept_bodies():
  rng = np.random.default_rng(1)
  n_frames, f0, stride = 12, 5, 2
  parent_com = polyline.round_to_grid(rng.normal(size=(6, 2, 3)), 0.002)  # stored rows are on the grid
  new = rng.normal(size=(2, n_frames - f0, 2, 3)).astype(np.float32)
  new[0, 3:] = new[0, 2]  # world 0 recorded 3 frames from f0 (8 in all)
  parent = rows_lib.ParentRow(com=parent_com, metrics=np.full((2, 2), 7.0, np.float32),
                              com_kept=np.array([[False, True], [False, False]]),
                              metrics_kept=np.array([[False, True], [True, False]]))
  rows = rows_lib.rows_from_chunks([_chunk(new, [3, 7], [world.AT_REST, world.END_TIME])], stride, 0.002,
                                   first_frame=f0, parent=parent)
  assert rows.frame_count.tolist() == [8, 12] and rows.com_count.tolist() == [4, 6]
  np.testing.assert_array_equal(rows.com[:, :3], np.broadcast_to(parent_com[:3], (2, 3, 2, 3)))  # frames 0, 2, 4
  np.testing.assert_array_equal(rows.com[0, :, 1], parent_com[[0, 1, 2, 3, 3, 3], 1])
  np.testing.assert_allclose(rows.com[1, 3:, 0], new[1, 1::2, 0], atol=0.001)  # frames 6, 8, 10 from f0 = 5
  assert (rows.com[0, 4:, 0] == rows.com[0, 3, 0]).all()
  assert rows.metrics[0, 1, 0] == 7.0 and rows.metrics[1, 0, 0] == 7.0 and rows.metrics[0, 0, 0] == 0.0


@pytest.fixture(scope="module")
def tiny_bank():
  return mwbx.sample(mwbx.load_config(TINY), 8, jax.random.key(3), backend="native")


def test_refined_worlds_keep_the_banks_tail_contract(tiny_bank):
  """Points past com_count repeat the last point, in refined worlds as in sampled
  ones. Refinement used to leave the last recorded frame's COM there (here one
  grid step away in two of the four worlds), an extra segment for queries."""
  new = run_refinement(tiny_bank, RefineRequest(2, ["cube"], t_min=0.2, n_samples=4, key=jax.random.key(5),
                                            backend="native")).new
  assert tiny_bank.record_fps / tiny_bank.query_fps > 1
  for bank in (tiny_bank, new):
    com = np.asarray(bank.com)
    for row, count in enumerate(bank.com_count):
      assert 0 < count <= com.shape[1]
      np.testing.assert_array_equal(com[row, count:], np.broadcast_to(com[row, count - 1], com[row, count:].shape))
  assert (new.com_count < new.com.shape[1]).any()  # the check above had tails to look at
