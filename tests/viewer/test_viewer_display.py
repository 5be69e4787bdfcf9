"""The display model both viewers draw from (:mod:`mwbx.viewer.display`), on
plain arrays, and that the meshcat viewer and the page draw it in the same colours."""

from __future__ import annotations

import types

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mwbx import queries as mq
from mwbx.browser import drawing, glb
from mwbx.viewer import display, frustums, paths
from mwbx.viewer.errors import ViewerError

FAST = settings(max_examples=40, deadline=None)


def _segments_reference(com, count):
  out = []
  for n in range(com.shape[0]):
    for k in range(com.shape[2]):
      for p in range(int(count[n]) - 1):
        a, b = com[n, p, k], com[n, p + 1, k]
        if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
          out.append((tuple(a), tuple(b)))
  return sorted(out)


@FAST
@given(st.data())
def test_polyline_segments_match_loop(data):
  n, p, k = data.draw(st.integers(1, 5)), data.draw(st.integers(1, 9)), data.draw(st.integers(1, 3))
  com = data.draw(hnp.arrays(np.float32, (n, p, k, 3),
                             elements=st.one_of(st.floats(-5, 5, width=32), st.just(np.nan))))
  count = data.draw(hnp.arrays(np.int32, (n,), elements=st.integers(0, p)))
  seg = display.polyline_segments(com, count)
  assert seg.dtype == np.float32 and seg.ndim == 3 and seg.shape[1:] == (2, 3)
  got = sorted((tuple(a), tuple(b)) for a, b in seg)
  assert got == _segments_reference(com, count)


def _distance_to_segments(point, segments):
  a, b = segments[:, 0].astype(np.float64), segments[:, 1].astype(np.float64)
  ab = b - a
  t = np.clip(np.sum((point - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-30), 0, 1)
  return np.linalg.norm(point - (a + t[:, None] * ab), axis=-1).min()


@FAST
@given(st.data())
def test_simplified_paths_stay_within_tolerance_of_every_point(data):
  """Against a slow reference: every valid recorded point lies within the
  tolerance of its own polyline's drawn segments (a point on no segment: an
  isolated valid point, drawn by none before either); ends are kept, no
  segment bridges an invalid point, and curves, rests and straight flights
  lose points."""
  n, p, k = data.draw(st.integers(1, 3)), data.draw(st.integers(2, 40)), data.draw(st.integers(1, 2))
  t = np.linspace(0, 1, p, dtype=np.float32)
  shape = data.draw(st.sampled_from(["parabola", "rest", "noise"]))
  scale = data.draw(st.floats(0.01, 2.0))
  tolerance = data.draw(st.sampled_from([1e-4, 1e-3, 1e-2]))
  com = np.zeros((n, p, k, 3), np.float32)
  com[..., 0] = t[None, :, None] * scale
  if shape == "parabola":
    com[..., 2] = -4.9 * (t[None, :, None] * scale) ** 2
  elif shape == "rest":
    com[:, p // 2:] = com[:, p // 2:p // 2 + 1]
  else:  # jitter about the size of the tolerance: points close to it either way
    com += tolerance * data.draw(hnp.arrays(np.float32, com.shape, elements=st.floats(-1, 1, width=32)))
  if data.draw(st.booleans()):
    com[0, data.draw(st.integers(0, p - 1)), 0, 1] = np.nan
  count = data.draw(hnp.arrays(np.int32, (n,), elements=st.integers(0, p)))
  keep = display.simplify_polylines(com, count, tolerance)
  drawn = display.polyline_segments(com, count, keep)
  assert len(drawn) <= len(display.polyline_segments(com, count))
  for w in range(n):
    for b in range(k):
      own = display.polyline_segments(com[w:w + 1, :, b:b + 1], count[w:w + 1], keep[w:w + 1, :, b:b + 1])
      every = display.polyline_segments(com[w:w + 1, :, b:b + 1], count[w:w + 1])
      for q in range(int(count[w])):
        point = com[w, q, b].astype(np.float64)
        if np.all(np.isfinite(point)) and len(every) and _distance_to_segments(point, every) == 0:
          assert _distance_to_segments(point, own) <= tolerance * 1.001 + 1e-6
      # No drawn segment has an end outside the valid points, nor spans a non-finite one.
      for a, c in own:
        ia = np.nonzero(np.all(com[w, :, b] == a, axis=-1))[0]
        ic = np.nonzero(np.all(com[w, :, b] == c, axis=-1))[0]
        assert any(np.all(np.isfinite(com[w, i:j + 1, b])) for i in ia for j in ic if i < j < count[w])


def test_simplified_paths_drop_flights_and_rests():
  p = 33
  com = np.zeros((1, p, 2, 3), np.float32)
  com[0, :, 0, 0] = np.linspace(0, 1, p)  # body 0 flies straight
  com[0, :, 1] = [0.3, 0.2, 0.1]  # body 1 lies still
  keep = display.simplify_polylines(com, np.array([p]), 1e-4)
  assert keep[0, :, 0].sum() == 2 and keep[0, :, 1].sum() == 2
  segments = display.polyline_segments(com, np.array([p]), keep)
  np.testing.assert_allclose(segments[0], [[0, 0, 0], [1, 0, 0]], atol=1e-6)
  # A point on the long chord stays while a corner before it does: dropping
  # it would draw (1, 1) -> (4, 0), 0.63 m from (2, 0).
  corner = np.array([[0, 0, 0], [1, 1, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]], np.float32)[None, :, None]
  np.testing.assert_array_equal(display.simplify_polylines(corner, np.array([5]), 1e-3)[0, :, 0],
                                [True, True, True, False, True])


@FAST
@given(st.data())
def test_classify_worlds_partitions(data):
  w = data.draw(st.integers(1, 12))
  valid = np.asarray(data.draw(st.lists(st.booleans(), min_size=w, max_size=w)))
  match = np.asarray(data.draw(st.lists(st.booleans(), min_size=w, max_size=w)))
  exclude = np.asarray(data.draw(st.lists(st.booleans(), min_size=w, max_size=w)))
  worlds = data.draw(st.none() | st.lists(st.integers(0, w - 1), max_size=w))
  c = display.classify_worlds(valid, worlds, match, exclude)
  drawn = np.concatenate(list(c))
  assert len(set(drawn.tolist())) == drawn.size  # disjoint
  chosen = set(range(w)) if worlds is None else set(worlds)
  assert set(drawn.tolist()) == {i for i in chosen if valid[i]}
  assert all(exclude[i] for i in c.exclude) and all(match[i] and not exclude[i] for i in c.match)
  assert all(not (match[i] and not exclude[i]) and not exclude[i] for i in c.faint)


def test_classify_worlds_rejects_bad_input():
  with pytest.raises(ViewerError, match="match must be bool\\[3\\]"):
    display.classify_worlds(np.ones(3, bool), None, np.ones(4, bool), None)
  with pytest.raises(ViewerError, match="index 7"):
    display.classify_worlds(np.ones(3, bool), [7], None, None)


def test_thin_keeps_an_even_subset_within_the_budget():
  worlds = np.arange(1000)
  kept, left_out = display.thin(worlds, per_world=40, budget=1000)  # 25 worlds of 40 segments
  assert kept.size == 25 and left_out == 975 and kept[0] == 0 and kept[-1] == 999 and np.all(np.diff(kept) > 0)
  np.testing.assert_array_equal(display.thin(worlds[:10], 40, 1000)[0], worlds[:10])
  assert display.thin(worlds, 40, None)[1] == 0 and display.thin(worlds, 40, None)[0].size == 1000
  assert display.thin(worlds, 5000, 1000)[0].size == 1  # never fewer than one world


def _bank(n_worlds=6, n_points=5, n_bodies=2, seed=0):
  rng = np.random.default_rng(seed)
  com = rng.normal(size=(n_worlds, n_points, n_bodies, 3)).astype(np.float32)
  count = np.full(n_worlds, n_points, np.int32)
  return com, count


def test_path_layers_split_colour_and_thin_by_class():
  com, count = _bank(n_worlds=6, n_points=5, n_bodies=2)
  classes = display.classify_worlds(np.ones(6, bool), None, np.array([1, 1, 0, 0, 0, 0], bool),
                                    np.array([0, 0, 1, 0, 0, 0], bool))
  layers = display.path_layers(com, count, np.array([1]), classes, {"faint": 4, "match": None})
  assert [layer.name for layer in layers] == list(display.PATH_CLASSES)
  faint, match, exclude = layers
  assert [layer.rgba for layer in layers] == [display.PATH_RGBA[n] for n in display.PATH_CLASSES]
  # 4 segments of one body per world: the faint class (worlds 3, 4, 5) keeps one world.
  assert faint.worlds.size == 1 and faint.left_out == 2 and faint.segments.shape == (4, 2, 3)
  np.testing.assert_array_equal(match.worlds, [0, 1])
  np.testing.assert_array_equal(match.segments[:4, 0], com[0, :4, 1])  # world 0, body 1, in order
  np.testing.assert_array_equal(match.segments[:4, 1], com[0, 1:, 1])
  assert exclude.segments.shape == (4, 2, 3) and exclude.left_out == 0


def test_path_layers_join_the_points_the_simplifier_keeps_and_remember_them():
  com, count = _bank(n_worlds=6, n_points=9, n_bodies=2)
  com[:, 4:] = com[:, 4:5]  # every body rests from point 4 on
  classes = display.classify_worlds(np.ones(6, bool), None, np.array([1, 1, 0, 0, 0, 0], bool),
                                    np.zeros(6, bool))
  simplify = display.PathSimplifier(1e-4)
  layers = display.path_layers(com, count, np.array([1]), classes, {"faint": None, "match": None}, simplify)
  faint, match, _ = layers
  # Points 0-4 joined one by one, then one segment over the rest: 5 a world, not 8.
  assert match.segments.shape == (2 * 5, 2, 3) and faint.segments.shape == (4 * 5, 2, 3)
  np.testing.assert_array_equal(match.segments[:5, 0], com[0, :5, 1])
  np.testing.assert_array_equal(match.segments[4, 1], com[0, 8, 1])
  assert simplify._done.all()
  simplify._keep[:] = True  # remembered: a second draw recomputes nothing ...
  again = display.path_layers(com, count, np.array([1]), classes, {"faint": None, "match": None}, simplify)
  assert again[1].segments.shape == (2 * 8, 2, 3)
  # ... until the bodies (or the array) change.
  other = display.path_layers(com, count, np.array([0]), classes, {"faint": None, "match": None}, simplify)
  assert other[1].segments.shape == (2 * 5, 2, 3)


def test_volume_shape_outline_and_rays():
  camera = mq.Camera.look_at([0, -3, 1], [0, 0, 0.5], fovy=40)
  query = mq.Query.screen(camera, mq.ScreenBox(0.4, 0.4, 0.6, 0.6), sign="exclude")
  shape = display.volume_shape(display.as_volume(query), max_depth=2.0)
  assert shape.rgba == display.QUERY_RGBA["exclude"]
  assert shape.edges.shape == (12, 2, 3)  # a frustum: 4 near, 4 far, 4 side edges
  np.testing.assert_allclose(shape.eye, camera.eye, atol=1e-6)
  assert shape.rays.shape == (4, 2, 3) and np.allclose(shape.rays[:, 0], camera.eye, atol=1e-5)
  lengths = np.linalg.norm(shape.edges[:, 1] - shape.edges[:, 0], axis=1)
  assert lengths.max() <= 2.0 + 1e-5  # the far face was moved in
  box = display.volume_shape(display.as_volume(mq.Query.region([0, 0, 0], [1, 2, 3])))
  assert box.eye is None and box.rays.shape == (0, 2, 3) and box.rgba == display.QUERY_RGBA["include"]


def test_camera_pose_fits_the_box_or_copies_the_eye():
  lo, hi = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0])
  d = np.array([1.0, -1.0, 1.0]) / np.sqrt(3)
  pose = display.camera_pose(lo, hi, display.ViewSpec(d, 45.0, None))
  np.testing.assert_allclose(pose.target, [0, 0, 0.5])
  np.testing.assert_allclose((pose.eye - pose.target) / np.linalg.norm(pose.eye - pose.target), d)
  assert pose.fovy == 45.0 and np.all(np.abs(pose.eye - pose.target) > 1.0)  # outside the box
  eye = np.array([0.0, -5.0, 0.5])
  exact = display.camera_pose(lo, hi, display.ViewSpec(np.array([0.0, -1.0, 0.0]), 30.0, eye))
  np.testing.assert_allclose(exact.eye, eye) and np.testing.assert_allclose(exact.target, [0, 0, 0.5])


def test_rgba_conversions():
  c = display.Rgba(1.0, 0.5, 0.0, 0.5)
  assert c.u8() == (255, 128, 0) and c.hex() == 0xFF8000
  assert c.over((1.0, 1.0, 1.0)) == (255, 191, 128) and c._replace(a=1.0).over() == c.u8()


# ---------------------------------------------------------------- the two front ends


class _Node:
  def __init__(self, log, path):
    self.log, self.path = log, path

  def __getitem__(self, name):
    return _Node(self.log, f"{self.path}/{name}")

  def set_object(self, obj, material=None):
    self.log[self.path] = obj if material is None else material

  def set_transform(self, matrix):
    pass

  def delete(self):
    self.log.pop(self.path, None)


class _Scene:
  def __init__(self):
    self.lines = {}

  def add_line_segments(self, name, points, colors, **kwargs):
    self.lines[name] = (np.asarray(points), tuple(int(c) for c in colors))
    return types.SimpleNamespace(remove=lambda: self.lines.pop(name, None))

  def add_glb(self, name, glb_data, **kwargs):  # native lines: read back from the file
    self.lines[name] = glb.read_line_segments(glb_data)
    return types.SimpleNamespace(remove=lambda: self.lines.pop(name, None), glb_data=glb_data)


def test_meshcat_and_page_draw_paths_in_the_table_colours():
  com, count = _bank(n_worlds=6)
  match, exclude = np.array([1, 1, 0, 0, 0, 0], bool), np.array([0, 0, 1, 0, 0, 0], bool)
  classes = display.classify_worlds(np.ones(6, bool), None, match, exclude)
  log = {}
  paths.draw_paths(_Node(log, ""), com, count, np.arange(2), classes)
  bank = types.SimpleNamespace(valid=np.ones(6, bool), com=com, com_count=count)
  server = types.SimpleNamespace(scene=_Scene())
  drawing.draw_paths(server, {}, bank, np.arange(2), match, exclude)
  for name in display.PATH_CLASSES:
    rgba = display.PATH_RGBA[name]
    material = log[f"/{name}"].material
    assert material.color == rgba.hex() and material.opacity == rgba.a
    page_rgb = server.scene.lines[f"/paths/{name}"][1]
    assert page_rgb == rgba.over((1.0, 1.0, 1.0))  # the same colour (opacity blended in: viser lines have none)
    if rgba.a == 1.0:
      assert page_rgb == rgba.u8() and (page_rgb[0] << 16 | page_rgb[1] << 8 | page_rgb[2]) == material.color
    # the same segments, too
    np.testing.assert_array_equal(server.scene.lines[f"/paths/{name}"][0].reshape(-1, 3),
                                  np.asarray(log[f"/{name}"].geometry.position).T)


def test_meshcat_and_page_draw_query_volumes_in_the_table_colours():
  camera = mq.Camera.look_at([0, -3, 1], [0, 0, 0.5], fovy=40)
  queries = [mq.Query.screen(camera, mq.ScreenBox(0.4, 0.4, 0.6, 0.6), sign=s) for s in ("include", "exclude")]
  server = types.SimpleNamespace(scene=_Scene())
  drawing.draw_frustums(server, {}, [types.SimpleNamespace(query=q, enabled=True) for q in queries], 2.0)
  for i, q in enumerate(queries):
    log = {}
    frustums.draw_volume(_Node(log, ""), display.as_volume(q, i), i, max_depth=2.0)
    rgba = display.QUERY_RGBA[q.sign]
    assert log["/volume"].color == rgba.hex() and log["/outline"].material.color == rgba.hex()
    points, rgb = server.scene.lines[f"/queries/q{i}"]
    assert rgb == rgba.u8() and points.shape == (12, 2, 3)
    assert server.scene.lines[f"/queries/q{i}-rays"][1] == display.CAMERA_RGBA.u8()
    assert log["/camera/rays"].material.color == display.CAMERA_RGBA.hex()
