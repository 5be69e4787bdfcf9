"""mwbx.rotations against its twins and MuJoCo C (float32 kernels: TOL)."""

import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import rotations
from mwbx.batch_sim import host_loops

TOL = 2e-6  # float32 rounding of products of unit quantities


def _unit_quats(n, seed=0):
  q = np.random.default_rng(seed).normal(size=(n, 4))
  return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quat_to_matrix_matches_numba_twin_and_mujoco():
  for q in _unit_quats(20):
    ref = np.zeros(9)
    mujoco.mju_quat2Mat(ref, q)
    got = np.asarray(rotations.quat_to_matrix(jnp.asarray(q, jnp.float32)))
    np.testing.assert_allclose(got.reshape(-1), ref, atol=TOL)
    np.testing.assert_allclose(np.array(host_loops.rotation_matrix(*q)), ref, atol=1e-12)


def test_quat_multiply_matches_mujoco_along_any_axis():
  a, b = _unit_quats(8, 1), _unit_quats(8, 2)
  ref = np.zeros((8, 4))
  for i in range(8):
    mujoco.mju_mulQuat(ref[i], a[i], b[i])
  np.testing.assert_allclose(np.asarray(rotations.quat_multiply(jnp.asarray(a), jnp.asarray(b))), ref,
                             atol=TOL)
  np.testing.assert_allclose(np.asarray(rotations.quat_multiply(jnp.asarray(a.T), jnp.asarray(b.T),
                                                                axis=0)).T, ref, atol=TOL)


def test_rotation_angle_twins_and_exp_forms():
  a, b = _unit_quats(16, 3), _unit_quats(16, 4)
  np.testing.assert_allclose(np.asarray(rotations.rotation_angle(jnp.asarray(a), jnp.asarray(b))),
                             rotations.rotation_angle_np(a, b), atol=1e-5)
  rotvec = np.random.default_rng(5).normal(size=(16, 3)) * 0.7
  batched = np.asarray(rotations.quat_exp(jnp.asarray(rotvec.T, jnp.float32))).T
  single = np.stack([np.asarray(rotations.quat_from_rotvec(jnp.asarray(v, jnp.float32))) for v in rotvec])
  ref = np.zeros((16, 4))
  for i, v in enumerate(rotvec):
    angle = np.linalg.norm(v)
    mujoco.mju_axisAngle2Quat(ref[i], v / angle, angle)
  np.testing.assert_allclose(batched, ref, atol=TOL)
  np.testing.assert_allclose(single, ref, atol=TOL)
  np.testing.assert_allclose(rotations.rotation_angle_np(ref, ref), 0.0, atol=1e-3)
  np.testing.assert_allclose(rotations.rotation_angle_np(ref, np.tile([1.0, 0, 0, 0], (16, 1))),
                             np.linalg.norm(rotvec, axis=1), atol=1e-6)


def test_numpy_twins_match_mujoco_relative_rotation_velocity():
  # float64 twins: MuJoCo's own operations, up to its compiler's rounding
  a, b = _unit_quats(64, 5), _unit_quats(64, 6)
  b[:4] = a[:4]  # no rotation: the degenerate axis
  b[4:8] = -a[4:8]  # the same rotation the long way round
  dt = 1 / 120
  ref = np.zeros((64, 3))
  for i in range(64):
    inv, rel = np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(inv, a[i])
    mujoco.mju_mulQuat(rel, b[i], inv)
    mujoco.mju_quat2Vel(ref[i], rel, dt)
  rel = rotations.quat_multiply_np(b, rotations.quat_conjugate_np(a))
  np.testing.assert_allclose(rotations.quat_to_velocity_np(rel, dt), ref, rtol=1e-12, atol=1e-9)
