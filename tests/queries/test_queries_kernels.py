"""Exact segment tests and the culled hierarchy against the loop reference."""

import math

from hypothesis import given, settings, HealthCheck
from hypothesis import strategies as st
import jax
import numpy as np
import pytest

from mwbx.queries import Camera, Frustum, ScreenBox
from mwbx.queries import index as index_lib
from mwbx.queries import segments

import queries_bank
import queries_reference as ref

SETTINGS = settings(max_examples=20, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
# A few fixed shapes keep the number of compilations small.
SHAPES = [(5, 1, 2), (4, 2, 3), (6, 17, 2), (3, 40, 3)]  # (W, P, B)
# (segments per chunk, chunks per exact-test block): tiny blocks loop many times.
LAYOUTS = [(1, 1), (3, 4), (16, 64)]
GRID = 8.0  # coordinates on a 1/8 m grid: boxes on the grid put points exactly on planes

coords = st.integers(-6, 6).map(lambda i: i / GRID)


@st.composite
def grid_paths(draw, shape):
  w, p, b = shape
  flat = draw(st.lists(coords, min_size=w * p * b * 3, max_size=w * p * b * 3))
  return np.asarray(flat, np.float32).reshape(w, p, b, 3)


@st.composite
def grid_box(draw):
  lo = [draw(st.integers(-6, 4)) / GRID for _ in range(3)]
  size = [draw(st.integers(0, 8)) / GRID for _ in range(3)]  # zero: a flat box
  return Frustum.box(lo, np.add(lo, size))


@st.composite
def camera_frustum(draw):
  eye = [draw(st.floats(-3, 3)), draw(st.floats(-4, -2)), draw(st.floats(-1, 3))]
  target = [draw(st.floats(-0.5, 0.5)) for _ in range(3)]
  cam = Camera.look_at(eye, target, fovy=draw(st.floats(20, 90)),
                       aspect=draw(st.sampled_from([1.0, 4 / 3, 16 / 9])),
                       orthographic=draw(st.booleans()))
  if cam.orthographic:
    cam = Camera.look_at(eye, target, fovy=draw(st.floats(0.5, 4)), aspect=cam.aspect,
                         orthographic=True)
  u = sorted(draw(st.floats(-0.2, 1.2)) for _ in range(2))
  v = sorted(draw(st.floats(-0.2, 1.2)) for _ in range(2))
  if draw(st.booleans()):  # sometimes a degenerate (zero-width) box
    u[1] = u[0]
  near = draw(st.one_of(st.none(), st.floats(0, 2)))
  far = draw(st.one_of(st.none(), st.floats(2.5, 8)))
  return cam.frustum(ScreenBox(u[0], v[0], u[1], v[1]), near, far), cam


@st.composite
def window(draw):
  # No subnormal times: XLA on a CPU flushes them to zero (a window from 1e-310 s
  # is one from 0 to the kernels), where the Python reference keeps them.
  t0 = draw(st.one_of(st.none(), st.floats(-0.2, 1.5, allow_subnormal=False)))
  t1 = draw(st.one_of(st.none(), st.floats(-0.2, 1.5, allow_subnormal=False)))
  if t0 is not None and t1 is not None and t0 > t1:
    t0, t1 = t1, t0
  if draw(st.booleans()) and t0 is not None:  # windows on whole frames
    t0 = math.floor(t0 * 30) / 30
  return (t0, t1)


def reference_hits(com, valid, frustum, offsets_b, body_mask, win_units):
  w, p, b, _ = com.shape
  out = np.zeros((w, b), bool)
  for i in range(w):
    for j in range(b):
      if valid[i] and body_mask[j]:
        out[i, j] = ref.path_entry(com[i, :, j], frustum.normals, offsets_b[j],
                                   *win_units) is not None
  return out


def check_all_paths(com, frustum, radius, win, chunk, block, valid=None, body_mask=None):
  w, p, b, _ = com.shape
  valid = np.ones(w, bool) if valid is None else valid
  body_mask = np.ones(b, bool) if body_mask is None else body_mask
  offsets = frustum.offsets[None, :] + np.asarray(radius)[:, None]
  units = np.asarray(ref.window_units(win, 30.0, p))
  expected = reference_hits(com, valid, frustum, offsets, body_mask, units)
  index = index_lib.build_index(com, valid, chunk=chunk)
  culled = np.asarray(index_lib.path_hits(index, frustum.normals, offsets, body_mask, units, block))
  brute = np.asarray(index_lib.brute_force_hits(index, frustum.normals, offsets, body_mask, units))
  np.testing.assert_array_equal(culled, expected)
  np.testing.assert_array_equal(brute, expected)
  return expected


@SETTINGS
@given(data=st.data(), shape=st.sampled_from(SHAPES), layout=st.sampled_from(LAYOUTS))
def test_grid_boxes_match_reference(data, shape, layout):
  chunk, block = layout
  com = data.draw(grid_paths(shape))
  frustum = data.draw(grid_box())
  radius = data.draw(st.lists(st.sampled_from([0.0, 0.125, 0.3]), min_size=shape[2],
                              max_size=shape[2]))
  # Mostly valid worlds and selected bodies, some not.
  valid = ~np.asarray(data.draw(st.lists(st.booleans(), min_size=shape[0], max_size=shape[0])))
  mask = ~np.asarray(data.draw(st.lists(st.booleans(), min_size=shape[2], max_size=shape[2])))
  check_all_paths(com, frustum, radius, data.draw(window()), chunk, block, valid, mask)


@SETTINGS
@given(data=st.data(), shape=st.sampled_from(SHAPES), layout=st.sampled_from(LAYOUTS))
def test_camera_frustums_match_reference(data, shape, layout):
  chunk, block = layout
  seed = data.draw(st.integers(0, 2**31))
  rng = np.random.default_rng(seed)
  fc = data.draw(camera_frustum())
  com = queries_bank.ballistic_paths(shape[0], shape[1], shape[2], seed=seed) * 0.5
  # Put some points exactly on the planes (frustum corners and their mixtures).
  picks = rng.random(com.shape[:3]) < 0.3
  corners = fc[0].corners.astype(np.float32)
  com[picks] = corners[rng.integers(0, 8, picks.sum())]
  radius = rng.choice([0.0, 0.05], size=shape[2])
  check_all_paths(com, fc[0], radius, data.draw(window()), chunk, block)


def test_segment_crossing_with_both_ends_outside_counts():
  frustum = Frustum.box([0, 0, 0], [1, 1, 1])
  com = np.array([[[-1, 0.5, 0.5], [2, 0.5, 0.5]]], np.float32)[:, :, None]  # W=1, P=2, B=1
  hits = check_all_paths(com, frustum, [0.0], None, 16, 8)
  assert hits[0, 0]
  # The same segment limited to a window in which it is still left of the box.
  hits = check_all_paths(com, frustum, [0.0], (0.0, 0.3 / 30), 16, 8)
  assert not hits[0, 0]


def test_time_window_edges_are_interpolated_exactly():
  # x goes 0 -> 3 over one segment (1/30 s); the box is x in [1, 2].
  frustum = Frustum.box([1, -1, -1], [2, 1, 1])
  com = np.array([[[0, 0, 0], [3, 0, 0]]], np.float32)[:, :, None]
  for t1, expected in [(1 / 90 - 1e-9, False), (1 / 90 + 1e-9, True)]:
    hits = check_all_paths(com, frustum, [0.0], (0.0, t1), 16, 8)
    assert hits[0, 0] == expected
  for t0, expected in [(2 / 90 - 1e-9, True), (2 / 90 + 1e-9, False)]:
    hits = check_all_paths(com, frustum, [0.0], (t0, None), 16, 8)
    assert hits[0, 0] == expected


def test_window_past_the_end_sees_the_last_point():
  frustum = Frustum.box([0.9, -1, -1], [1.1, 1, 1])
  com = np.array([[[0, 0, 0], [0.5, 0, 0], [1, 0, 0]]], np.float32)[:, :, None]
  hits = check_all_paths(com, frustum, [0.0], (5.0, 6.0), 16, 8)
  assert hits[0, 0]


def test_first_entry_kernel_matches_reference():
  rng = np.random.default_rng(3)
  frustum = Frustum.box([-0.2, -0.3, 0.2], [0.4, 0.3, 0.9])
  com = queries_bank.ballistic_paths(8, 45, 2, seed=4)
  for w in range(8):
    for b in range(2):
      win = (float(rng.uniform(0, 0.5)), None)
      units = np.asarray(ref.window_units(win, 30.0, 45))
      with jax.enable_x64(True):
        got = float(segments.path_first_entry(com[w, :, b], frustum.normals,
                                              frustum.offsets, units))
      want = ref.path_entry(com[w, :, b], frustum.normals, frustum.offsets, *units)
      assert (math.isinf(got) and want is None) or got == want


@pytest.mark.parametrize("chunk", [1, 5, 16])
def test_index_boxes_bound_their_chunks(chunk):
  com = queries_bank.ballistic_paths(3, 23, 2, seed=1)
  index = index_lib.build_index(com, np.ones(3, bool), chunk=chunk)
  pts = np.asarray(index.points)  # [B, W, P', 3]
  lo, hi = np.asarray(index.box_lo), np.asarray(index.box_hi)  # [B, 3, W, NC]
  assert index.chunk == chunk and int(index.n_segments) == 22 and index.shape == (3, 2)
  np.testing.assert_array_equal(pts[:, :, :23], com.transpose(2, 0, 1, 3))
  np.testing.assert_array_equal(pts[:, :, 23:], np.broadcast_to(pts[:, :, 22:23], pts[:, :, 23:].shape))
  for c in range(index.n_chunks):
    seg = pts[:, :, c * chunk: c * chunk + chunk + 1]
    np.testing.assert_array_equal(lo[..., c], np.moveaxis(seg.min(axis=2), -1, 1))
    np.testing.assert_array_equal(hi[..., c], np.moveaxis(seg.max(axis=2), -1, 1))


def test_culling_leaves_few_candidates_and_shortcuts_enclosed_paths():
  com = queries_bank.ballistic_paths(32, 61, 4, seed=5)
  index = index_lib.build_index(com, np.ones(32, bool), chunk=8)
  units = np.array([0.0, 60.0])
  mask = np.ones(4, bool)
  small = Frustum.box([0.1, 0.1, 0.5], [0.3, 0.3, 0.7])
  offsets = np.tile(small.offsets, (4, 1))
  with jax.enable_x64(True):
    candidates, inside = jax.jit(index_lib._box_tests)(index, small.normals, offsets, mask, units)
  assert 0 < np.asarray(candidates).sum() < 0.1 * np.asarray(candidates).size
  assert not np.asarray(inside).any()
  # A box around everything: every path hits through the shortcut, no exact test.
  big = Frustum.box([-50, -50, -50], [50, 50, 50])
  offsets = np.tile(big.offsets, (4, 1))
  with jax.enable_x64(True):
    candidates, inside = jax.jit(index_lib._box_tests)(index, big.normals, offsets, mask, units)
  assert not np.asarray(candidates).any() and np.asarray(inside).all()
  # Unselected bodies are skipped entirely.
  mask = np.array([True, False, False, True])
  with jax.enable_x64(True):
    candidates, inside = jax.jit(index_lib._box_tests)(index, big.normals, offsets, mask, units)
  np.testing.assert_array_equal(np.asarray(inside).any(axis=1), mask)
