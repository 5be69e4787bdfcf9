"""Models written by others sample with a config naming only the MJCF: the
physics step stays the MJCF's, and the recording rates follow it."""

import math
import pathlib
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import mwbx
from mwbx import rates as rates_lib

END_TIME = 0.25
Z0 = 5.0  # the free bodies start here and fall freely for END_TIME
G = 9.81

# timestep (s) -> (steps a frame, record fps, frames a query point, query fps)
EXPECTED = {
    0.001: (8, 125.0, 4, 31.25),
    0.002: (4, 125.0, 4, 31.25),
    0.0025: (3, 400.0 / 3, 4, 100.0 / 3),
    0.004: (2, 125.0, 4, 31.25),
    0.005: (2, 100.0, 3, 100.0 / 3),
    0.01: (1, 100.0, 3, 100.0 / 3),
    0.02: (1, 50.0, 2, 25.0),
}

TETRAHEDRON_OBJ = """\
v 0 0 0
v 0.1 0 0
v 0 0.1 0
v 0 0 0.1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
"""


def write_model(folder: pathlib.Path, timestep: float) -> pathlib.Path:
  """A model the way others write them: an <include>d asset file with a mesh
  file and an inline mesh, an <include>d hinge chain, and free bodies."""
  (folder / "tet.obj").write_text(TETRAHEDRON_OBJ)
  (folder / "assets.xml").write_text(textwrap.dedent("""\
      <mujoco>
        <asset>
          <mesh name="tet" file="tet.obj"/>
          <mesh name="wedge" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1  0.1 0.1 0.1"/>
        </asset>
      </mujoco>
      """))
  (folder / "arm.xml").write_text(textwrap.dedent("""\
      <mujoco>
        <body name="arm" pos="0 1 1">
          <joint name="shoulder" type="hinge" axis="0 1 0" damping="0.01"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
          <body name="forearm" pos="0.3 0 0">
            <joint name="elbow" type="hinge" axis="0 1 0" damping="0.01"/>
            <geom type="cylinder" fromto="0 0 0 0.25 0 0" size="0.025"/>
            <body name="hand" pos="0.25 0 0">
              <joint name="wrist" type="hinge" axis="0 0 1"/>
              <geom type="box" size="0.03 0.02 0.01"/>
            </body>
          </body>
        </body>
      </mujoco>
      """))
  main = folder / "model.xml"
  main.write_text(textwrap.dedent(f"""\
      <mujoco model="others">
        <option timestep="{timestep}"/>
        <include file="assets.xml"/>
        <worldbody>
          <geom name="floor" type="plane" size="3 3 0.1"/>
          <include file="arm.xml"/>
          <body name="tet" pos="0 0 {Z0}"><freejoint/><geom type="mesh" mesh="tet"/></body>
          <body name="wedge" pos="1 0 {Z0}"><freejoint/><geom type="mesh" mesh="wedge"/></body>
          <body name="ball" pos="-1 0 {Z0}"><freejoint/><geom type="sphere" size="0.05"/></body>
        </worldbody>
      </mujoco>
      """))
  return main


def only_mjcf(folder: pathlib.Path, timestep: float, extra: str = "") -> pathlib.Path:
  write_model(folder, timestep)
  path = folder / "cfg.yaml"
  path.write_text(f"scene: {{mjcf: model.xml}}\nsim: {{end_time: {END_TIME}{extra}}}\n")
  return path


@pytest.mark.parametrize("timestep", sorted(EXPECTED))
def test_config_naming_only_the_mjcf_samples_at_rates_from_its_timestep(tmp_path, timestep):
  steps, record_fps, stride, query_fps = EXPECTED[timestep]
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, timestep)))
  assert scene.rates.steps_per_frame == steps and scene.rates.query_stride == stride
  bank = mwbx.sample(scene, n_worlds=2, key=jax.random.key(0), backend="native")
  assert bank.timestep == pytest.approx(timestep, rel=1e-12)  # the physics as written
  assert bank.record_fps == pytest.approx(record_fps, rel=1e-12)
  assert bank.query_fps == pytest.approx(query_fps, rel=1e-12)
  assert bank.config["sim"]["record_fps"] == bank.record_fps  # the bank's config states them
  assert not np.any(bank.flags & (mwbx.bank.FLAG_UNSTABLE | mwbx.bank.FLAG_SIM_ERROR))
  frames = int(round(END_TIME * record_fps)) + 1
  assert np.all(bank.frame_count == frames)
  assert np.all(bank.steps == frames * steps)  # a block of `steps` physics steps per recorded frame
  # Frame f is physics step f·steps: the free fall the stored frames show is
  # the integrator's, z_n = z0 - g h² n (n + 1) / 2 (semi-implicit Euler).
  qpos = bank.qpos_frames(int(bank.world_ids[0]))
  z_adr = scene.model.jnt_qposadr[scene.model.body_jntadr[scene.model.body("ball").id]] + 2
  n = np.arange(frames) * steps
  ball_start = qpos[0, z_adr]
  np.testing.assert_allclose(qpos[:, z_adr], ball_start - G * timestep ** 2 * n * (n + 1) / 2,
                             atol=2e-3)
  # A COM polyline point every `stride` frames.
  com = np.asarray(bank.com[0, :bank.com_count[0], list(bank.body_names).index("ball"), 2])
  assert bank.com_count[0] == (frames - 1) // stride + 1
  np.testing.assert_allclose(com, qpos[::stride, z_adr][:com.size], atol=2e-3)


def test_rates_chosen_for_each_timestep_are_whole_steps_nearest_120():
  cfg = mwbx.config_from_dict({"scene": {"mjcf": "m.xml"}})
  for timestep in [0.001, 0.002, 0.0025, 0.003, 0.004, 0.005, 0.01, 0.02, 1 / 480, 0.0020833333333333333, 1e-4]:
    r = rates_lib.resolve(cfg, timestep)
    assert r.steps_per_frame * timestep * r.record_fps == pytest.approx(1.0, rel=1e-9)
    # No whole number of steps gives a rate nearer 120 fps; none of query points nearer 30.
    for k in range(1, 200):
      assert abs(1 / (k * timestep) - 120) >= abs(r.record_fps - 120) - 1e-9
    for s in range(1, 50):
      assert abs(r.record_fps / s - 30) >= abs(r.query_fps - 30) - 1e-9
    assert r.record_fps / r.query_fps == pytest.approx(r.query_stride, rel=1e-12)
    assert r.chosen == ("sim.record_fps", "sim.query_fps")
  # A timestep dividing 1/120 s keeps the shipped rates exactly (1/480 s written in decimal too).
  for timestep in [1 / 480, 0.00208333333333333, 0.004166666666666667, 1 / 120]:
    r = rates_lib.resolve(cfg, timestep)
    assert (r.record_fps, r.query_fps) == (120.0, 30.0)


def test_null_rates_are_chosen(tmp_path):
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, 0.02, ", record_fps: null, query_fps: null")))
  assert (scene.rates.record_fps, scene.rates.query_fps) == (50.0, 25.0)
  assert (scene.config.sim.record_fps, scene.config.sim.query_fps) == (50.0, 25.0)


def test_rates_the_config_sets_are_kept(tmp_path):
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, 0.002, ", record_fps: 100")))
  assert (scene.rates.steps_per_frame, scene.rates.record_fps) == (5, 100.0)
  assert scene.rates.query_fps == pytest.approx(100 / 3) and scene.rates.chosen == ("sim.query_fps",)
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, 0.002, ", query_fps: 25")))
  # The frame rate nearest 120 fps that is whole steps and whole query points apart.
  assert (scene.rates.record_fps, scene.rates.query_stride, scene.rates.query_fps) == (125.0, 5, 25.0)
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, 0.002, ", timestep: 0.001, record_fps: 200,"
                                                 " query_fps: 50")))
  assert scene.rates.steps_per_frame == 5 and scene.rates.query_stride == 4 and scene.rates.chosen == ()
  assert scene.rates.timestep_from == "sim.timestep"


@pytest.mark.parametrize("extra, names", [
    (", record_fps: 120", ["sim.record_fps: 120", "the MJCF's <option timestep> = 0.002"]),
    (", timestep: 0.003, record_fps: 120", ["sim.record_fps: 120", "sim.timestep = 0.003"]),
    (", record_fps: 125, query_fps: 30", ["sim.query_fps: 30", "sim.record_fps: 125"]),
    (", query_fps: 30", ["sim.query_fps: 30", "the MJCF's <option timestep> = 0.002"]),
])
def test_contradicting_values_are_one_error_naming_both(tmp_path, extra, names):
  path = only_mjcf(tmp_path, 0.002, extra)
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.Scene(mwbx.load_config(path))
  text = str(err.value)
  assert str(path) in text and "contradict" in text and "\n" not in text
  for name in names:
    assert name in text


def test_cli_prints_the_rates_on_one_line(tmp_path):
  path = only_mjcf(tmp_path, 0.005)
  out = tmp_path / "bank"
  result = subprocess.run([sys.executable, "-m", "mwbx.cli", "sample", str(path), "--worlds", "2",
                           "--backend", "native", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
  assert result.returncode == 0, result.stderr
  lines = [line for line in result.stderr.splitlines() if "rates:" in line]
  assert len(lines) == 1
  assert "physics step 0.005 s (MJCF), 2 steps a frame: record 100 fps, query 33.3333 fps (every 3rd frame)" \
      in lines[0]
  assert lines[0].endswith("chosen from the step: sim.record_fps, sim.query_fps")
  bank = mwbx.Bank.load(out)
  assert (bank.record_fps, bank.timestep) == (100.0, 0.005)
  assert math.isclose(bank.query_fps, 100 / 3)


def test_a_bank_at_chosen_rates_saves_loads_and_refines(tmp_path):
  # 0.005 s: 2 steps a frame at 100 fps; the bank's own config states them.
  scene = mwbx.Scene(mwbx.load_config(only_mjcf(tmp_path, 0.005)))
  bank = mwbx.sample(scene, n_worlds=2, key=jax.random.key(1), backend="native")
  bank.save(tmp_path / "bank")
  loaded = mwbx.Bank.load(tmp_path / "bank")
  assert (loaded.record_fps, loaded.timestep) == (100.0, 0.005)
  parent = int(loaded.world_ids[0])
  refined = mwbx.refine(loaded, parent, ["arm"], t_min=0.1, n_samples=2, key=jax.random.key(2),
                        backend="native")
  new = refined.world_ids[refined.parent_world == parent]
  assert new.size == 2 and refined.record_fps == 100.0
  f0 = 10  # 0.1 s at 100 fps
  before = loaded.qpos_frames(parent)
  for world in new:
    after = refined.qpos_frames(int(world))
    assert after.shape == before.shape
    # Up to t_min every frame is the parent's; the free bodies never touch
    # the arm, so they keep their stored paths to the end.
    np.testing.assert_allclose(after[:f0 + 1], before[:f0 + 1], atol=2e-3)
    free = scene.model.jnt_qposadr[scene.model.body_jntadr[scene.model.body("ball").id]]
    np.testing.assert_allclose(after[:, free:free + 3], before[:, free:free + 3], atol=2e-3)
