"""The native backend's compiled bookkeeping against world.frame_update (JAX)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mwbx import perturb
from mwbx.batch_sim import host_bookkeeping, world
from mwbx.perturb import sparse
from mwbx.scene import SENSOR_WIDTH

# float64 on the host against float32 in XLA: metrics accumulate over ~100 steps.
_METRIC_TOLERANCE = 2e-5
_WRENCH_TOLERANCE = 1e-4


def test_uniforms_are_jax_random_bit_for_bit():
  rng = np.random.default_rng(0)
  out = np.empty(6)
  for _ in range(50):
    key_data = rng.integers(0, 2**32, size=2, dtype=np.uint32)
    step, body = int(rng.integers(0, 2**31 - 1)), int(rng.integers(0, 64))
    want = sparse.body_step_uniforms(jax.random.wrap_key_data(key_data), step, body)
    host_bookkeeping.body_step_uniforms(key_data[0], key_data[1], step, body, out)
    np.testing.assert_array_equal(out.astype(np.float32), np.asarray(want))


def _params(enabled=True, flex=False):
  """Three bodies (the third not perturbable); with ``flex`` a fourth, and
  the last two one flex."""
  mass, inertia = [1.0, 0.3, 2.5], [[0.01, 0.02, 0.03], [0.002, 0.002, 0.004], [0.2, 0.1, 0.05]]
  perturbable, flex_weight = [True, True, False], np.zeros((0, 3))
  if flex:
    mass, inertia = mass + [1.5], inertia + [[0.1, 0.1, 0.1]]
    perturbable, flex_weight = perturbable + [False], np.array([[0.0, 0.0, 2.5 / 4, 1.5 / 4]])
  return world.WorldParams(
      gravity=jnp.array([0.0, 0.0, -9.81]), mass=jnp.array(mass), inertia=jnp.array(inertia),
      perturbable=jnp.array(perturbable), flex_weight=jnp.asarray(flex_weight, jnp.float32),
      flex_perturbable=jnp.ones(len(flex_weight), bool),
      perturb=perturb.PerturbParams(alpha=0.1, lobe_exponent=20.0, linear_threshold=100.0,
                                    angular_threshold=2000.0),
      enabled=enabled, dt=1 / 480, rest_linear_speed=0.05, rest_angular_speed=0.1, rest_steps=12,
      max_speed=50.0, collision_gap_steps=5, steps_per_frame=4, end_frame=25)


def _observations(rng, n_worlds, n_frames, n_steps, n_bodies):
  """f32[F, W, S, B * SENSOR_WIDTH]: moving, resting, exploding and NaN worlds, with impacts."""
  shape = (n_frames, n_worlds, n_steps, n_bodies)
  quat = rng.normal(size=shape + (4,))
  quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
  lin_vel = rng.normal(size=shape + (3,))
  ang_vel = 3 * rng.normal(size=shape + (3,))
  lin_acc = rng.normal(size=shape + (3,))  # as MuJoCo reports it: a - gravity
  ang_acc = 10 * rng.normal(size=shape + (3,))
  impacts = rng.random(shape) < 0.08
  lin_acc = np.where(impacts[..., None], 400 * rng.normal(size=shape + (3,)), lin_acc)
  spins = rng.random(shape) < 0.08
  ang_acc = np.where(spins[..., None], 6000 * rng.normal(size=shape + (3,)), ang_acc)
  com = np.cumsum(lin_vel, axis=0) / 120 + [0.0, 0.0, 1.0]
  resting = np.arange(n_worlds) % 4 == 1  # still from frame 6 on: comes to rest
  lin_vel[6:, resting] *= 1e-3
  ang_vel[6:, resting] *= 1e-3
  lin_acc[6:, resting] = [0.0, 0.0, 9.81]
  ang_acc[6:, resting] = 0.0
  lin_vel[9, 2, 1, 0] = [80.0, 0.0, 0.0]  # faster than max_speed: unstable
  com[13, 3, 2, 1, 2] = np.nan  # a NaN observation mid-frame: unstable
  com[0, 7, 0, 0, 0] = np.inf  # not finite at frame 0, step 0: nothing recorded
  sensors = np.concatenate([com, quat, lin_vel, ang_vel, lin_acc, ang_acc], axis=-1)
  assert sensors.shape[-1] == SENSOR_WIDTH
  return sensors.reshape(n_frames, n_worlds, n_steps, -1).astype(np.float32)


@pytest.mark.parametrize("enabled,flex", [(True, False), (False, False), (True, True)])
def test_frame_update_matches_world_frame_update(enabled, flex):
  rng = np.random.default_rng(1)
  params = _params(enabled, flex)
  host_params = host_bookkeeping.host_params(params)
  n_worlds, n_frames, n_steps, nq, nbody = 12, 30, 4, 5, 7
  tracked = np.array([1, 3, 4, 5] if flex else [1, 3, 4])
  n_bodies = len(tracked)
  active = np.arange(n_worlds) != 11  # a padding slot
  observations = _observations(rng, n_worlds, n_frames, n_steps, n_bodies)
  keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(jax.random.key(3), jnp.arange(n_worlds))
  key_data = np.asarray(jax.random.key_data(keys), np.uint32)

  jax_update = jax.jit(lambda carry, sensors: world.frame_update(
      carry, jax.vmap(jax.vmap(lambda s: world.Observation.from_sensordata(s, params.gravity)))(sensors),
      keys, params))
  jax_carry = jax.vmap(world.init_carry, in_axes=(None, 0))(n_bodies, jnp.asarray(active))
  carry = host_bookkeeping.init_carry(n_bodies, active)
  running = active.copy()
  qpos_buf = np.zeros((n_worlds, n_frames, nq), np.float32)
  com_buf = np.zeros((n_worlds, n_frames, n_bodies, 3), np.float32)
  wrench_full = np.zeros((n_worlds, n_steps, nbody, 6))
  states = rng.normal(size=(n_frames, n_worlds, 1 + nq))
  buffers = host_bookkeeping.ChunkBuffers(
      params=host_params, key_data=key_data, tracked_ids=tracked, states=np.zeros((n_worlds, 1 + nq)),
      warmstart=np.zeros((n_worlds, 1)), sensordata=np.zeros_like(observations[0]), wrench_full=wrench_full,
      qpos_buf=qpos_buf, com_buf=com_buf, carry=carry)
  saw = {"perturbed": 0}
  for frame in range(n_frames):
    rows = np.flatnonzero(running)
    if rows.size == 0:
      break
    sensors = observations[frame]
    stale = wrench_full[rows]
    stale[:, :, tracked] = np.nan  # every stepped world's wrenches must be written
    wrench_full[rows] = stale
    buffers.sensordata[...] = sensors
    host_bookkeeping.frame_update(rows, buffers, states[frame, rows], 1, frame, running)
    jax_carry, out = jax_update(jax_carry, sensors)

    for name in ("step", "status", "frame_count", "still_steps", "since_impact", "perturbations"):
      np.testing.assert_array_equal(getattr(carry, name), np.asarray(getattr(jax_carry, name)),
                                    err_msg=f"{name}, frame {frame}")
    np.testing.assert_allclose(carry.metrics, np.asarray(jax_carry.metrics), rtol=_METRIC_TOLERANCE,
                               atol=_METRIC_TOLERANCE, err_msg=f"metrics, frame {frame}")
    # Rest times are multiples of dt; the same float32 values on both sides.
    np.testing.assert_array_equal(carry.metrics[..., 1].astype(np.float32),
                                  np.asarray(jax_carry.metrics)[..., 1])
    np.testing.assert_array_equal(running[rows], np.asarray(out.running)[rows])
    scale = np.abs(np.asarray(out.wrench[rows])).max() + 1.0
    np.testing.assert_allclose(wrench_full[rows][:, :, tracked], np.asarray(out.wrench)[rows],
                               rtol=_WRENCH_TOLERANCE, atol=_WRENCH_TOLERANCE * scale)
    assert not wrench_full[rows][:, :, np.setdiff1d(np.arange(nbody), tracked)].any()
    if flex:  # the flex's bodies share one velocity change: force / mass alike
      dv_flex = wrench_full[rows][:, :, tracked[2:], :3] / np.asarray(params.mass)[2:, None]
      np.testing.assert_allclose(dv_flex[:, :, 0], dv_flex[:, :, 1], rtol=1e-12, atol=1e-12)
      assert not wrench_full[rows][:, :, tracked[2:], 3:].any()
      saw["flex"] = saw.get("flex", 0) + int(np.count_nonzero(dv_flex))
    recorded = rows[np.asarray(out.record)[rows]]
    np.testing.assert_array_equal(qpos_buf[recorded, frame], states[frame, recorded, 1:].astype(np.float32))
    np.testing.assert_array_equal(com_buf[recorded, frame], sensors[recorded, 0, :].reshape(
        -1, n_bodies, SENSOR_WIDTH)[..., :3])
    saw["perturbed"] += int(np.count_nonzero(wrench_full[rows]))

  # The data reached every branch: perturbations (when enabled), rest, end
  # time, instability, and a frame that is not recorded.
  assert (saw["perturbed"] > 0) == enabled
  assert saw.get("flex", 0) > 0 or not flex
  assert set(carry.status.tolist()) == {world.AT_REST, world.END_TIME, world.UNSTABLE}
  assert carry.frame_count[7] == carry.step[7] // n_steps - 1
