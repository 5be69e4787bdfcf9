"""Every geom type MuJoCo has draws in the meshcat viewer and in the browsing
page (viser), with the size, place and orientation MuJoCo gives it."""

import math
import pathlib

import jax
import meshcat
import meshcat.commands
import mujoco
import numpy as np
import pytest
import umsgpack

import mwbx
from mwbx.browser import app
from mwbx.browser import scene as page_scene
from mwbx import viewer
from mwbx.viewer import geometry

TET_OBJ = "v 0 0 0\nv 0.2 0 0\nv 0 0.1 0\nv 0 0 0.3\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"

MJCF = """<mujoco model="every geom">
  <option timestep="0.002"/>
  <extension>
    <plugin plugin="mujoco.sdf.torus">
      <instance name="torus"><config key="radius1" value="0.2"/><config key="radius2" value="0.05"/></instance>
    </plugin>
  </extension>
  <asset>
    <mesh name="tet" file="tet.obj"/>
    <mesh name="torus"><plugin instance="torus"/></mesh>
    <hfield name="bumps" nrow="4" ncol="5" size="0.6 0.4 0.2 0.05"
            elevation="0 0 0 0 0  0 0.5 1 0.2 0  0 0.3 0.7 0 0  0 0 0 0 0.9"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="3 2 0.1"/>
    <geom name="endless" type="plane" size="0 0 1" pos="0 0 -1"/>
    <geom name="bumps" type="hfield" hfield="bumps" pos="2 0 0" euler="0 0 30"/>
    <geom name="torus" type="sdf" mesh="torus" pos="-2 0 0.3" contype="0" conaffinity="0">
      <plugin instance="torus"/>
    </geom>
    <body name="ball" pos="0 0 1"><freejoint/><geom name="ball" type="sphere" size="0.07"/></body>
    <body name="pill" pos="0.5 0 1" euler="20 30 0"><freejoint/>
      <geom name="pill" type="capsule" size="0.04 0.12"/></body>
    <body name="egg" pos="1 0 1" euler="0 40 10"><freejoint/>
      <geom name="egg" type="ellipsoid" size="0.05 0.08 0.11"/></body>
    <body name="can" pos="-0.5 0 1" euler="50 0 0"><freejoint/>
      <geom name="can" type="cylinder" size="0.06 0.15"/></body>
    <body name="crate" pos="-1 0 1" euler="10 20 30"><freejoint/>
      <geom name="crate" type="box" size="0.05 0.1 0.15"/></body>
    <body name="shard" pos="0 0.6 1"><freejoint/><geom name="shard" type="mesh" mesh="tet"/></body>
    <body name="arm" pos="0 -0.8 1">
      <joint type="hinge" axis="0 1 0"/>
      <geom name="upper" type="cylinder" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="forearm" pos="0.3 0 0"><joint type="hinge" axis="0 1 0"/>
        <geom name="lower" type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/></body>
    </body>
  </worldbody>
</mujoco>
"""

T = mujoco.mjtGeom
EVERY_TYPE = {T.mjGEOM_PLANE, T.mjGEOM_HFIELD, T.mjGEOM_SPHERE, T.mjGEOM_CAPSULE, T.mjGEOM_ELLIPSOID,
              T.mjGEOM_CYLINDER, T.mjGEOM_BOX, T.mjGEOM_MESH, T.mjGEOM_SDF}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> pathlib.Path:
  folder = tmp_path_factory.mktemp("every_geom")
  (folder / "tet.obj").write_text(TET_OBJ)
  (folder / "model.xml").write_text(MJCF)
  (folder / "cfg.yaml").write_text("scene: {mjcf: model.xml}\nsim: {end_time: 0.2}\n")
  return folder


@pytest.fixture(scope="module")
def model(scene_dir) -> mujoco.MjModel:
  return mujoco.MjModel.from_xml_path(str(scene_dir / "model.xml"))


@pytest.fixture(scope="module")
def bank(scene_dir):
  return mwbx.sample(mwbx.load_config(scene_dir / "cfg.yaml"), n_worlds=2, key=jax.random.key(0),
                     backend="native")


def geom_frame_triangles(model, g):
  """(f64[V, 3] vertices in the MuJoCo geom's frame, i32[F, 3]) as both views draw it."""
  shape, fix = geometry.geom_shape(model, g, plane_extent=5.0)
  verts, faces = page_scene._mesh(shape)  # the browsing page's conversion of the meshcat geometry
  return np.asarray(verts, np.float64) @ fix[:3, :3].T + fix[:3, 3], faces


def signed_volume(verts, faces) -> float:
  a, b, c = (verts[faces[:, i]] for i in range(3))
  return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_the_model_has_every_geom_type(model):
  assert set(int(t) for t in model.geom_type) == {int(t) for t in EVERY_TYPE}


def test_every_geom_draws_where_mujoco_puts_it(model):
  visuals = geometry.scene_visuals(model)
  assert sorted(v.geom_id for v in visuals) == list(range(model.ngeom))  # nothing skipped
  for g in range(model.ngeom):
    verts, faces = geom_frame_triangles(model, g)
    assert verts.shape[1] == 3 and faces.shape[1] == 3 and faces.max() < verts.shape[0]
    assert np.all(np.isfinite(verts))
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    if model.geom_type[g] == T.mjGEOM_PLANE:
      half = model.geom_size[g, :2] if model.geom_size[g, 0] > 0 else [5.0, 5.0]
      np.testing.assert_allclose(hi[:2], half) and np.testing.assert_allclose(lo[:2], -np.asarray(half))
      np.testing.assert_allclose([lo[2], hi[2]], [-geometry.PLANE_THICKNESS, 0.0], atol=1e-9)
      continue
    # The box MuJoCo bounds the geom with, in the geom's own frame.
    centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
    np.testing.assert_allclose(lo, centre - half, atol=0.01 * half.max() + 1e-6, err_msg=model.geom(g).name)
    np.testing.assert_allclose(hi, centre + half, atol=0.01 * half.max() + 1e-6, err_msg=model.geom(g).name)
    assert signed_volume(verts, faces) > 0, model.geom(g).name  # closed, faces outward


@pytest.mark.parametrize("name, volume", [
    ("ball", 4 / 3 * math.pi * 0.07 ** 3),
    ("egg", 4 / 3 * math.pi * 0.05 * 0.08 * 0.11),
    ("can", math.pi * 0.06 ** 2 * 0.3),
    ("crate", 0.1 * 0.2 * 0.3),
    ("pill", math.pi * 0.04 ** 2 * 0.24 + 4 / 3 * math.pi * 0.04 ** 3),
    ("shard", 0.2 * 0.1 * 0.3 / 6),
])
def test_primitives_have_their_volume(model, name, volume):
  verts, faces = geom_frame_triangles(model, model.geom(name).id)
  assert signed_volume(verts, faces) == pytest.approx(volume, rel=0.04)


def test_cylinder_keeps_radius_and_length_along_its_axis(model):
  g = model.geom("can").id
  shape, fix = geometry.geom_shape(model, g, plane_extent=5.0)
  lowered = meshcat.commands.SetObject(shape, geometry.material(geometry.geom_rgba(model, g)), "/can").lower()
  spec = lowered["object"]["geometries"][0]
  assert spec["type"] == "CylinderGeometry"
  assert spec["radiusTop"] == spec["radiusBottom"] == pytest.approx(0.06) and spec["height"] == pytest.approx(0.3)
  verts, _ = geom_frame_triangles(model, g)
  np.testing.assert_allclose(verts[:, 2].min(), -0.15) and np.testing.assert_allclose(verts[:, 2].max(), 0.15)
  np.testing.assert_allclose(np.hypot(verts[:, 0], verts[:, 1]).max(), 0.06, rtol=1e-6)


def test_height_field_follows_mujoco_collision_surface(model):
  # A ray straight down onto the height field hits it at the drawn height.
  g = model.geom("bumps").id
  data = mujoco.MjData(model)
  mujoco.mj_forward(model, data)
  verts, faces = geom_frame_triangles(model, g)
  top = verts[:verts.shape[0] // 2]  # the top grid, then the bottom copy
  rot, pos = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
  geomid = np.zeros(1, np.int32)
  hits = 0
  for v in top:
    # 2% towards the middle (MuJoCo's ray misses the very rim); the slopes
    # change the height there by less than 0.015 m.
    local = np.array([v[0] * 0.98, v[1] * 0.98, 0.0])
    start = pos + rot @ (local + [0, 0, 1.0])
    dist = mujoco.mj_ray(model, data, start, -rot[:, 2], None, 1, -1, geomid)
    if geomid[0] == g:
      hits += 1
      assert 1.0 - dist == pytest.approx(v[2], abs=0.015), v
  assert hits == top.shape[0]
  assert top[:, 2].max() == pytest.approx(model.hfield_size[0, 2])


def test_large_height_field_is_drawn_coarser_with_its_corners(model):
  verts, faces = geometry.hfield_mesh(model, 0, max_vertices=6)
  assert verts.shape[0] < 2 * 20 and signed_volume(verts.astype(np.float64), faces) > 0
  for corner in ([-0.6, -0.4], [0.6, 0.4], [0.6, -0.4], [-0.6, 0.4]):
    assert np.any(np.all(np.isclose(verts[:, :2], corner), axis=1))


def test_unknown_geometry_is_a_clear_error():
  class Odd(meshcat.geometry.Geometry):
    pass
  with pytest.raises(mwbx.MwbxError, match="Odd"):
    page_scene._mesh(Odd())


def test_bank_of_every_geom_opens_in_the_viewer_and_the_page(bank):
  assert bank.record_fps == 125.0  # the MJCF's 0.002 s step, 4 steps a frame
  vis = meshcat.Visualizer(window=viewer.SceneRecorder())
  viewer.draw(vis, bank, worlds=[int(bank.world_ids[0])])
  drawn = [umsgpack.unpackb(blob) for blob in vis.window.command_blobs()]
  kinds = {o["object"]["geometries"][0]["type"] for o in drawn if o["type"] == "set_object"
           and o["object"].get("geometries")}
  assert {"BoxGeometry", "SphereGeometry", "CylinderGeometry", "BufferGeometry"} <= kinds
  names = " ".join(o["path"] for o in drawn if o["type"] == "set_object")
  for g in range(bank.model.ngeom):
    assert f"g{g}_" in names, bank.model.geom(g).name
  browser = app.browse(bank, block=False)
  try:
    drawn = {v.geom_id for v in browser.visuals}
    assert drawn == set(range(browser.model.ngeom))
    moving = {name for body in browser.moving.values() for name, *_ in body}
    assert any(name.endswith("_can") for name in moving) and any(name.endswith("_egg") for name in moving)
  finally:
    browser.close()
