"""The display model both viewers draw from (:mod:`mwbx.viewer.display`), on
plain arrays, and that the meshcat viewer and the page draw it in the same colours."""

from __future__ import annotations

import types

import hypothesis.extra.numpy as hnp
import meshcat
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mwbx import queries as mq
from mwbx.browser import drawing
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
