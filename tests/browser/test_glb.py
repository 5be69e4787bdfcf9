"""The page's native lines (mwbx.browser.glb) read back by an independent glTF reader."""

from __future__ import annotations

import io
import types

import numpy as np
import pytest
import trimesh

from mwbx.browser import drawing, glb, scene


def _segments(n, seed=0):
  return np.random.default_rng(seed).normal(size=(n, 2, 3)).astype(np.float32)


def test_trimesh_reads_the_segments_as_lines():
  segments = _segments(7)
  scene = trimesh.load(io.BytesIO(glb.line_segments(segments, (10, 200, 30))), file_type="glb")
  (path,) = scene.geometry.values()
  assert isinstance(path, trimesh.path.Path3D)  # LINES, not a triangle mesh
  np.testing.assert_array_equal(np.asarray(path.vertices, np.float32), segments.reshape(-1, 3))


@pytest.mark.parametrize("rgb", [(0, 0, 0), (255, 255, 255), (34, 139, 34), (200, 200, 200), (1, 2, 3)])
def test_round_trip_keeps_points_and_colour(rgb):
  segments = _segments(3, seed=sum(rgb))
  points, back = glb.read_line_segments(glb.line_segments(segments, rgb))
  np.testing.assert_array_equal(points, segments)
  assert back == rgb
  assert glb.segment_count(glb.line_segments(segments, rgb)) == 3


def test_colour_factor_is_linear():
  data = glb.line_segments(_segments(1), (128, 128, 128))
  assert b'"baseColorFactor":[0.2158605' in data  # sRGB 128 is 0.2159 linear (IEC 61966-2-1)
  assert b"KHR_materials_unlit" in data and len(data) % 4 == 0


def test_no_segments_is_an_error():
  with pytest.raises(ValueError, match="at least one segment"):
    glb.line_segments(np.zeros((0, 2, 3)), (0, 0, 0))


class _Scene:
  """Counts what goes to the page."""

  def __init__(self):
    self.nodes, self.sent = {}, []

  def _add(self, name, **props):
    self.sent.append(name)
    self.nodes[name] = props
    return types.SimpleNamespace(remove=lambda: self.nodes.pop(name, None), **props)

  def add_glb(self, name, glb_data, **kwargs):
    return self._add(name, glb_data=glb_data)

  def add_line_segments(self, name, points, colors, **kwargs):
    return self._add(name, points=points)


def test_faint_paths_are_native_lines_sent_only_when_they_change():
  rng = np.random.default_rng(1)
  com = np.cumsum(rng.normal(size=(4, 6, 2, 3)), axis=1).astype(np.float32)  # [W, P, B, 3]
  bank = types.SimpleNamespace(valid=np.ones(4, bool), com=com, com_count=np.full(4, 6))
  server, handles = types.SimpleNamespace(scene=_Scene()), {}
  none, match = np.zeros(4, bool), np.array([1, 0, 0, 0], bool)
  drawing.draw_paths(server, handles, bank, np.arange(2), none, none)
  assert "glb_data" in server.scene.nodes["/paths/faint"] and server.scene.sent == ["/paths/faint"]
  drawing.draw_paths(server, handles, bank, np.arange(2), none, none)
  assert server.scene.sent == ["/paths/faint"]  # unchanged: nothing sent
  drawing.draw_paths(server, handles, bank, np.arange(2), match, none)
  assert server.scene.sent[1:] == ["/paths/faint", "/paths/match"]
  assert "points" in server.scene.nodes["/paths/match"]  # wider lines: viser's
  points, _ = glb.read_line_segments(server.scene.nodes["/paths/faint"]["glb_data"])
  assert len(points) == 3 * 2 * 5  # three worlds, two bodies, five segments each
  assert drawing.segments_drawn(handles["paths/faint"]) == len(points)
  assert drawing.segments_drawn(handles["paths/match"]) == 2 * 5


@pytest.mark.parametrize("length, spacing", [(4.0, 0.2), (0.3, 0.02), (1.0, 0.05), (7.0, 0.5), (20.0, 1.0)])
def test_grid_spacing_is_round(length, spacing):
  assert scene.grid_spacing(length) == pytest.approx(spacing)


def test_plane_grid_covers_the_plane_at_round_multiples():
  segments = scene.plane_grid(1.0, 0.45)  # spacing 0.1 (2 m / 20)
  assert np.all(segments[..., 2] == 0)
  assert segments[..., 0].min() == -1.0 and segments[..., 0].max() == 1.0
  assert segments[..., 1].min() == pytest.approx(-0.45) and segments[..., 1].max() == pytest.approx(0.45)
  along_y = segments[segments[:, 0, 0] == segments[:, 1, 0]]  # lines of constant x
  xs = np.sort(along_y[:, 0, 0])
  np.testing.assert_allclose(xs, np.round(np.arange(-10, 11) * 0.1, 6), atol=1e-6)
  ys = np.sort(segments[segments[:, 0, 1] == segments[:, 1, 1]][:, 0, 1])
  np.testing.assert_allclose(ys, [-0.45] + list(np.arange(-4, 5) * 0.1) + [0.45], atol=1e-6)  # and the border


_PLANE_XML = """<mujoco><worldbody>
  <geom name="floor" type="plane" size="1 0.5 0.1" pos="0.2 0 0.1" euler="0 0 90" rgba="0 0 0 1"/>
  <geom name="step" type="box" size="0.1 0.1 0.1"/>
  <body name="ball" pos="0 0 1"><freejoint/><geom type="sphere" size="0.05"/></body>
</worldbody></mujoco>"""


class _StageScene:
  def __init__(self):
    self.glbs, self.meshes = {}, {}

  def add_glb(self, name, glb_data, wxyz, position, **kwargs):
    self.glbs[name] = (glb_data, np.asarray(wxyz), np.asarray(position))

  def add_mesh_simple(self, name, vertices, faces, **kwargs):
    self.meshes[name] = vertices


def test_stage_draws_a_plane_as_a_grid_on_its_surface():
  import mujoco
  model = mujoco.MjModel.from_xml_string(_PLANE_XML)
  server = types.SimpleNamespace(scene=_StageScene())
  stage = scene.Stage(server, model, (np.zeros(3), np.ones(3)))
  assert list(server.scene.meshes) == ["/scene/g1_step"]  # the box stays a mesh
  ((name, (data, wxyz, position)),) = server.scene.glbs.items()
  assert name.startswith("/scene/") and isinstance(stage.static[0], scene.StaticLines)
  segments, rgb = glb.read_line_segments(data)
  assert rgb == tuple(int(round(255 * scene.PLANE_GRID_FADE)) for _ in range(3))  # black, faded
  # In the world: the plane's surface (z = 0.1), its size turned by 90 degrees about z.
  rot = np.zeros(9)
  mujoco.mju_quat2Mat(rot, wxyz)
  world = segments.reshape(-1, 3) @ rot.reshape(3, 3).T + position
  np.testing.assert_allclose(world[:, 2], 0.1, atol=1e-6)
  np.testing.assert_allclose([world[:, 0].min(), world[:, 0].max()], [-0.3, 0.7], atol=1e-6)
  np.testing.assert_allclose([world[:, 1].min(), world[:, 1].max()], [-1.0, 1.0], atol=1e-6)
