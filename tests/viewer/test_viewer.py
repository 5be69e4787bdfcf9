"""Viewer kernels against slow, obvious references, and the drawing API on a
small bank (no browser here: see test_viewer_browser.py)."""

from __future__ import annotations

import base64
import re
import warnings

import hypothesis.extra.numpy as hnp
import mujoco
import numpy as np
import pytest
import umsgpack
from hypothesis import given, settings
from hypothesis import strategies as st

with warnings.catch_warnings():
  warnings.simplefilter("ignore", DeprecationWarning)
  import meshcat

import mwbx.viewer as mv
from mwbx.viewer import display, geometry, hull, kinematics, playback
from viewer_banks import quickstart_bank
from mwbx.testing.standin import STANDIN_XML, make_standin_bank

FAST = settings(max_examples=int(__import__("os").environ.get("VIEWER_EXAMPLES", 40)), deadline=None)


@pytest.fixture(scope="module")
def bank():
  return make_standin_bank(n_worlds=6, unstable=[5])


@pytest.fixture(scope="module")
def model():
  return mujoco.MjModel.from_xml_string(STANDIN_XML)


# ---------------------------------------------------------------- geometry


def _point_segment_distance(p, a, b):
  t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
  return np.linalg.norm(p - (a + t * (b - a)))


@FAST
@given(radius=st.floats(0.005, 2.0), half=st.floats(0.001, 3.0),
       n_around=st.integers(3, 32), n_cap=st.integers(1, 10))
def test_capsule_mesh_is_a_closed_outward_capsule(radius, half, n_around, n_cap):
  verts, faces = geometry.capsule_mesh(radius, half, n_around, n_cap)
  a, b = np.array([0, 0, -half]), np.array([0, 0, half])
  for v in verts.astype(np.float64):
    assert abs(_point_segment_distance(v, a, b) - radius) <= 1e-5 * max(radius, half)
  # Closed 2-manifold: every undirected edge is used by exactly two faces,
  # once in each direction (consistent orientation).
  directed = {}
  for f in faces:
    for i in range(3):
      e = (int(f[i]), int(f[(i + 1) % 3]))
      directed[e] = directed.get(e, 0) + 1
  for (i, j), n in directed.items():
    if i == j:
      continue
    assert n == 1 and directed.get((j, i)) == 1
  # Outward: positive signed volume, below the true volume (inscribed).
  tri = verts.astype(np.float64)[faces]
  volume = np.sum(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))) / 6
  exact = np.pi * radius**2 * (4 / 3 * radius + 2 * half)
  assert 0 < volume <= exact * (1 + 1e-5)


def test_geom_rgba_follows_mujoco_material_rule(model):
  for g in range(model.ngeom):
    rgba = np.asarray(model.geom_rgba[g])
    mat = model.geom_matid[g]
    expected = model.mat_rgba[mat] if mat >= 0 and np.allclose(rgba, [0.5, 0.5, 0.5, 1]) else rgba
    np.testing.assert_allclose(geometry.geom_rgba(model, g), expected, rtol=0, atol=1e-7)
  assert geometry.geom_rgba(model, model.geom("floor").id)[:3] == pytest.approx((0.85, 0.85, 0.8))


def test_scene_visuals_cover_every_type_and_pose(model):
  visuals = geometry.scene_visuals(model)
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  by_geom = {v.geom_id: v for v in visuals}
  hidden = model.geom("hidden_collider").id
  assert hidden not in by_geom  # group 3 is not drawn
  assert {int(model.geom_type[g]) for g in by_geom} == {int(t) for t in (
      mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_SPHERE,
      mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER,
      mujoco.mjtGeom.mjGEOM_ELLIPSOID, mujoco.mjtGeom.mjGEOM_MESH)}
  for g, v in by_geom.items():
    body = model.geom_bodyid[g]
    assert v.static == (body == 0)
    # Pose of the meshcat primitive in the world = body pose (identity for
    # static geoms) @ local; it must be MuJoCo's geom pose, except that
    # three.js cylinders lie along +y (turned +90 deg about x onto +z).
    body_pose = np.eye(4)
    if not v.static:
      body_pose = geometry.pose_matrix(data.xpos[body], data.xquat[body])
    world = body_pose @ v.local
    expected = data.geom_xmat[g].reshape(3, 3)
    if isinstance(v.geometry, meshcat.geometry.Cylinder):
      expected = expected @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    np.testing.assert_allclose(world[:3, :3], expected, atol=1e-9)
    offset = np.zeros(3)
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
      offset[2] = -geometry.PLANE_THICKNESS / 2
    np.testing.assert_allclose(world[:3, 3], data.geom_xpos[g] + data.geom_xmat[g].reshape(3, 3) @ offset,
                               atol=1e-9)
  moving = geometry.moving_body_ids(visuals)
  assert set(moving.tolist()) == {model.body(n).id for n in
                                  ("box", "ball", "pill", "can", "egg", "tetra", "arm_base", "arm_tip")}


def test_material_tint_and_opacity():
  rgba = geometry.Rgba(1.0, 0.0, 0.0, 1.0)
  opaque = geometry.material(rgba)
  assert opaque.color == 0xFF0000 and not opaque.transparent
  ghost = geometry.material(rgba, tint=geometry.Rgba(0.0, 0.0, 1.0, 1.0), tint_weight=0.5, opacity=0.4)
  assert ghost.color == 0x800080 and ghost.transparent and ghost.opacity == pytest.approx(0.4)


# ---------------------------------------------------------------- kinematics


def test_body_trajectories_match_mj_forward(bank, model):
  qpos = bank.qpos_frames(0)
  body_ids = np.asarray(bank.body_ids)
  pos, quat = kinematics.body_trajectories(model, qpos, body_ids)
  data = mujoco.MjData(model)
  for t in range(0, qpos.shape[0], 7):
    data.qpos[:] = qpos[t]
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(pos[t], data.xpos[body_ids], atol=1e-9)
    dots = np.abs(np.sum(quat[t] * data.xquat[body_ids], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)  # same rotation, maybe other sign
  with pytest.raises(mv.ViewerError, match="nq"):
    kinematics.body_trajectories(model, qpos[:, :-1], body_ids)


@FAST
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 30), st.integers(1, 3), st.just(4)),
                  elements=st.floats(-1, 1)))
def test_continuous_quaternions_only_flip_signs(quat):
  out = kinematics.continuous_quaternions(quat)
  for t in range(quat.shape[0]):
    for k in range(quat.shape[1]):
      assert np.array_equal(out[t, k], quat[t, k]) or np.array_equal(out[t, k], -quat[t, k])
  assert np.all(np.sum(out[1:] * out[:-1], axis=-1) >= 0)


def test_pad_frames_holds_last():
  x = np.arange(6.0).reshape(3, 2)
  np.testing.assert_array_equal(kinematics.pad_frames(x, 5)[3:], [[4, 5], [4, 5]])
  np.testing.assert_array_equal(kinematics.pad_frames(x, 2), x[:2])


# ---------------------------------------------------------------- paths


# ---------------------------------------------------------------- frustums


def _frustum(eye, forward_angles, near, far, half_w, half_h):
  """Corners of a perspective frustum, reference construction."""
  yaw, pitch = forward_angles
  f = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
  right = np.cross(f, [0, 0, 1.0])
  right /= np.linalg.norm(right)
  up = np.cross(right, f)
  out = []
  for depth in (near, far):
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
      out.append(eye + depth * (f + sx * half_w * right + sy * half_h * up))
  return np.asarray(out)


frustum_params = st.tuples(
    hnp.arrays(np.float64, 3, elements=st.floats(-5, 5)),
    st.tuples(st.floats(-3.1, 3.1), st.floats(-1.2, 1.2)),
    st.floats(0.05, 2.0), st.floats(1.0, 10.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0))


@FAST
@given(frustum_params)
def test_hull_mesh_and_eye_of_random_frustums(params):
  eye, angles, near, extra, hw, hh = params
  corners = _frustum(eye, angles, near, near + extra, hw, hh)
  verts, faces, edges = hull.hull_mesh(corners)
  assert faces.shape == (12, 3) and edges.shape == (12, 2)
  centre = corners.mean(axis=0)
  for f in faces:
    a, b, c = corners[f]
    normal = np.cross(b - a, c - a)
    assert np.dot(normal, a - centre) > 0  # outward
    assert np.all((corners - a) @ normal <= 1e-7 * np.linalg.norm(normal) * 10)  # supporting plane
  # The 12 frustum edges: 4 near, 4 far, 4 sides (near i - far i).
  expected = {tuple(sorted(e)) for e in [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7),
                                         (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]}
  assert {tuple(e) for e in edges.tolist()} == expected
  np.testing.assert_allclose(hull.frustum_eye(corners), eye, atol=1e-6 * (1 + np.abs(eye).max()))


def test_orthographic_box_has_no_eye_and_flat_frustum_is_an_error():
  box = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                  [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
  assert hull.frustum_eye(box) is None
  flat = box.copy()
  flat[:, 2] = 0  # a zero-height screen box: a flat wedge, drawn as a polygon
  _, faces, edges = hull.hull_mesh(flat)
  assert faces.shape == (2, 3) and edges.shape == (4, 2)
  line = np.zeros((8, 3))
  line[:, 0] = np.arange(8)
  with pytest.raises(mv.ViewerError, match="query 3: frustum is empty"):
    hull.hull_mesh(line, index=3)


@FAST
@given(frustum_params, st.floats(0.01, 5.0))
def test_truncate_keeps_far_face_parallel(params, depth):
  eye, angles, near, extra, hw, hh = params
  corners = _frustum(eye, angles, near, near + extra, hw, hh)
  cut = hull.truncate(corners, depth)
  np.testing.assert_array_equal(cut[:4], corners[:4])
  longest = np.linalg.norm(corners[4:] - corners[:4], axis=1).max()
  if longest <= depth:
    np.testing.assert_array_equal(cut, corners)
  else:
    assert np.linalg.norm(cut[4:] - cut[:4], axis=1).max() == pytest.approx(depth, rel=1e-9)
  # Still a frustum of the same camera: side edges meet at the eye.
  np.testing.assert_allclose(hull.frustum_eye(cut), eye, atol=1e-5 * (1 + np.abs(eye).max()))


def test_as_volume_accepts_pairs_and_mwbx_queries():
  from mwbx import queries as mq

  corners = _frustum(np.zeros(3), (0.0, 0.0), 0.5, 2.0, 0.2, 0.1)
  assert display.as_volume((corners, False)).include is False
  camera = mq.Camera.look_at(eye=[0.0, -2.0, 1.0], target=[0.0, 0.0, 0.5])
  query = mq.Query.screen(camera, [0.4, 0.4, 0.6, 0.6], sign="exclude")
  vol = display.as_volume(query)
  assert not vol.include
  np.testing.assert_allclose(vol.eye, camera.eye)
  np.testing.assert_allclose(hull.frustum_eye(vol.corners), camera.eye, atol=1e-6)
  box = display.as_volume(mq.Query.region([0, 0, 0], [1, 2, 3]))
  assert box.include and box.eye is None and hull.frustum_eye(box.corners) is None
  planes_only = mq.Frustum.from_planes(np.vstack([np.eye(3), -np.eye(3)]), [1, 2, 3, 0, 0, 0])
  vol = display.as_volume(mq.VolumeQuery(planes_only))
  assert sorted(map(tuple, vol.corners.tolist())) == sorted(
      (x, y, z) for x in (0.0, 1.0) for y in (0.0, 2.0) for z in (0.0, 3.0))
  with pytest.raises(mv.ViewerError, match="query 2: frustum corners must be finite"):
    display.as_volume((corners[:3], True), index=2)
  with pytest.raises(mv.ViewerError, match="query 0: expected"):
    display.as_volume("not a query")


@FAST
@given(hnp.arrays(np.float64, st.tuples(st.integers(4, 14), st.just(3)), elements=st.floats(-3, 3)))
def test_hull_mesh_matches_scipy(points):
  scipy_spatial = pytest.importorskip("scipy.spatial")
  try:
    reference = scipy_spatial.ConvexHull(points)
  except scipy_spatial.QhullError:
    return  # flat or degenerate input: covered by the explicit flat test
  if reference.volume < 1e-3:
    return  # nearly flat: the tolerances of the two differ
  _, faces, _ = hull.hull_mesh(points)
  tri = points[faces]
  volume = np.sum(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))) / 6
  assert volume == pytest.approx(reference.volume, rel=1e-6)  # outward and closed
  used = points[np.unique(faces)]
  tol = 1e-9 * np.ptp(points, axis=0).max()
  normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
  normals /= np.linalg.norm(normals, axis=1, keepdims=True)
  for v in points[reference.vertices]:  # every extreme point is used (up to tolerance) ...
    if np.min(np.abs(used - v).max(axis=1)) <= tol:
      continue
    # ... or lies on a face: Qhull keeps a point a hair off a face's plane as a vertex.
    dist = np.einsum("ij,ij->i", normals, v - tri[:, 0])
    assert dist.max() <= 1e-6 * np.ptp(points, axis=0).max() and np.abs(dist).min() <= 1e-6, (v, dist)


# ---------------------------------------------------------------- recorder and API


def _recorded(vis):
  """{(type, path): decoded command} of everything recorded in an offline window."""
  out = {}
  for blob in vis.window.command_blobs():
    cmd = umsgpack.unpackb(blob)
    out[(cmd["type"], cmd["path"])] = cmd
  return out


def _draw_offline(bank, **kw):
  vis = meshcat.Visualizer(window=mv.SceneRecorder())
  info = mv.draw(vis, bank, **kw)
  return vis, info


def test_animation_tracks_replay_forward_kinematics(bank, model):
  worlds = [0, 1]  # world 1 has a shorter recording
  vis, info = _draw_offline(bank, worlds=worlds, layout="overlay")
  cmds = _recorded(vis)
  anim = cmds[("set_animation", "")]
  clips = {a["path"]: a["clip"] for a in anim["animations"]}
  n_frames = int(np.max(bank.frame_count[worlds]))
  body = model.body("arm_tip").id
  for w in worlds:
    clip = clips[f"/meshcat/mwbx/worlds/w{w}/arm_tip"]
    assert clip["fps"] == bank.record_fps
    tracks = {t["name"]: t for t in clip["tracks"]}
    keys_pos, keys_quat = tracks[".position"]["keys"], tracks[".quaternion"]["keys"]
    assert len(keys_pos) == n_frames and [k["time"] for k in keys_pos] == list(range(n_frames))
    data = mujoco.MjData(model)
    qpos = bank.qpos_frames(w)
    for t in (0, 5, n_frames - 1):
      data.qpos[:] = qpos[min(t, qpos.shape[0] - 1)]
      mujoco.mj_kinematics(model, data)
      np.testing.assert_allclose(keys_pos[t]["value"], data.xpos[body], atol=1e-9)
      x, y, z, w_ = keys_quat[t]["value"]
      assert abs(np.dot([w_, x, y, z], data.xquat[body])) == pytest.approx(1.0, abs=1e-9)
  # Static scene drawn once in overlay layout; ghost worlds translucent.
  assert ("set_object", "/meshcat/mwbx/worlds/static/g0_floor") in cmds
  ghost = cmds[("set_object", "/meshcat/mwbx/worlds/w1/box/g3")]["object"]["materials"][0]
  assert ghost["transparent"] and ghost["opacity"] < 1
  first = cmds[("set_object", "/meshcat/mwbx/worlds/w0/box/g3")]["object"]["materials"][0]
  assert ghost["color"] == first["color"]  # a ghost keeps its body's colour
  np.testing.assert_array_equal(info.offsets, 0)


def test_grid_layout_separates_worlds(bank):
  vis, info = _draw_offline(bank, worlds=[0, 2, 3, 4], layout="grid")
  cmds = _recorded(vis)
  assert info.offsets.shape == (4, 3)
  gaps = np.linalg.norm(info.offsets[:, None, :2] - info.offsets[None, :, :2], axis=-1)
  span = np.ptp(np.asarray(bank.com)[[0, 2, 3, 4]].reshape(-1, 3)[:, :2], axis=0)
  assert np.all(gaps[~np.eye(4, dtype=bool)] >= span.max() * 0.99)
  for w in (0, 2, 3, 4):
    assert ("set_object", f"/meshcat/mwbx/worlds/w{w}/static/g0_floor") in cmds
    assert ("set_transform", f"/meshcat/mwbx/worlds/w{w}") in cmds


def test_grid_layout_draws_queries_and_a_label_on_every_tile(bank):
  corners = _frustum(np.array([0, -2.0, 0.5]), (np.pi / 2, 0.0), 0.5, 3.0, 0.2, 0.2)
  vis, info = _draw_offline(bank, worlds=[0, 2, 3], layout="grid", queries=[(corners, True)])
  cmds = _recorded(vis)
  for k, w in enumerate((0, 2, 3)):
    assert ("set_object", f"/meshcat/mwbx/queries/q0/w{w}/volume") in cmds
    shift = np.asarray(cmds[("set_transform", f"/meshcat/mwbx/queries/q0/w{w}")]["matrix"]).reshape(4, 4).T
    np.testing.assert_allclose(shift[:3, 3], info.offsets[k])  # the frustum moves with its tile
    label = cmds[("set_object", f"/meshcat/mwbx/worlds/w{w}/label")]["object"]
    assert label["textures"] and label["images"][0]["url"].startswith("data:image/png;base64,")
  assert ("set_object", "/meshcat/mwbx/queries/q0/volume") not in cmds


def test_label_png_shows_the_text():
  import io
  from PIL import Image
  a = np.asarray(Image.open(io.BytesIO(playback.label_png("world 7"))).convert("L"))
  b = np.asarray(Image.open(io.BytesIO(playback.label_png("world 8"))).convert("L"))
  assert a.shape == playback.LABEL_PIXELS[::-1] and (a < 128).mean() > 0.02 and not np.array_equal(a, b)


def test_paths_queries_and_shift(bank):
  corners = _frustum(np.array([0, -2.0, 0.5]), (np.pi / 2, 0.0), 0.5, 3.0, 0.2, 0.2)
  match = np.array([1, 1, 0, 0, 0, 1], bool)  # world 5 is unstable: never drawn
  exclude = np.array([0, 0, 1, 0, 0, 0], bool)
  vis, info = _draw_offline(bank, worlds=[], paths="round", match=match, exclude=exclude,
                            queries=[(corners, True), mv.DrawnVolume(corners + 0.1, False)])
  n_bodies = bank.select_bodies("round").size
  seg = lambda ws: sum((int(bank.com_count[w]) - 1) * n_bodies for w in ws)  # noqa: E731
  assert info.path_segments == {"faint": seg([3, 4]), "match": seg([0, 1]), "exclude": seg([2])}
  assert info.n_queries == 2 and info.worlds.size == 0
  cmds = _recorded(vis)
  for q, hexcol in (("q0", display.QUERY_RGBA["include"].hex()), ("q1", display.QUERY_RGBA["exclude"].hex())):
    mat = cmds[("set_object", f"/meshcat/mwbx/queries/{q}/volume")]["object"]["materials"][0]
    assert mat["color"] == hexcol and mat["transparent"]
    assert ("set_object", f"/meshcat/mwbx/queries/{q}/camera/eye") in cmds
  root = np.asarray(cmds[("set_transform", "/meshcat/mwbx")]["matrix"]).reshape(4, 4).T
  np.testing.assert_allclose(root[:3, 3], -info.centre)


def test_draw_errors_name_the_value(bank):
  vis = meshcat.Visualizer(window=mv.SceneRecorder())
  with pytest.raises(mv.ViewerError, match="layout must be one of .*'side'"):
    mv.draw(vis, bank, layout="side")
  with pytest.raises(mv.ViewerError, match="worlds: world 99: no world with this id"):
    mv.draw(vis, bank, worlds=[99])
  with pytest.raises(mv.ViewerError, match="world 5 is flagged unstable"):
    mv.draw(vis, bank, worlds=[5])
  with pytest.raises(mv.ViewerError, match="no MJCF camera named 'nope'"):
    mv.draw(vis, bank, camera="nope")
  with pytest.raises(ValueError, match="'wheel'"):
    mv.draw(vis, bank, paths=["wheel"])


def test_export_html_is_standalone(bank, tmp_path):
  out = mv.export_html(bank, tmp_path / "scene.html", worlds=[0, 2], paths=True)
  html = out.read_text()
  assert "MeshCat.Viewer" in html and "mwbx_loaded" in html
  assert "http://" not in html.split("<script>", 1)[0]  # no external resources in the head
  blobs = re.findall(r'"([A-Za-z0-9+/=]{40,})"', html)
  types = [umsgpack.unpackb(base64.b64decode(b))["type"] for b in blobs]
  assert types[-1] == "set_animation" and types.count("set_animation") == 1
  with pytest.raises(mv.ViewerError, match="does not exist"):
    mv.export_html(bank, tmp_path / "missing" / "scene.html")


def test_recorder_replays_what_the_meshcat_server_stores(bank):
  """The offline recorder keeps the same commands as a live meshcat server."""
  live = mv.view(bank, worlds=[0], paths="box")
  try:
    server_html = live.static_html()
    # A second visualizer connected to the same server redraws the scene.
    other = mv.view(bank, worlds=[2], zmq_url=live.window.zmq_url)
    assert other.window.server_proc is None
    redrawn = live.static_html()
  finally:
    live.window.server_proc.kill()
    live.window.server_proc.wait()
  assert live.url().startswith("http")
  paths_in = lambda html: {umsgpack.unpackb(base64.b64decode(b))["path"]  # noqa: E731
                           for b in re.findall(r'base64,([A-Za-z0-9+/=]+)"', html)}
  assert "/meshcat/mwbx/worlds/w2/box/g3" in paths_in(redrawn)
  assert not any("/worlds/w0/" in p for p in paths_in(redrawn))
  offline, _ = _draw_offline(bank, worlds=[0], paths="box")
  server_blobs = re.findall(r'base64,([A-Za-z0-9+/=]+)"', server_html)
  decoded = lambda blobs: sorted(  # noqa: E731
      (umsgpack.unpackb(b)["type"], umsgpack.unpackb(b)["path"]) for b in blobs)
  ours = decoded(offline.window.command_blobs())
  theirs = decoded(base64.b64decode(b) for b in server_blobs)
  # meshcat's own viewer adds nothing on the Python side; uuids differ per draw.
  assert ours == theirs


# ---------------------------------------------------------------- a real sampled bank


@pytest.fixture(scope="module")
def real_bank():
  return quickstart_bank(4)


def test_real_bank_with_screen_queries(real_bank, tmp_path):
  from mwbx import queries as mq

  model = real_bank.model
  camera = mq.Camera.from_model(model, "front")
  include = mq.Query.screen(camera, [0.0, 0.4, 1.0, 1.0], bodies="round")
  exclude = mq.Query.screen(camera, [0.0, 0.0, 0.45, 0.6], bodies="box_a", sign="exclude")
  flat = mq.Query.screen(camera, [0.5, 0.2, 0.5, 0.8], sign="exclude")  # zero-width wedge
  queries = [include, exclude, flat]
  vis, info = _draw_offline(real_bank, worlds=[0, 1], paths="round", queries=queries)
  each = mq.evaluate_each(real_bank, queries)
  match = each.all(axis=1)
  rejected = ~each[:, 1] | ~each[:, 2]
  n_bodies = real_bank.select_bodies("round").size
  seg = lambda ws: int(sum((real_bank.com_count[w] - 1) * n_bodies for w in ws))  # noqa: E731
  worlds = np.arange(real_bank.n_worlds)
  assert info.path_segments == {
      "faint": seg(worlds[~match & ~rejected]), "match": seg(worlds[match & ~rejected]),
      "exclude": seg(worlds[rejected])}
  assert info.n_queries == 3
  cmds = _recorded(vis)
  clips = {a["path"] for a in cmds[("set_animation", "")]["animations"]}
  ids = real_bank.world_ids
  assert clips == {f"/meshcat/mwbx/worlds/w{ids[w]}/{b}" for w in (0, 1) for b in real_bank.body_names}
  assert ("set_object", "/meshcat/mwbx/queries/q1/camera/eye") in cmds
  out = mv.export_html(real_bank, tmp_path / "real.html", worlds=[2], layout="grid", paths=True)
  assert out.stat().st_size > 100_000


# ---------------------------------------------------------------- mwbx view


@pytest.fixture(scope="module")
def bank_dir(real_bank, tmp_path_factory):
  out = tmp_path_factory.mktemp("bank") / "quick"
  real_bank.save(out)
  return out


def test_cli_view_writes_html_for_ranked_worlds(real_bank, bank_dir, tmp_path, capsys):
  from mwbx import cli
  from mwbx import queries as mq

  qfile = tmp_path / "q.yaml"
  qfile.write_text("camera: {mjcf: front}\nqueries:\n  - {box: [0, 0, 1, 1], bodies: [round]}\n")
  out = tmp_path / "view.html"
  rc = cli.main(["view", str(bank_dir), "--top", "2", "--rank", "path_length", "--queries", str(qfile),
                 "--html", str(out)])
  assert rc == 0 and out.stat().st_size > 100_000
  ids, _ = mq.rank(real_bank, "path_length",
                   match=mq.evaluate(real_bank, mq.load_queries(qfile, bank=real_bank).queries),
                   top=2)
  assert f"(worlds {', '.join(str(int(i)) for i in ids)})" in capsys.readouterr().out


def test_cli_view_top_without_a_rank_shows_what_mwbx_query_lists(real_bank, bank_dir, tmp_path, capsys):
  # Unranked: the first matching worlds in world order; no world matching
  # every query: the worlds meeting the most, said in one line.
  from mwbx import cli
  from mwbx import queries as mq
  out = tmp_path / "view.html"
  assert cli.main(["view", str(bank_dir), "--top", "2", "--html", str(out)]) == 0
  first = np.asarray(real_bank.world_ids)[np.flatnonzero(real_bank.valid)[:2]]
  assert f"(worlds {', '.join(str(int(i)) for i in first)})" in capsys.readouterr().out
  never = tmp_path / "never.yaml"
  never.write_text("queries:\n  - {region: {min: [50, 50, 50], max: [51, 51, 51]}, bodies: [round]}\n"
                   "  - {region: {min: [-50, -50, -50], max: [50, 50, 50]}, bodies: [round]}\n")
  assert cli.main(["view", str(bank_dir), "--top", "2", "--queries", str(never), "--html", str(out)]) == 0
  captured = capsys.readouterr()
  assert "no valid world meets every query; showing the worlds that meet the most" in captured.err
  met = np.sum(mq.evaluate_each(real_bank, mq.load_queries(never, bank=real_bank).queries), axis=1)
  shown = [int(i) for i in captured.out.split("(worlds ")[1].rstrip(")\n").split(", ")]
  assert all(met[real_bank.row_of(i)] == 1 for i in shown) and len(shown) == 2


@pytest.mark.parametrize("argv, message", [
    (["--worlds", "0,x"], "--worlds: 'x' is not a world id"),
    (["--worlds", "999"], "--worlds: world 999: no world with this id"),
    (["--worlds", "0", "--top", "1", "--rank", "path_length"], "--worlds cannot be combined with --top/--rank"),
    (["--top", "0"], "--top: must be a positive number of worlds, got 0"),
    (["--paths", "nonexistent"], "nonexistent"),
])
def test_cli_view_errors_are_one_line(bank_dir, tmp_path, capsys, argv, message):
  from mwbx import cli

  rc = cli.main(["view", str(bank_dir), *argv, "--html", str(tmp_path / "x.html")])
  err = capsys.readouterr().err
  assert rc == 2 and message in err and err.count("\n") == 1


@pytest.mark.parametrize("kwargs, message", [
    (dict(ids=[0], top=1), "ids cannot be combined with top/rank"),
    (dict(ids=[999]), "ids: world 999: no world with this id"),
    (dict(top=0), "top: must be a positive number of worlds, got 0"),
])
def test_choose_worlds_from_python_names_its_parameters(real_bank, kwargs, message):
  # Its messages named the flags of `mwbx view` (--worlds, --top) to Python callers.
  with pytest.raises(mv.ViewerError) as err:
    mv.choose_worlds(real_bank, **kwargs)
  assert str(err.value).startswith(message) and "--" not in str(err.value), str(err.value)


def _gone(pid: int) -> bool:
  import os
  return not os.path.exists(f"/proc/{pid}") or open(f"/proc/{pid}/stat").read().split()[2] == "Z"


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGKILL"])
def test_cli_view_server_goes_with_its_parent(bank_dir, how):
  """`mwbx view` keeps its meshcat server up and prints the URL; Ctrl-C or
  SIGTERM stop it, and a parent killed outright takes the server with it."""
  import signal
  import subprocess
  import sys
  import time

  proc = subprocess.Popen([sys.executable, "-m", "mwbx.cli", "view", str(bank_dir), "--worlds", "0",
                           "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          # the suite may run with SIGINT ignored (nohup, background jobs)
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  children = []
  try:
    lines = []
    deadline = time.monotonic() + 300  # a loaded machine starts slowly
    while time.monotonic() < deadline:
      line = proc.stderr.readline()
      lines.append(line)
      if "Ctrl-C stops it" in line or not line:
        break
    assert any("showing worlds 0 at http" in ln for ln in lines), lines
    children = [int(c) for c in open(f"/proc/{proc.pid}/task/{proc.pid}/children").read().split()]
    assert children, "no meshcat server subprocess"
    proc.send_signal(getattr(signal, how))
    code = proc.wait(timeout=300)
    assert code == (-9 if how == "SIGKILL" else 0)
    deadline = time.monotonic() + 60
    while not all(_gone(c) for c in children) and time.monotonic() < deadline:
      time.sleep(0.1)
    assert all(_gone(c) for c in children), f"server {children} outlived {how} of its parent"
  finally:
    if proc.poll() is None:
      proc.kill()
      proc.wait()
    for child in children:
      if not _gone(child):
        import os
        os.kill(child, signal.SIGKILL)


def test_live_view_close_stops_its_server(real_bank):
  import mwbx.viewer as mv
  with mv.view(real_bank, worlds=[int(real_bank.world_ids[0])]) as vis:
    proc = vis.server_proc
    assert proc.poll() is None and vis.url().startswith("http")
  assert proc.poll() is not None
  vis.close()  # idempotent


def test_queries_accepts_one_query_or_a_query_set(real_bank, tmp_path):
  from mwbx import queries as mq

  qfile = tmp_path / "q.yaml"
  qfile.write_text("camera: {mjcf: front}\nqueries:\n  - {box: [0, 0, 0.5, 1]}\n"
                   "  - {box: [0.5, 0, 1, 1], sign: exclude}\n")
  qset = mq.load_queries(qfile, bank=real_bank)
  for queries, n in ((qset, 2), (qset.queries[0], 1), (qset.queries, 2)):
    _, info = _draw_offline(real_bank, worlds=[], paths=True, queries=queries)
    assert info.n_queries == n
  corners = _frustum(np.zeros(3), (0.0, 0.0), 0.5, 2.0, 0.2, 0.1)
  _, info = _draw_offline(real_bank, worlds=[], queries=(corners, True))
  assert info.n_queries == 1


def test_scene_bounds_cover_static_boxes_and_moving_bodies(bank, model):
  from mwbx.viewer import framing

  worlds = np.array([0, 2])
  lo, hi = framing.scene_bounds(bank, model, worlds, None, None)
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  ramp = model.geom("ramp").id
  # Reference: the ramp's 8 corners one by one, and every body's COM +- its geom radius.
  size = model.geom_size[ramp]
  for sx in (-1, 1):
    for sy in (-1, 1):
      for sz in (-1, 1):
        p = data.geom_xpos[ramp] + data.geom_xmat[ramp].reshape(3, 3) @ (size * [sx, sy, sz])
        assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9)
  com = np.asarray(bank.com)[worlds].reshape(-1, 3)
  r = max(model.geom_rbound[g] for g in range(model.ngeom) if model.body_weldid[model.geom_bodyid[g]])
  assert np.all(com.min(axis=0) - r >= lo - 1e-6) and np.all(com.max(axis=0) + r <= hi + 1e-6)
  hidden = data.geom_xpos[model.geom("hidden_collider").id]  # group 3: not shown, not framed
  assert hidden[2] > hi[2]


@FAST
@given(st.integers(1, 12), hnp.arrays(np.float64, 3, elements=st.floats(0.05, 5.0)),
       st.floats(-np.pi, np.pi), st.floats(0.05, 1.4))
def test_grid_cells_never_overlap(n, size, yaw, pitch):
  direction = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
  lo, hi = -size / 2, size / 2
  grid = playback.make_grid(n, lo, hi, direction)
  offsets = playback.grid_offsets(n, grid)
  corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
  # Separating-axis reference: two translated copies of the box are apart when
  # their projections on the column or the row axis are apart.
  for i in range(n):
    for j in range(i + 1, n):
      apart = False
      for axis in (grid.col_axis, grid.row_axis):
        a, b = corners @ axis + offsets[i] @ axis, corners @ axis + offsets[j] @ axis
        apart |= a.max() < b.min() or b.max() < a.min()
      assert apart
  # Columns run across the view (perpendicular to it, horizontal).
  assert abs(grid.col_axis @ direction) < 1e-9 and abs(grid.col_axis[2]) < 1e-9
  # Extents below 0.2 m count as 0.2 m (tiny scenes still get usable cells).
  tall = max(size[2], 0.2) > max(np.ptp(corners @ np.cross([0, 0, 1.0], grid.col_axis)), 0.2)
  assert np.allclose(grid.row_axis, [0, 0, -1]) == tall


def test_orientation_queries_colour_the_worlds_they_reject(real_bank):
  """An exclude orientation query makes the worlds it rejects red, an include
  one leaves only the worlds it holds in as matches (viewer colour classes)."""
  from mwbx import queries as mq
  from mwbx.viewer import query_adapter

  upright = mq.OrientationQuery(bodies="box_a", axis=(0.0, 0.0, 1.0), within_deg=20.0)
  tilted = mq.OrientationQuery(bodies="box_a", axis=(0.0, 0.0, 1.0), within_deg=20.0, sign="exclude")
  held = np.asarray(mq.evaluate_each(real_bank, [upright]), bool)[:, 0]
  valid = np.asarray(real_bank.valid, bool)
  match, exclude = query_adapter.evaluate_classes(real_bank, [upright])
  assert match.tolist() == (held & valid).tolist() and not exclude.any()
  match, exclude = query_adapter.evaluate_classes(real_bank, [tilted])
  assert exclude.tolist() == (held & valid).tolist()
  assert match.tolist() == (~held & valid).tolist()
