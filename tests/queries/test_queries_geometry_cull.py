"""The compiled culling pass of whole-geometry queries answers exactly as the
exact test on every stored frame (each grown by its step's margin), whatever
its chunk size or query rate, and its distance test is that of
convex.point_distances."""

import numpy as np
import pytest

from mwbx import queries as mq
from mwbx.queries import convex
from mwbx.queries import geometry as geometry_lib
from mwbx.queries import geometry_cull
from mwbx.queries import geometry_query

import geometry_reference as ref

WINDOWS = [None, (0.1, 0.25), (0.0, 0.05), (0.3, None), (0.5, 0.5)]


@pytest.fixture(scope="module")
def bank():
  return ref.shapes_bank(n_worlds=24, n_frames=81, seed=3, spin=5.0)


def _every_frame(index, frustum, window) -> np.ndarray:
  """bool[W, B]: the exact stage on every kept frame the window reaches, no
  culling, no skipped repeats, no early exit, nothing settled."""
  n_bodies, n_worlds, n_frames = index.com.shape[:3]
  relevant, margin = geometry_query.frame_margins(index, window)
  volume = convex.clipped(frustum, index.lo, index.hi)
  out = np.zeros((n_worlds, n_bodies), bool)
  for b in range(n_bodies):
    worlds, frames = np.nonzero(index.valid[:, None] & relevant[None])
    m = margin[b, worlds, frames].astype(np.float64) + index.codec[b]
    hit = geometry_query._exact_stage(index, b, worlds, frames, m, volume, index.tol)
    out[worlds[hit], b] = True
  return out


def _every_stored_frame(bank, frustum, window) -> np.ndarray:
  """`_every_frame` on an index that keeps every stored frame."""
  index = geometry_lib.build(bank, np.asarray(bank.valid, bool), stride=1)
  assert index.stored is None
  return _every_frame(index, frustum, window)


@pytest.mark.parametrize("chunk,group,stride", [(1, 1, 4), (1, 3, 1), (3, 2, 4), (8, 1, 3)])
def test_culled_pass_equals_the_exact_test_on_every_stored_frame(bank, chunk, group, stride):
  index = geometry_lib.build(bank, np.asarray(bank.valid, bool), stride=stride, chunk=chunk, group=group)
  assert index.repeat.any()  # worlds that end early hold their last pose
  rng = np.random.default_rng(chunk)
  mask = np.ones(len(bank.body_names), bool)
  hits = misses = settled = 0
  for k, frustum in enumerate(ref.random_frustums(rng, 15, corner=(0.15, 0.75), size=(0.01, 0.25), box_side=(0.02, 0.4))):
    window = WINDOWS[k % len(WINDOWS)]
    ours = geometry_query.geometry_hits(index, frustum, mask, window)
    np.testing.assert_array_equal(ours, _every_stored_frame(bank, frustum, window), err_msg=f"frustum {k}")
    # Settling on the stored frames only ever drops what the kept frames' margins let in.
    kept = _every_frame(index, frustum, window)
    assert not (ours & ~kept).any()
    settled += int((kept & ~ours).sum())
    hits += int(ours.sum())
    misses += int((~ours).sum())
  assert hits > 20 and misses > 20  # both answers occur
  assert (settled > 0) == (stride > 1)  # the kept frames' margins alone let in more
  # Unselected bodies report nothing, selected ones as before.
  one = np.zeros_like(mask)
  one[2] = True
  both = geometry_query.geometry_hits(index, frustum, mask, None)
  np.testing.assert_array_equal(geometry_query.geometry_hits(index, frustum, one, None), both & one[None])


def test_within_is_the_exact_point_distance():
  rng = np.random.default_rng(11)
  cam = mq.Camera.look_at((0.2, -2.0, 0.4), (0.0, 0.0, 0.1), fovy=50)
  for frustum in (cam.frustum(mq.ScreenBox(0.35, 0.4, 0.6, 0.55), 1.7, 2.3),
                  cam.frustum(mq.ScreenBox(0.1, 0.2, 0.3, 0.9))):
    volume = convex.clipped(frustum, (-3, -3, -3), (3, 3, 3))
    arrays = geometry_cull.volume_arrays(volume)
    lo, hi = volume.vertices.min(axis=0) - 0.3, volume.vertices.max(axis=0) + 0.3
    points = rng.uniform(lo, hi, (3000, 3))
    exact = convex.point_distances(points, volume)
    grow = exact * rng.choice([0.5, 0.999, 1.001, 2.0], len(points)) + rng.choice([0.0, 1e-3], len(points))
    scratch = np.empty(len(arrays.normals))
    ours = np.array([geometry_cull.within(points, i, g, arrays, scratch) for i, g in enumerate(grow)])
    np.testing.assert_array_equal(ours, exact <= grow)
    assert 0.2 < ours.mean() < 0.8


def test_answers_are_kept_per_query_and_returned_as_copies(bank):
  index = geometry_lib.build(bank, np.asarray(bank.valid, bool))
  frustum = mq.Frustum.box((-0.6, -0.5, 0.7), (0.6, 0.5, 1.2))
  mask = np.ones(len(bank.body_names), bool)
  first = geometry_query.geometry_hits(index, frustum, mask, (0.1, 0.3))
  assert first.any() and len(index.answers) == 1
  first[:] = ~first  # the caller's copy: the kept answer does not change
  again = geometry_query.geometry_hits(index, frustum, mask, (0.1, 0.3))
  np.testing.assert_array_equal(again, ~first)
  np.testing.assert_array_equal(again, _every_stored_frame(bank, frustum, (0.1, 0.3)))
  other = geometry_query.geometry_hits(index, frustum, mask, (0.0, 0.05))  # another window: computed
  np.testing.assert_array_equal(other, _every_stored_frame(bank, frustum, (0.0, 0.05)))
  assert len(index.answers) == 2
  for k in range(geometry_query.ANSWERS_KEPT + 3):
    geometry_query.geometry_hits(index, mq.Frustum.box((-0.6, -0.5, 0.7), (0.6, 0.5, 1.2 + 0.01 * k)), mask, None)
  assert len(index.answers) == geometry_query.ANSWERS_KEPT


def test_worlds_settled_one_by_one_answer_as_the_whole_bank(bank, monkeypatch):
  """Where the stored frames of the whole bank do not fit the budget, the
  worlds to settle are decoded and kept one by one: same answers."""
  monkeypatch.setattr(geometry_lib, "STORED_FRAMES_BYTES", 200_000)
  index = geometry_lib.build(bank, np.asarray(bank.valid, bool))
  assert not index.stored._whole
  rng = np.random.default_rng(5)
  mask = np.ones(len(bank.body_names), bool)
  for k, frustum in enumerate(ref.random_frustums(rng, 6, corner=(0.15, 0.75), size=(0.01, 0.25), box_side=(0.02, 0.4))):
    window = WINDOWS[k % len(WINDOWS)]
    ours = geometry_query.geometry_hits(index, frustum, mask, window)
    np.testing.assert_array_equal(ours, _every_stored_frame(bank, frustum, window), err_msg=f"frustum {k}")
  assert 0 < index.stored._bytes <= 200_000 or len(index.stored._kept) == 1
