"""Actuated objects: controls from the config, applied alike by every loop.

Scene: tests/scenes/servo_arm.xml, a position servo holding an arm level and
then lifting it to -0.8 rad (a ramp from 0.6 s to 0.9 s), a ball dropped on
the arm.
"""

import jax
import numpy as np
import pytest

import mwbx
from mwbx import controls
from mwbx.batch_sim import mujoco_c
from conftest import TESTS
from test_sampler import _reference_chunk

SERVO = TESTS / "scenes" / "servo_arm.yaml"
TARGET = -0.8  # rad, the schedule's last value
# The servo (kp 30) holds the arm against gravity and the ball's weight this
# far from its target, radians: 0.5 kg at 0.2 m over kp.
SAG = 0.05
# MJX (float32) against MuJoCo C (float64) on the unperturbed arm, radians
# over the whole 1.5 s (the ball lands on it at about 0.3 s).
MJX_ANGLE_TOLERANCE = 5e-3
SHOULDER = 0  # qpos address of the arm's hinge (the first joint)


@pytest.fixture(scope="module")
def servo_config():
  return mwbx.load_config(SERVO)


def _plain(cfg):
  return cfg.model_copy(update={"perturb": cfg.perturb.model_copy(update={"enabled": False})})


def _config(tmp_path, text):
  path = tmp_path / "c.yaml"
  path.write_text(f"scene: {{mjcf: {TESTS / 'scenes' / 'servo_arm.xml'}}}\n{text}")
  return path


@pytest.mark.parametrize("text, message", [
    ("controls: {elbow: 1.0}", "controls.elbow: the MJCF has no actuator 'elbow' (actuators: shoulder)"),
    ("controls: {shoulder: {times: [0, 1], values: [0]}}", "times has 2 knots but values has 1"),
    ("controls: {shoulder: {times: [1, 0], values: [0, 1]}}", "times must increase strictly"),
    ("controls: {shoulder: {times: [0], values: [0], interpolation: cubic}}",
     "controls.shoulder.interpolation: Input should be 'linear' or 'step'"),
    ("controls: {shoulder: fast}", "controls.shoulder: Input should be a valid dictionary"),
])
def test_bad_controls_name_the_field(tmp_path, text, message):
  with pytest.raises(mwbx.MwbxError, match=message.replace("(", r"\(").replace(")", r"\)")):
    mwbx.Scene(mwbx.load_config(_config(tmp_path, text)))


def test_control_table_follows_the_schedule(servo_config):
  scene = mwbx.Scene(servo_config)
  dt = scene.model.opt.timestep
  table = controls.scene_table(scene, 1000)
  t = np.arange(1000) * dt
  expected = np.interp(t, [0.6, 0.9], [0.0, TARGET])
  np.testing.assert_allclose(table[:, 0], expected, rtol=0, atol=1e-12)
  # Rows from a later first step are that stretch of the same schedule.
  np.testing.assert_array_equal(controls.scene_table(scene, 100, first_step=300), table[300:400])
  step = mwbx.config.ControlSchedule(times=(0.5, 1.0), values=(1.0, 2.0), interpolation="step")
  np.testing.assert_array_equal(controls.schedule_values(step, np.array([0.0, 0.5, 0.99, 1.0, 3.0])),
                                [1.0, 1.0, 1.0, 2.0, 2.0])
  assert controls.control_table(scene.model, {}, 10).shape == (10, 0)


def test_compiled_loop_applies_controls_like_mj_step(servo_config):
  assert mujoco_c.available()
  with mwbx.Sampler(servo_config, backend="native") as sampler:
    _, init_keys, step_keys = mwbx.batch_sim.sampler.world_keys(jax.random.key(5), np.arange(3))
    qpos0, qvel0 = (np.asarray(x) for x in sampler._init(init_keys))
    result = sampler.backend.run_chunk(sampler.scene, sampler.params, qpos0, qvel0, step_keys,
                                       np.ones(3, bool), sampler.n_frames)
    carry, qpos_buf = _reference_chunk(sampler, qpos0, qvel0, step_keys)
  np.testing.assert_array_equal(result.frame_count, carry.frame_count)
  for w in range(3):
    n = result.frame_count[w]
    np.testing.assert_array_equal(result.qpos[w, :n], qpos_buf[w, :n])
  # The servo lifted the arm to its target.
  assert abs(result.qpos[0, -1, SHOULDER] - TARGET) < SAG


def test_backends_apply_the_same_controls(servo_config, monkeypatch):
  """Unperturbed, the compiled loop, the lockstep rollout loop and MJX follow
  the same schedule: without controls the arm would stay level."""
  from mwbx.batch_sim import native_backend
  plain = _plain(servo_config)
  key = jax.random.key(2)
  native = mwbx.sample(plain, n_worlds=8, key=key, backend="native")
  mjx_bank = mwbx.sample(plain, n_worlds=8, key=key, backend="mjx")
  monkeypatch.setattr(native_backend.mujoco_c, "available", lambda: False)
  lockstep = mwbx.sample(plain, n_worlds=8, key=key, backend="native")
  for w in range(8):
    a = native.qpos_frames(w)[:, SHOULDER]
    assert abs(a[-1] - TARGET) < SAG
    assert abs(a[int(0.5 * 120)]) < SAG  # level before the ramp
    np.testing.assert_allclose(mjx_bank.qpos_frames(w)[:, SHOULDER], a, atol=MJX_ANGLE_TOLERANCE)
    # Rollout restarts MuJoCo's warm start per frame: equal to rounding.
    np.testing.assert_allclose(lockstep.qpos_frames(w)[:, SHOULDER], a, atol=1e-4)


@pytest.mark.parametrize("backend", ["native", "mjx"])
def test_refined_actuated_object_keeps_following_the_schedule(servo_config, backend):
  bank = mwbx.sample(servo_config, n_worlds=4, key=jax.random.key(0), backend="native")
  done = mwbx.run_refinement(bank, mwbx.RefineRequest(
      0, ["arm"], t_min=0.4, n_samples=8, key=jax.random.key(1), backend=backend))
  new, stats = done.new, done.stats
  assert new.valid.all()
  parent = bank.qpos_frames(0)[:, SHOULDER]
  f0 = stats.first_frame
  for w in new.world_ids:
    angle = new.qpos_frames(int(w))[:, SHOULDER]
    # Before t_min: the parent's frames, coded again with the arm's new motion
    # (each decoded copy within the codec bound of the simulation).
    np.testing.assert_allclose(angle[:f0], parent[:f0], atol=2 * servo_config.codec.e_scalar)
    # The ramp starts at 0.6 s, after t_min: only controls applied by the
    # refinement loop lift the arm.
    assert abs(angle[-1] - TARGET) < SAG, (backend, angle[-1])


def test_refinement_restarts_actuator_activations(tmp_path):
  """A servo with a time constant (activation dynamics, na = 1) refined in
  the middle of its ramp: its activation at t_min is the one sampling had
  there, so the unperturbed refined arm retraces the parent's motion; started
  from zero activation it would sag by about the target angle."""
  (tmp_path / "arm.xml").write_text((TESTS / "scenes" / "servo_arm.xml").read_text().replace(
      'kp="30"', 'kp="30" timeconst="0.2"'))
  text = SERVO.read_text().replace("mjcf: servo_arm.xml", f"mjcf: {tmp_path / 'arm.xml'}")
  (tmp_path / "arm.yaml").write_text(text)
  cfg = _plain(mwbx.load_config(tmp_path / "arm.yaml"))
  scene = mwbx.Scene(cfg)
  assert scene.model.na == 1
  bank = mwbx.sample(scene, n_worlds=1, key=jax.random.key(0), backend="native")
  parent = bank.qpos_frames(0)[:, SHOULDER]
  t_min = 0.8  # s, two thirds up the ramp
  spf = 4  # physics steps per 120 fps frame at this timestep
  table = controls.scene_table(scene, int(round(t_min * 120)) * spf)
  act = controls.activation_at(scene.model, table, len(table))
  assert act[0] < -0.1  # well away from zero: the servo is pulling
  done = mwbx.run_refinement(bank, mwbx.RefineRequest(
      0, ["arm"], t_min=t_min, n_samples=2, key=jax.random.key(1), backend="native"))
  new, stats = done.new, done.stats
  f0 = stats.first_frame
  for w in new.world_ids:
    angle = new.qpos_frames(int(w))[:, SHOULDER]
    # Perturbations are off: the arm follows the parent within the codec
    # bounds plus the restart's rounding.
    np.testing.assert_allclose(angle[f0:f0 + 60], parent[f0:f0 + 60], atol=0.01)
