"""Cameras, screen boxes and frustums."""

from hypothesis import given, settings
from hypothesis import strategies as st
import mujoco
import numpy as np
import pytest

from mwbx.errors import MwbxError
from mwbx.queries import Camera, Frustum, ScreenBox

import queries_bank

finite = st.floats(-5, 5)


@st.composite
def cameras(draw):
  eye = np.array([draw(finite), draw(finite), draw(finite)])
  target = eye + np.array([draw(st.floats(-1, 1)) for _ in range(3)])
  if np.linalg.norm(target - eye) < 0.1 or abs((target - eye)[2]) > 0.95 * np.linalg.norm(target - eye):
    target = eye + np.array([1.0, 0.3, 0.1])
  ortho = draw(st.booleans())
  fovy = draw(st.floats(0.5, 5)) if ortho else draw(st.floats(10, 120))
  return Camera.look_at(eye, target, fovy=fovy, aspect=draw(st.floats(0.5, 2.5)),
                        orthographic=ortho)


@settings(max_examples=60, deadline=None)
@given(cam=cameras(), uv=st.tuples(st.floats(-0.5, 1.5), st.floats(-0.5, 1.5)),
       depth=st.floats(0.1, 20))
def test_project_inverts_unproject(cam, uv, depth):
  p = cam.unproject(np.array(uv), depth)
  uv2, depth2 = cam.project(p)
  np.testing.assert_allclose(uv2, uv, atol=1e-9)
  np.testing.assert_allclose(depth2, depth, rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(cam=cameras(), data=st.data())
def test_frustum_contains_what_projects_into_the_box(cam, data):
  u = sorted(data.draw(st.floats(0, 1)) for _ in range(2))
  v = sorted(data.draw(st.floats(0, 1)) for _ in range(2))
  near = data.draw(st.one_of(st.none(), st.floats(0.1, 1)))
  far = data.draw(st.one_of(st.none(), st.floats(3, 10)))
  box = ScreenBox(u[0], v[0], u[1], v[1])
  frustum = cam.frustum(box, near, far)
  rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
  uv = rng.uniform(-0.3, 1.3, size=(200, 2))
  depth = rng.uniform(-2, 12, size=200)
  points = cam.unproject(uv, depth)
  uv_back, depth_back = cam.project(points)
  lo_depth = 0.0 if near is None else near
  hi_depth = np.inf if far is None else far
  inside = ((uv_back[:, 0] >= box.u0) & (uv_back[:, 0] <= box.u1) & (uv_back[:, 1] >= box.v0)
            & (uv_back[:, 1] <= box.v1) & (depth_back >= lo_depth) & (depth_back <= hi_depth))
  if not cam.orthographic:
    inside &= depth_back > 0
  # Ignore points within rounding distance of a boundary.
  margin = np.minimum.reduce([np.abs(uv_back[:, 0] - box.u0), np.abs(uv_back[:, 0] - box.u1),
                              np.abs(uv_back[:, 1] - box.v0), np.abs(uv_back[:, 1] - box.v1),
                              np.abs(depth_back - lo_depth), np.abs(depth_back - hi_depth)])
  clear = margin > 1e-5
  np.testing.assert_array_equal(frustum.contains(points)[clear], inside[clear])


def test_corners_lie_on_the_planes_and_eye_is_apex():
  cam = Camera.look_at([0, -3, 1], [0, 0, 0.5], fovy=50, aspect=4 / 3)
  frustum = cam.frustum(ScreenBox(0.2, 0.3, 0.6, 0.9), near=0.5, far=6)
  assert frustum.n_planes == 6
  d = frustum.distances(frustum.corners)
  assert np.all(d <= 1e-6) and np.all(np.sum(np.abs(d) < 1e-6, axis=1) >= 3)
  np.testing.assert_allclose(frustum.eye, [0, -3, 1])
  side = frustum.distances(frustum.eye)[:4]
  np.testing.assert_allclose(side, 0, atol=1e-6)


def test_degenerate_box_excludes_points_behind_the_camera():
  cam = Camera.look_at([0, -3, 0], [0, 0, 0], fovy=60, aspect=1)
  frustum = cam.frustum(ScreenBox(0.5, 0.2, 0.5, 0.8))
  assert frustum.contains([[0, 0, 0]])  # on the flat wedge, in front
  assert not frustum.contains([[0, -6, 0]])  # behind the eye


def test_mjcf_camera_matches_mujoco_pose():
  model = mujoco.MjModel.from_xml_string(queries_bank.scene_xml(3))
  cam = Camera.from_model(model, "front")
  np.testing.assert_allclose(cam.eye, [0, -4, 1])
  np.testing.assert_allclose(cam.forward, [0, 1, 0], atol=1e-12)
  np.testing.assert_allclose(cam.up, [0, 0, 1], atol=1e-12)
  assert cam.fovy == 45 and cam.aspect == 640 / 480
  uv, depth = cam.project([0, 0, 1])  # straight ahead: the image centre
  np.testing.assert_allclose(uv, [0.5, 0.5]) and np.testing.assert_allclose(depth, 4)
  uv, _ = cam.project([0, 0, 1 + 4 * np.tan(np.radians(22.5))])  # top edge
  np.testing.assert_allclose(uv, [0.5, 0.0], atol=1e-12)


def test_aabb_frustum():
  f = Frustum.box([0, 0, 0], [1, 2, 3])
  assert f.contains([[0, 0, 0], [1, 2, 3], [0.5, 1, 1.5]]).all()
  assert not f.contains([[1.01, 0, 0]]).any()
  assert f.contains([[1.01, 0, 0]], radius=0.02).all()


@pytest.mark.parametrize("make, message", [
    (lambda: ScreenBox(0.6, 0, 0.5, 1), "u0 <= u1"),
    (lambda: ScreenBox(0, float("nan"), 1, 1), "finite"),
    (lambda: Camera.look_at([0, 0, 0], [0, 0, 0]), "coincide"),
    (lambda: Camera.look_at([0, 0, 0], [0, 0, 1]), "parallel"),
    (lambda: Camera.look_at([0, 0, 0], [1, 0, 0], fovy=190), "fovy"),
    (lambda: Camera.look_at([0, 0, 0], [1, 0, 0]).frustum(ScreenBox(0, 0, 1, 1), 2, 1), "near"),
    (lambda: Frustum.box([0, 0, 1], [1, 1, 0]), "empty"),
    (lambda: Camera.from_model(mujoco.MjModel.from_xml_string(queries_bank.scene_xml(2)), "top"),
     "no MJCF camera named 'top'"),
])
def test_user_errors_are_clear(make, message):
  with pytest.raises(MwbxError, match=message):
    make()
