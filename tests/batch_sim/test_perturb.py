"""Perturbations: the plausibility bound, thresholds, the Phong lobe, free flight."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats

import mwbx
from mwbx import perturb
from mwbx.batch_sim import world

# float32 arithmetic on the magnitude: relative slack for the bound.
_BOUND_TOLERANCE = 1e-5
# Wrench → velocity change in MuJoCo C (float64 sim of a float32 wrench).
_WRENCH_TOLERANCE = 1e-5

_perturbation = jax.jit(perturb.perturbation_from_uniforms)
_finite = st.floats(-1e3, 1e3, allow_nan=False, width=32)


@settings(max_examples=200, deadline=None)
@given(u=st.lists(st.floats(0, 1, exclude_max=True, width=32), min_size=3, max_size=3),
       delta=st.lists(_finite, min_size=3, max_size=3),
       alpha=st.floats(0, 1), exponent=st.floats(0, 200))
def test_perturbation_never_exceeds_alpha_times_delta(u, delta, alpha, exponent):
  delta = np.asarray(delta, np.float32)
  out = np.asarray(_perturbation(jnp.asarray(u, jnp.float32), jnp.asarray(delta), alpha, exponent))
  assert np.all(np.isfinite(out))
  bound = alpha * np.linalg.norm(delta.astype(np.float64))
  # The norm in float64: squares of float32 components near 1e-23 underflow.
  assert np.linalg.norm(out.astype(np.float64)) <= bound * (1 + _BOUND_TOLERANCE) + 1e-30


@pytest.mark.parametrize("exponent", [0.0, 5.0, 40.0])
def test_lobe_direction_follows_phong_lobe(exponent):
  # Goodness of fit: cos θ to the axis has CDF c^(n+1) on [0, 1]; φ is uniform.
  axis = np.array([0.3, -1.2, 0.5], np.float32)
  keys = jax.random.split(jax.random.key(7), 20000)
  d = np.asarray(jax.vmap(perturb.sample_lobe_direction, in_axes=(0, None, None))(keys, axis, exponent))
  np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
  unit = axis / np.linalg.norm(axis)
  cos_theta = np.clip(d @ unit, 0, 1)
  result = stats.kstest(cos_theta, lambda c: np.clip(c, 0, 1) ** (exponent + 1))
  assert result.pvalue > 1e-3, result
  e1, e2 = (np.asarray(v) for v in perturb.orthonormal_basis(jnp.asarray(unit)))
  phi = np.arctan2(d @ e2, d @ e1)
  assert stats.kstest(phi, stats.uniform(-np.pi, 2 * np.pi).cdf).pvalue > 1e-3
  # A wrong lobe (exponent off by a factor of two) is rejected by the same test.
  wrong = stats.kstest(cos_theta, lambda c: np.clip(c, 0, 1) ** (2 * exponent + 2))
  assert exponent == 0 or wrong.pvalue < 1e-6


def test_impacts_only_above_thresholds(tiny_native):
  """frame_update perturbs exactly the body-steps above C_v or C_ω (numpy reference)."""
  params = tiny_native.params
  rng = np.random.default_rng(0)
  w, s, b = 6, params.steps_per_frame, 2
  gravity = np.asarray(params.gravity)
  lin_acc = gravity + rng.normal(0, 1, (w, s, b, 3)) * rng.choice([1.0, 80.0, 400.0], (w, s, b, 1))
  ang_acc = rng.normal(0, 1, (w, s, b, 3)) * rng.choice([10.0, 3000.0], (w, s, b, 1))
  quat = np.tile([1.0, 0, 0, 0], (w, s, b, 1))
  zeros = np.zeros((w, s, b, 3))
  obs = world.Observation(*(jnp.asarray(x, jnp.float32) for x in (zeros, quat, zeros, zeros, lin_acc, ang_acc)))
  carry = jax.vmap(world.init_carry, in_axes=(None, 0))(b, jnp.ones(w, bool))
  keys = jax.random.split(jax.random.key(3), w)
  _, out = jax.jit(lambda c, o, k: world.frame_update(c, o, k, params))(carry, obs, keys)
  dt = params.dt
  lin_expected = np.linalg.norm(lin_acc - gravity, axis=-1) > params.perturb.linear_threshold
  ang_expected = np.linalg.norm(ang_acc, axis=-1) > params.perturb.angular_threshold
  assert lin_expected.any() and (~lin_expected).any() and ang_expected.any()
  np.testing.assert_array_equal(np.asarray(out.linear_impact), lin_expected)
  np.testing.assert_array_equal(np.asarray(out.angular_impact), ang_expected)
  dv, dw = np.asarray(out.dv), np.asarray(out.dw)
  np.testing.assert_array_equal(np.linalg.norm(dv, axis=-1) > 0, lin_expected)
  np.testing.assert_array_equal(np.linalg.norm(dw, axis=-1) > 0, ang_expected)
  bound_v = params.perturb.alpha * np.linalg.norm(dt * (lin_acc - gravity), axis=-1)
  bound_w = params.perturb.alpha * np.linalg.norm(dt * ang_acc, axis=-1)
  assert np.all(np.linalg.norm(dv, axis=-1) <= bound_v * (1 + _BOUND_TOLERANCE))
  assert np.all(np.linalg.norm(dw, axis=-1) <= bound_w * (1 + _BOUND_TOLERANCE))
  # The wrenches (computed only at impacts) are impulse_wrench of (dv, dw).
  reference = jax.vmap(perturb.impulse_wrench, in_axes=(0, 0, 0, 0, 0, None))(
      dv.reshape(-1, 3), dw.reshape(-1, 3), np.tile(np.asarray(params.mass), w * s),
      np.tile(np.asarray(params.inertia), (w * s, 1)), quat.reshape(-1, 4).astype(np.float32), dt)
  np.testing.assert_allclose(np.asarray(out.wrench).reshape(-1, 6), reference, rtol=1e-5, atol=1e-6)


def test_a_flex_is_perturbed_as_a_whole_within_its_bound(tiny_native):
  """Two of three bodies as one flex: one perturbation per flex-step, exactly
  where one of its bodies' velocity change is over C_v, bounded by α times the
  flex's (its bodies' mass-weighted mean), the same velocity change for each of
  its bodies (no jitter)."""
  mass = np.array([2.0, 0.5, 1.5], np.float32)
  weight = np.array([[0.0, 0.25, 0.75]], np.float32)
  params = tiny_native.params._replace(
      mass=jnp.asarray(mass), inertia=jnp.ones((3, 3)), perturbable=jnp.array([True, False, False]),
      flex_weight=jnp.asarray(weight), flex_perturbable=jnp.array([True]))
  rng = np.random.default_rng(5)
  w, s, b = 8, params.steps_per_frame, 3
  gravity = np.asarray(params.gravity)
  lin_acc = gravity + rng.normal(0, 1, (w, s, b, 3)) * rng.choice([1.0, 80.0, 400.0], (w, s, b, 1))
  zeros = np.zeros((w, s, b, 3))
  quat = np.tile([1.0, 0, 0, 0], (w, s, b, 1))
  obs = world.Observation(*(jnp.asarray(x, jnp.float32) for x in (zeros, quat, zeros, zeros, lin_acc, zeros)))
  carry = jax.vmap(world.init_carry, in_axes=(None, 0))(b, jnp.ones(w, bool))
  keys = jax.random.split(jax.random.key(4), w)
  _, out = jax.jit(lambda c, o, k: world.frame_update(c, o, k, params))(carry, obs, keys)
  dt = params.dt
  flex_delta = dt * np.einsum("b,wsbc->wsc", weight[0], lin_acc - gravity)  # numpy reference
  struck = np.linalg.norm(lin_acc - gravity, axis=-1) > params.perturb.linear_threshold
  expected = struck[:, :, 1:].any(axis=-1)
  assert expected.any() and (~expected).any()
  dv, dw = np.asarray(out.dv), np.asarray(out.dw)
  assert dv.shape == (w, s, b + 1, 3)
  assert not dv[:, :, 1:3].any() and not dw[:, :, 1:].any()  # never a vertex alone, never a spin
  flex_dv = dv[:, :, 3]
  np.testing.assert_array_equal(np.linalg.norm(flex_dv, axis=-1) > 0, expected)
  bound = params.perturb.alpha * np.linalg.norm(flex_delta, axis=-1)
  assert np.all(np.linalg.norm(flex_dv, axis=-1) <= bound * (1 + _BOUND_TOLERANCE))
  wrench = np.asarray(out.wrench)
  for body in (1, 2):
    np.testing.assert_allclose(wrench[:, :, body, :3] * dt / mass[body], flex_dv, rtol=1e-5, atol=1e-7)
    assert not wrench[:, :, body, 3:].any()


def test_sparse_batch_perturbations_match_dense_reference():
  """batch_perturbations (gathered, several rounds) equals drawing every entry."""
  rng = np.random.default_rng(1)
  w, s, b = 5, 4, 3
  delta_v = jnp.asarray(rng.normal(size=(w, s, b, 3)), jnp.float32)
  delta_w = jnp.asarray(rng.normal(size=(w, s, b, 3)), jnp.float32)
  lin = jnp.asarray(rng.random((w, s, b)) < 0.4)
  ang = jnp.asarray(rng.random((w, s, b)) < 0.2)
  keys = jax.random.split(jax.random.key(5), w)
  first = jnp.asarray(rng.integers(0, 1000, w), jnp.int32)
  params = perturb.PerturbParams()
  dv, dw = perturb.batch_perturbations(keys, first, delta_v, delta_w, lin, ang, params, cap=4)
  for i in range(w):
    for j in range(s):
      for k in range(b):
        u = perturb.body_step_uniforms(keys[i], first[i] + j, k)
        ref_v = perturb.perturbation_from_uniforms(u[:3], delta_v[i, j, k], params.alpha, params.lobe_exponent)
        ref_w = perturb.perturbation_from_uniforms(u[3:], delta_w[i, j, k], params.alpha, params.lobe_exponent)
        np.testing.assert_allclose(dv[i, j, k], ref_v if lin[i, j, k] else 0.0, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(dw[i, j, k], ref_w if ang[i, j, k] else 0.0, rtol=1e-6, atol=1e-7)


def test_impulse_wrench_changes_velocity_by_dv_in_mujoco():
  """One step with the wrench in MuJoCo C changes a free body's velocity by (dv, dw)."""
  xml = """<mujoco><option gravity="0 0 0" integrator="Euler"/><worldbody><body name="b" pos="0 0 1"
    euler="20 40 10"><freejoint/><geom type="box" size="0.1 0.05 0.02" mass="0.7"/></body></worldbody></mujoco>"""
  m = mujoco.MjModel.from_xml_string(xml)
  d = mujoco.MjData(m)
  mujoco.mj_forward(m, d)
  dv = np.array([0.3, -0.2, 0.1])
  dw = np.array([1.0, 0.5, -2.0])
  quat = np.zeros(4)
  mujoco.mju_mat2Quat(quat, d.ximat[1])
  wrench = perturb.impulse_wrench(jnp.asarray(dv), jnp.asarray(dw), m.body_mass[1], jnp.asarray(m.body_inertia[1]),
                                  jnp.asarray(quat), m.opt.timestep)
  d.xfrc_applied[1] = np.asarray(wrench, np.float64)
  mujoco.mj_step(m, d)
  mujoco.mj_forward(m, d)  # velocities of the new state
  vel = np.zeros(6)
  mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)  # (angular, linear), world frame
  np.testing.assert_allclose(vel[3:], dv, rtol=_WRENCH_TOLERANCE, atol=_WRENCH_TOLERANCE)
  np.testing.assert_allclose(vel[:3], dw, rtol=1e-3, atol=1e-3)  # Euler leaves gyroscopic O(dt) terms


def test_no_perturbations_in_free_flight():
  cfg = mwbx.config_from_dict({
      "scene": {"mjcf": "flight.xml"},
      "randomize": {"spinner": {"angular_velocity": {"dist": "normal", "scale": 6.0},
                                "linear_velocity": {"dist": "normal", "scale": 2.0}}},
      "sim": {"end_time": 0.6, "chunk_size": 8},
  }, source=str(__import__("pathlib").Path(__file__).parents[1] / "scenes" / "flight.yaml"))
  bank = mwbx.sample(cfg, n_worlds=8, key=jax.random.key(0), backend="native")
  assert bank.valid.all()
  assert (bank.perturbations == 0).all()
  assert (bank.metric("collisions") == 0).all()
  assert (bank.metric("angular_travel") > 0).all()
