"""mwbx.export: a world to npz (exact decoded qpos and FK poses), USD (poses
read back with usd-core within the codec's bounds, one prim per geom, MJCF
materials) and mp4 (offscreen MuJoCo rendering read back with imageio-ffmpeg)."""

import math
import sys
import warnings

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.export import export_npz
from mwbx.export import export_usd
from mwbx.export import render_video
from mwbx.export import world_poses
from mwbx.export import poses as poses_lib
from mwbx.export import usd as usd_lib
from mwbx.export import video as video_lib

pxr = pytest.importorskip("pxr", reason="usd-core is the `export` extra (pip install 'mwbx[export]')")
from pxr import Usd, UsdGeom, UsdShade  # noqa: E402

TET_OBJ = "v 0 0 0\nv 0.2 0 0\nv 0 0.1 0\nv 0 0 0.3\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"

# Every primitive USD has, a mesh, a hinge chain, MJCF materials and a camera.
MJCF = """<mujoco model="export shapes">
  <option timestep="0.002"/>
  <asset>
    <mesh name="tet" file="tet.obj"/>
    <material name="red" rgba="0.8 0.1 0.1 1" shininess="0.3"/>
    <material name="blue" rgba="0.1 0.2 0.9 1"/>
  </asset>
  <worldbody>
    <camera name="side" pos="0 -3 1" xyaxes="1 0 0 0 0.3 1"/>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="3 2 0.1" material="blue"/>
    <body name="ball" pos="0 0 1"><freejoint/><geom name="ball" type="sphere" size="0.07" material="red"/></body>
    <body name="pill" pos="0.5 0 1" euler="20 30 0"><freejoint/>
      <geom name="pill" type="capsule" size="0.04 0.12" rgba="0 1 0 1" material="red"/></body>
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
CONFIG = "scene: {mjcf: model.xml}\nsim: {end_time: 0.6, backend: native}\n"


@pytest.fixture(scope="module")
def bank(tmp_path_factory):
  folder = tmp_path_factory.mktemp("export_scene")
  (folder / "tet.obj").write_text(TET_OBJ)
  (folder / "model.xml").write_text(MJCF)
  (folder / "cfg.yaml").write_text(CONFIG)
  return mwbx.sample(mwbx.load_config(folder / "cfg.yaml"), n_worlds=2, key=jax.random.key(0))


def reference_poses(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Plain forward kinematics, frame by frame: (xpos f64[T, nbody, 3], xquat f64[T, nbody, 4])."""
  data = mujoco.MjData(model)
  xpos, xquat = [], []
  for q in np.asarray(qpos, np.float64):
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    xpos.append(data.xpos.copy())
    xquat.append(data.xquat.copy())
  return np.array(xpos), np.array(xquat)


def angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
  """Rotation angle, rad, between unit wxyz quaternions f[..., 4]."""
  dot = np.abs(np.sum(q1 * q2, axis=-1))
  return 2 * np.arccos(np.clip(dot, 0.0, 1.0))


def test_npz_holds_the_decoded_qpos_exactly_and_its_forward_kinematics(bank, tmp_path):
  world = int(bank.world_ids[1])
  path = export_npz(bank, world, tmp_path / "w.npz")
  out = np.load(path)
  qpos = bank.qpos_frames(world)
  assert out["qpos"].dtype == np.float32
  np.testing.assert_array_equal(out["qpos"], qpos)
  model = bank.model
  xpos, xquat = reference_poses(model, qpos)
  np.testing.assert_allclose(out["xpos"], xpos, rtol=0, atol=1e-12)
  assert np.all(angle_between(out["xquat"], xquat) < 1e-6)
  np.testing.assert_array_equal(out["times"], np.arange(len(qpos)) / bank.record_fps)
  np.testing.assert_array_equal(out["frames"], np.arange(len(qpos)))
  assert list(out["body_names"]) == [model.body(b).name or f"body{b}" for b in range(model.nbody)]
  assert out["present"].all() and out["present"].shape == (len(qpos), model.nbody)
  assert float(out["fps"]) == bank.record_fps and int(out["world"]) == world


def test_usd_poses_match_the_decoded_poses_within_the_codec_bounds(bank, tmp_path):
  world = int(bank.world_ids[0])
  path = export_usd(bank, world, tmp_path / "w.usda")
  stage = Usd.Stage.Open(str(path))
  model = bank.model
  qpos = bank.qpos_frames(world)
  xpos, xquat = reference_poses(model, qpos)
  assert stage.GetTimeCodesPerSecond() == bank.record_fps
  assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, len(qpos) - 1)
  assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
  bounds = bank.qpos_store.bounds
  bodies = {p.GetCustomDataByKey("mujoco:body_id"): p for p in stage.Traverse()
            if p.GetCustomDataByKey("mujoco:body_id") is not None}
  assert sorted(bodies) == list(range(1, model.nbody))
  data = mujoco.MjData(model)
  for frame in (0, 17, len(qpos) // 2, len(qpos) - 1):
    for b, prim in bodies.items():
      matrix = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(float(frame))
      assert np.max(np.abs(np.array(matrix.ExtractTranslation()) - xpos[frame, b])) <= bounds.e_pos
      q = matrix.ExtractRotationQuat()
      usd_quat = np.array([q.GetReal(), *q.GetImaginary()])
      assert angle_between(usd_quat, xquat[frame, b]) <= bounds.e_rot
    # Geoms: where USD puts each one's origin is where MuJoCo does.
    data.qpos[:] = qpos[frame]
    mujoco.mj_kinematics(model, data)
    for prim in stage.Traverse():
      g = prim.GetCustomDataByKey("mujoco:geom_id")
      if g is not None:
        origin = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(float(frame)).Transform((0, 0, 0))
        assert np.max(np.abs(np.array(origin) - data.geom_xpos[g])) <= bounds.e_pos, model.geom(g).name


def test_usd_has_one_prim_per_geom_with_its_shape_and_mjcf_colours(bank, tmp_path):
  reports = []
  stage = Usd.Stage.Open(str(export_usd(bank, int(bank.world_ids[0]), tmp_path / "w.usdc",
                                        progress=reports.append)))
  assert reports[-1].phase == "writing USD" and reports[-1].done == reports[-1].total == 1
  model = bank.model
  geoms = {p.GetCustomDataByKey("mujoco:geom_id"): p for p in stage.Traverse()
           if p.GetCustomDataByKey("mujoco:geom_id") is not None}
  assert sorted(geoms) == list(range(model.ngeom))
  kind = {model.geom(g).name: prim.GetTypeName() for g, prim in geoms.items()}
  assert kind == {"floor": "Plane", "ball": "Sphere", "pill": "Capsule", "egg": "Sphere", "can": "Cylinder",
                  "crate": "Cube", "shard": "Mesh", "upper": "Cylinder", "lower": "Capsule"}
  by_name = {model.geom(g).name: prim for g, prim in geoms.items()}
  assert UsdGeom.Sphere(by_name["ball"]).GetRadiusAttr().Get() == pytest.approx(0.07)
  assert UsdGeom.Capsule(by_name["pill"]).GetHeightAttr().Get() == pytest.approx(0.24)
  mesh = UsdGeom.Mesh(by_name["shard"])
  assert len(mesh.GetPointsAttr().Get()) == model.mesh_vertnum[0]
  assert len(mesh.GetFaceVertexIndicesAttr().Get()) == 3 * model.mesh_facenum[0]
  # The red ball shows its material (bound); the pill's own rgba overrides its material's colour.
  red = UsdShade.MaterialBindingAPI(by_name["ball"]).ComputeBoundMaterial()[0]
  assert red.GetPath() == "/World/Looks/red"
  shader = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/red/surface"))
  assert tuple(shader.GetInput("diffuseColor").Get()) == pytest.approx((0.8, 0.1, 0.1))
  assert not UsdShade.MaterialBindingAPI(by_name["pill"]).ComputeBoundMaterial()[0]
  assert tuple(UsdGeom.Gprim(by_name["pill"]).GetDisplayColorAttr().Get()[0]) == (0, 1, 0)


def test_usd_at_a_lower_rate_samples_the_nearest_recorded_frames(bank, tmp_path):
  world = int(bank.world_ids[0])
  stage = Usd.Stage.Open(str(export_usd(bank, world, tmp_path / "w.usd", fps=25.0, start=0.1)))
  duration = (bank.frame_count[bank.row_of(world)] - 1) / bank.record_fps
  assert stage.GetTimeCodesPerSecond() == 25.0
  assert stage.GetEndTimeCode() == math.floor((duration - 0.1) * 25 + 1e-6)
  poses = world_poses(bank, world)
  prim = stage.GetPrimAtPath("/World/bodies/ball")
  for k in (0, 3, int(stage.GetEndTimeCode())):
    frame = round((0.1 + k / 25) * bank.record_fps)
    got = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(float(k)).ExtractTranslation()
    np.testing.assert_allclose(np.array(got), poses.xpos[frame, poses.body_names.index("ball")], atol=1e-12)


class _FakeBank:
  """What presence() reads of a bank: objects and absent()."""
  objects = {"ball": ("ball",), "arm": ("arm", "forearm")}

  def absent(self, world):
    return {"arm": (0.2, math.inf)}


def test_absent_objects_are_hidden_over_their_span(bank, tmp_path):
  model = bank.model
  poses = world_poses(bank, int(bank.world_ids[0]))
  present = poses_lib.presence(_FakeBank(), 0, model, poses.times)
  arm = [model.body("arm").id, model.body("forearm").id]
  np.testing.assert_array_equal(present[:, arm].all(axis=1), poses.times < 0.2)
  assert present[:, model.body("ball").id].all()
  stage = Usd.Stage.Open(str(usd_lib.write_stage(model, poses._replace(present=present), tmp_path / "h.usda")))
  forearm = UsdGeom.Imageable(stage.GetPrimAtPath("/World/bodies/forearm"))
  first_gone = int(np.argmax(poses.times >= 0.2))
  assert forearm.ComputeVisibility(float(first_gone - 1)) == UsdGeom.Tokens.inherited
  assert forearm.ComputeVisibility(float(first_gone)) == UsdGeom.Tokens.invisible
  assert UsdGeom.Imageable(stage.GetPrimAtPath("/World/bodies/ball")).ComputeVisibility(50.0) == "inherited"


@pytest.fixture(scope="module")
def gl():
  reason = video_lib.gl_unavailable_reason()
  if reason is not None:
    pytest.skip(f"offscreen OpenGL unavailable: {reason}")


def read_video(path) -> tuple[tuple[int, int], list[np.ndarray]]:
  """((width, height), u8[H, W, 3] frames) of an mp4, decoded by imageio-ffmpeg's ffmpeg."""
  import imageio_ffmpeg
  reader = imageio_ffmpeg.read_frames(str(path))
  with warnings.catch_warnings():  # JAX warns of any fork; ffmpeg's is exec'd at once
    warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
    meta = next(reader)
  width, height = meta["size"]
  return (width, height), [np.frombuffer(b, np.uint8).reshape(height, width, 3) for b in reader]


@pytest.mark.parametrize("view", [{}, {"camera": "side"}, {"look_at": ((0, -3, 2), (0, 0, 0.5))}])
def test_video_has_the_frames_and_size_asked_for(bank, tmp_path, gl, view):
  path = render_video(bank, int(bank.world_ids[0]), tmp_path / "w.mp4", width=160, height=120, fps=30,
                      stop=0.5, **view)
  size, frames = read_video(path)
  assert size == (160, 120)
  assert len(frames) == 16  # 0, 1/30, ..., 0.5 s
  assert frames[0].std() > 5  # a picture, not a blank frame


def test_video_from_an_mjcf_camera_differs_from_a_look_at(bank, tmp_path, gl):
  world = int(bank.world_ids[0])
  reports = []
  side = read_video(render_video(bank, world, tmp_path / "a.mp4", camera="side", width=64, height=48, stop=0,
                                 progress=reports.append))[1]
  assert [(r.phase, r.done) for r in reports] == [("rendering video", 1.0)]
  top = read_video(render_video(bank, world, tmp_path / "b.mp4", look_at=((0, 0, 4), (0, 0, 0)), width=64,
                                height=48, stop=0))[1]
  assert len(side) == len(top) == 1
  assert np.abs(side[0].astype(float) - top[0].astype(float)).mean() > 5


def test_bad_requests_are_one_error_naming_the_value(bank, tmp_path):
  world = int(bank.world_ids[0])
  cases = [
      (lambda: export_usd(bank, 99, tmp_path / "w.usda"), "world 99"),
      (lambda: export_usd(bank, world, tmp_path / "w.obj"), "w.obj"),
      (lambda: export_npz(bank, world, tmp_path / "w.npz", start=5.0), "start"),
      (lambda: export_usd(bank, world, tmp_path / "w.usda", fps=0), "fps"),
      (lambda: render_video(bank, world, tmp_path / "w.mp4", camera="nope"), "'nope'"),
      (lambda: render_video(bank, world, tmp_path / "w.mp4", width=161), "width"),
      (lambda: render_video(bank, world, tmp_path / "w.mp4", look_at=((0, 0, 1), (0, 0, 1))), "look_at"),
  ]
  for call, named in cases:
    with pytest.raises(mwbx.MwbxError, match=named):
      call()
  assert not list(tmp_path.iterdir())  # nothing half-written


def test_a_missing_package_is_named_with_what_to_install(bank, tmp_path, monkeypatch):
  world = int(bank.world_ids[0])
  monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
  with pytest.raises(mwbx.MwbxError, match="pip install imageio-ffmpeg"):
    render_video(bank, world, tmp_path / "w.mp4")
  monkeypatch.setitem(sys.modules, "pxr", None)
  with pytest.raises(mwbx.MwbxError, match="pip install usd-core"):
    export_usd(bank, world, tmp_path / "w.usda")
