"""The compiled host loops of the native sampler against their numpy form."""

import numpy as np

from mwbx.batch_sim import free_bodies, host_loops


def _absorb_numpy(before, after, sensors, timestep, qvel_start, nv):
  """What NativeBackend.absorb_frame computes, in numpy (the reference)."""
  n_steps = after.shape[1]
  bad = ~np.isclose(after[:, -1, 0], before[:, 0] + n_steps * timestep, rtol=0, atol=1e-6)
  sensors = sensors.copy()
  sensors[bad] = np.nan
  qvel = slice(qvel_start, qvel_start + nv)
  previous = after[:, -2] if n_steps > 1 else before
  return sensors.astype(np.float32), (after[:, -1, qvel] - previous[:, qvel]) / timestep, after[:, -1]


def test_absorb_rows_matches_numpy():
  rng = np.random.default_rng(0)
  c, n_steps, nstate, nsens, nq, nv, dt = 9, 4, 15, 11, 7, 6, 1 / 480
  rows = np.array([0, 2, 3, 7, 8])
  before = rng.normal(size=(rows.size, nstate))
  after = rng.normal(size=(rows.size, n_steps, nstate))
  after[:, :, 0] = before[:, :1] + dt * np.arange(1, n_steps + 1)
  after[2, -1, 0] = 0.0  # MuJoCo reset this world: its sensors must become NaN
  sensors = rng.normal(size=(rows.size, n_steps, nsens))
  sensordata = np.zeros((c, n_steps, nsens), np.float32)
  warmstart = np.zeros((c, nv))
  states = np.zeros((c, nstate))
  host_loops.absorb_rows(rows, before, after, sensors, dt, 1 + nq, sensordata, warmstart, states)
  want_s, want_w, want_x = _absorb_numpy(before, after, sensors, dt, 1 + nq, nv)
  np.testing.assert_array_equal(sensordata[rows], want_s)
  np.testing.assert_array_equal(warmstart[rows], want_w)
  np.testing.assert_array_equal(states[rows], want_x)
  assert np.isnan(sensordata[rows[2]]).all() and not np.isnan(sensordata[rows[1]]).any()
  untouched = np.setdiff1d(np.arange(c), rows)
  assert not sensordata[untouched].any() and not warmstart[untouched].any()


# Sensors are float32 in the block; velocities of a few m/s and accelerations
# of thousands of m/s² at impacts round at these magnitudes.
_POSE_TOLERANCE = 1e-6
_VELOCITY_TOLERANCE = 1e-5
_ACCELERATION_RTOL = 1e-5
# The JAX kernel runs in float32 from float32 states: velocity differences over
# one 2 ms step lose about 1e-7 · |v| / dt.
_F32_POSE_TOLERANCE = 2e-6
_F32_VELOCITY_TOLERANCE = 1e-4
_F32_ACCELERATION_RTOL = 1e-4


def test_observe_free_bodies_matches_mujoco_sensors(quickstart_config):
  """The block computed from states is what MuJoCo's sensors report, acceleration included."""
  import jax
  import mujoco
  from mujoco import rollout

  import mwbx
  from mwbx.batch_sim.native_backend import NativeBackend
  from mwbx.batch_sim.sampler import world_keys

  scene = mwbx.Scene(quickstart_config)
  model = scene.model
  backend = NativeBackend(model, threads=1)
  free = free_bodies.free_bodies(model, scene.body_ids)
  assert free is not None
  n_worlds, n_steps, n_frames = 4, 4, 60
  _, init_keys, _ = world_keys(jax.random.key(0), np.arange(n_worlds))
  qpos0, qvel0 = jax.vmap(scene.initial_state)(init_keys)
  start = backend.initial_states(np.asarray(qpos0), np.asarray(qvel0))
  with rollout.Rollout(nthread=1) as pool:
    states, sensors = pool.rollout(model, mujoco.MjData(model), start, nstep=n_steps * n_frames)
  backend.close()
  got = np.zeros((n_worlds, n_frames * n_steps, model.nsensordata), np.float32)
  for f in range(n_frames):
    before = start if f == 0 else states[:, f * n_steps - 1]
    frame = np.zeros((n_worlds, n_steps, model.nsensordata), np.float32)
    host_loops.observe_free_bodies(np.arange(n_worlds), before, states[:, f * n_steps:(f + 1) * n_steps],
                                   model.opt.timestep, model.opt.gravity, 1, 1 + model.nq, free, frame)
    got[:, f * n_steps:(f + 1) * n_steps] = frame
  got = got.reshape(n_worlds, -1, len(scene.body_ids), 19).astype(np.float64)
  want = sensors.reshape(got.shape)
  # The horizon must contain impacts, or accelerations would only be gravity.
  assert np.linalg.norm(want[..., 13:16], axis=-1).max() > 2 * quickstart_config.perturb.linear_threshold
  np.testing.assert_allclose(got[..., 0:3], want[..., 0:3], atol=_POSE_TOLERANCE)
  sign = np.sign(np.sum(got[..., 3:7] * want[..., 3:7], axis=-1, keepdims=True))  # q and -q: one rotation
  np.testing.assert_allclose(sign * got[..., 3:7], want[..., 3:7], atol=_POSE_TOLERANCE)
  np.testing.assert_allclose(got[..., 7:13], want[..., 7:13], atol=_VELOCITY_TOLERANCE)
  scale = np.abs(want[..., 13:19]).max()
  np.testing.assert_allclose(got[..., 13:19], want[..., 13:19], atol=_ACCELERATION_RTOL * scale)

  # The JAX kernel (MJX) computes the same block in float32.
  path = np.concatenate([start[:, None], states], axis=1).astype(np.float32)
  qpos, qvel = path[..., 1:1 + model.nq], path[..., 1 + model.nq:1 + model.nq + model.nv]
  block = jax.vmap(free_bodies.observe, in_axes=(0, 0, None, None, None))(
      qpos, qvel, free, model.opt.timestep, jax.numpy.asarray(model.opt.gravity, np.float32))
  block = np.asarray(block).reshape(got.shape).astype(np.float64)
  sign = np.sign(np.sum(block[..., 3:7] * want[..., 3:7], axis=-1, keepdims=True))
  np.testing.assert_allclose(block[..., 0:3], want[..., 0:3], atol=_F32_POSE_TOLERANCE)
  np.testing.assert_allclose(sign * block[..., 3:7], want[..., 3:7], atol=_F32_POSE_TOLERANCE)
  np.testing.assert_allclose(block[..., 7:13], want[..., 7:13], atol=_F32_VELOCITY_TOLERANCE)
  np.testing.assert_allclose(block[..., 13:19], want[..., 13:19], atol=_F32_ACCELERATION_RTOL * scale)


def test_free_bodies_only_for_free_roots(tiny_config):
  import mwbx

  scene = mwbx.Scene(tiny_config)
  assert free_bodies.free_bodies(scene.model, scene.body_ids) is not None
  assert free_bodies.free_bodies(scene.model, np.array([0])) is None  # the world body has no joint
