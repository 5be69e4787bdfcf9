"""path_boxes: every stored point lies in its chunk's decoded box, the
stored layout round-trips, and a path is decided only as the exact segment
test decides it (compared per path with the brute-force kernel)."""

import numpy as np
import pytest

from mwbx.queries import Frustum
from mwbx.queries import index as index_lib
from mwbx.queries import path_boxes

import queries_bank


@pytest.mark.parametrize("n_points,chunk", [(1, 32), (2, 32), (31, 4), (33, 32), (121, 32), (40, 7)])
def test_every_point_lies_in_its_decoded_chunk_box(n_points, chunk):
  com = queries_bank.ballistic_paths(9, n_points, 3, seed=n_points)
  com[2, 3 % n_points, 1] = np.nan  # a path with a non-finite point
  boxes = path_boxes.unpack(path_boxes.pack(path_boxes.build(com, chunk)), max(n_points - 1, 1), chunk)
  assert boxes.chunk_lo.shape[2] == path_boxes.n_chunks(max(n_points - 1, 1), chunk)
  lo = path_boxes.decode_corner(boxes.lo, boxes.hi, boxes.chunk_lo)  # [W, B, NC, 3]
  hi = path_boxes.decode_corner(boxes.lo, boxes.hi, boxes.chunk_hi)
  points = np.concatenate([com, com], axis=1) if n_points == 1 else com
  for j in range(lo.shape[2]):  # chunk j holds points j*chunk .. (j+1)*chunk, the last one shared
    part = points[:, j * chunk:(j + 1) * chunk + 1].astype(np.float64)  # [W, k, B, 3]
    finite = np.isfinite(part).all(axis=(1, 3)) & np.isfinite(boxes.lo).all(axis=-1)  # [W, B]: else never decided
    inside = (part >= lo[:, None, :, j]) & (part <= hi[:, None, :, j])
    assert inside.all(axis=(1, 3))[finite].all()
    # ... and the box is at most one code step wider than the points on each side.
    step = (boxes.hi - boxes.lo).astype(np.float64) / path_boxes.CODE_MAX + 1e-9  # [W, B, 3]
    assert (lo[:, :, j] >= part.min(axis=1) - step)[finite].all()
    assert (hi[:, :, j] <= part.max(axis=1) + step)[finite].all()
  assert np.isnan(boxes.lo[2, 1]).all()


def test_a_wrong_row_length_is_refused():
  stored = path_boxes.pack(path_boxes.build(np.zeros((2, 40, 3, 3), np.float32)))
  with pytest.raises(ValueError, match="expected"):
    path_boxes.unpack(stored, 70, 32)


def test_decisions_are_those_of_the_exact_test():
  rng = np.random.default_rng(4)
  com = queries_bank.ballistic_paths(64, 61, 4, seed=3)
  com[5:9, 20:] = com[5:9, 20:21]  # resting stretches
  com[11, 7, 2] = np.nan
  boxes = path_boxes.build(com, 8)
  index = index_lib.build_index(com, np.ones(len(com), bool))
  decided = 0
  for _ in range(40):
    centre = rng.uniform([-1, -1, 0], [1, 1, 1.5])
    half = rng.uniform(0.02, 0.8, size=3)
    frustum = Frustum.box(centre - half, centre + half)
    radius = rng.choice([0.0, 0.05])
    offsets = frustum.offsets[None, :] + np.full((4, 1), radius)
    mask = rng.random(4) < 0.7
    w0 = rng.uniform(0, 60)
    window = np.array(sorted([w0, rng.uniform(w0, 60)]))
    state = path_boxes.classify(boxes, frustum.normals, offsets, mask, window)
    exact = np.asarray(index_lib.brute_force_hits(index, frustum.normals, offsets, mask, window))
    assert not (exact & (state == path_boxes.MISS)).any()
    assert exact[state == path_boxes.HIT].all()
    assert (state[:, ~mask] == path_boxes.MISS).all()
    assert (state[11, 2] == path_boxes.UNKNOWN) or not mask[2]
    decided += int((state != path_boxes.UNKNOWN)[:, mask].sum())
  assert decided > 0.5 * 40 * 64 * 4 * 0.7  # most paths are decided by their boxes
