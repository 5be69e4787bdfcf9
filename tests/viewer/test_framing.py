"""The first view frames every body's paths from outside them, in the viewer
and the page, and never takes its direction from a camera that follows a body."""

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.browser import app
from mwbx.viewer import display, framing

# A humanoid-like figure lying on the floor (it hardly moves: its paths span
# less than its own size), whose only cameras ride on it: one tracking its
# centre of mass, one egocentric in the head. Big spheres for the head and hands.
HUMANOID = """<mujoco model="lying figure">
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="torso" pos="0 0 0.16" euler="0 90 0">
      <camera name="back" mode="trackcom" pos="0 -2.5 0.8" xyaxes="1 0 0 0 0.3 1"/>
      <freejoint/>
      <geom type="capsule" size="0.14 0.3"/>
      <body name="head" pos="0 0 0.5">
        <camera name="egocentric" pos="0.1 0 0" xyaxes="0 -1 0 0.1 0 1"/>
        <joint type="hinge" axis="0 1 0" range="-20 20" damping="1"/>
        <geom type="sphere" size="0.16"/>
      </body>
      <body name="arm_l" pos="0 0.22 0.2">
        <joint type="hinge" axis="1 0 0" range="-30 30" damping="1"/>
        <geom type="capsule" fromto="0 0 0 0 0.35 0" size="0.05"/>
        <body name="hand_l" pos="0 0.45 0"><geom type="sphere" size="0.1"/></body>
      </body>
      <body name="arm_r" pos="0 -0.22 0.2">
        <joint type="hinge" axis="1 0 0" range="-30 30" damping="1"/>
        <geom type="capsule" fromto="0 0 0 0 -0.35 0" size="0.05"/>
        <body name="hand_r" pos="0 -0.45 0"><geom type="sphere" size="0.1"/></body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

# The same figure seen by a world camera that turns to follow it (first) and a
# fixed overview camera (second).
WITH_WORLD_CAMERAS = HUMANOID.replace(
    '<geom name="floor"',
    '<camera name="follow" mode="targetbody" target="torso" pos="0 3 0.3"/>\n'
    '    <camera name="overview" pos="2 -3 2" xyaxes="0.83 0.55 0 -0.3 0.45 0.84" fovy="40"/>\n'
    '    <geom name="floor"')


@pytest.fixture(scope="module")
def bank(tmp_path_factory):
  folder = tmp_path_factory.mktemp("figure")
  (folder / "figure.xml").write_text(HUMANOID)
  (folder / "cfg.yaml").write_text("scene: {mjcf: figure.xml}\nsim: {end_time: 0.3}\n")
  return mwbx.sample(mwbx.load_config(folder / "cfg.yaml"), n_worlds=3, key=jax.random.key(0),
                     backend="native")


def paths_box(bank, model):
  """(lo, hi) around every body's COM path in the valid worlds, widened by the
  largest moving geom: the space the bodies sweep."""
  com = np.asarray(bank.com)[np.asarray(bank.valid, bool)].reshape(-1, 3)
  moving = model.body_weldid[model.geom_bodyid] != 0
  margin = float(model.geom_rbound[moving].max())
  return com.min(axis=0) - margin, com.max(axis=0) + margin


def assert_frames_from_outside(lo, hi, eye, look_at, fovy_deg):
  inside = np.all((eye > lo) & (eye < hi))
  assert not inside, (eye, lo, hi)
  forward = (look_at - eye) / np.linalg.norm(look_at - eye)
  corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
  rel = corners - eye
  depth = rel @ forward
  assert np.all(depth > 0)  # every corner in front of the eye
  # ... and inside the cone around the view of a 4:3 window.
  tan_v = np.tan(np.radians(fovy_deg) / 2)
  cone = np.arctan(np.hypot(tan_v, tan_v * 4 / 3))
  assert np.all(np.arccos(np.clip(depth / np.linalg.norm(rel, axis=1), -1, 1)) < cone)


def test_cameras_on_or_following_a_body_give_no_direction():
  model = mujoco.MjModel.from_xml_string(HUMANOID)
  assert model.ncam == 2 and framing.scene_camera(model) == -1
  spec = framing.view_spec(model)
  np.testing.assert_allclose(spec.direction, framing.DEFAULT_VIEW_DIR / np.linalg.norm(framing.DEFAULT_VIEW_DIR))
  assert spec.fovy == framing.DEFAULT_FOVY and spec.eye is None
  # A fixed world camera is still followed, even after one that turns to a body.
  model = mujoco.MjModel.from_xml_string(WITH_WORLD_CAMERAS)
  overview = model.camera("overview").id
  assert model.camera("follow").id < overview and framing.scene_camera(model) == overview
  spec = framing.view_spec(model)
  camera = mq.Camera.from_model(model, "overview")
  np.testing.assert_allclose(spec.direction, -camera.forward) and np.testing.assert_allclose(spec.fovy, 40.0)
  # Asked for by name, any camera is viewed from exactly.
  assert framing.view_spec(model, camera="follow").eye is not None


@pytest.mark.parametrize("direction", [[1.0, -1.4, 0.9], [0.0, 0.0, 1.0], [0.3, 0.1, -1.0], [0.0, -1.0, 0.0]])
def test_frame_box_puts_the_eye_outside_seeing_every_corner(direction):
  lo, hi = np.array([-0.5, -0.2, 0.0]), np.array([0.7, 0.3, 0.25])
  d = np.asarray(direction) / np.linalg.norm(direction)
  centre, eye = display.frame_box(lo, hi, framing.ViewSpec(d, 50.0, None))
  np.testing.assert_allclose(centre, (lo + hi) / 2)
  assert_frames_from_outside(lo, hi, eye, centre, 50.0)


def test_page_first_view_of_a_lying_figure_is_from_outside_its_paths(bank):
  model = bank.model
  lo, hi = paths_box(bank, model)
  page = app.browse(bank, block=False)
  try:
    camera = page.server.initial_camera
    eye, look_at = np.asarray(camera.position, np.float64), np.asarray(camera.look_at, np.float64)
    assert_frames_from_outside(lo, hi, eye, look_at, np.degrees(camera.fov))
    # Along the default direction: the figure's cameras ride on it.
    d = (eye - look_at) / np.linalg.norm(eye - look_at)
    np.testing.assert_allclose(d, framing.DEFAULT_VIEW_DIR / np.linalg.norm(framing.DEFAULT_VIEW_DIR), atol=1e-9)
  finally:
    page.close()


def test_viewer_first_view_of_a_lying_figure_is_from_outside_its_paths(bank):
  model = bank.model
  lo, hi = paths_box(bank, model)
  rows = np.flatnonzero(np.asarray(bank.valid, bool))
  box_lo, box_hi = framing.scene_bounds(bank, model, rows, None, None)
  assert np.all(box_lo <= lo + 1e-6) and np.all(box_hi >= hi - 1e-6)  # the viewer's box holds the paths
  spec = framing.view_spec(model)
  centre, eye = display.frame_box(box_lo, box_hi, spec)
  assert_frames_from_outside(lo, hi, eye, centre, spec.fovy)


def test_a_large_height_field_ground_does_not_push_the_view_away(bank):
  # The same figure on a 100 m x 100 m terrain: the view frames the figure's paths.
  terrain = HUMANOID.replace(
      "<worldbody>", '<asset><hfield name="terrain" nrow="3" ncol="3" size="50 50 1 0.1"/></asset>\n'
      '  <worldbody>\n    <geom type="hfield" hfield="terrain" pos="0 0 -0.1"/>')
  model = mujoco.MjModel.from_xml_string(terrain)
  rows = np.flatnonzero(np.asarray(bank.valid, bool))
  lo, hi = framing.scene_bounds(bank, model, rows, None, None)
  assert np.all(hi - lo < 5.0)
