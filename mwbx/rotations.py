"""Rotation helpers, (w, x, y, z) quaternions, shared by every package.

JAX forms and their numpy twins side by side (as brax's ``math.py`` does);
the numba twin of :func:`quat_to_matrix` used inside the compiled per-world
loop is ``mwbx.batch_sim.host_loops.rotation_matrix``. ``tests/codec/test_rotations.py``
compares each form with its twin and with MuJoCo's ``mju_*`` functions.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_MJMINVAL = 1e-15  # MuJoCo's mjMINVAL: below it a vector has no direction (MuJoCo's normalize)


def quat_multiply(a: jax.Array, b: jax.Array, axis: int = -1) -> jax.Array:
  """Hamilton product ``a (x) b``; the 4 components lie along ``axis`` of both
  (``f32[..., 4]`` by default, ``axis=0`` for ``f32[4, ...]``)."""
  aw, ax, ay, az = (jnp.take(a, i, axis=axis) for i in range(4))
  bw, bx, by, bz = (jnp.take(b, i, axis=axis) for i in range(4))
  return jnp.stack([
      aw * bw - ax * bx - ay * by - az * bz,
      aw * bx + ax * bw + ay * bz - az * by,
      aw * by - ax * bz + ay * bw + az * bx,
      aw * bz + ax * by - ay * bx + az * bw,
  ], axis=axis)


def quat_multiply_np(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """numpy twin of :func:`quat_multiply` (components last; ``mju_mulQuat``'s
  order of operations, so float64 inputs give its result bit for bit)."""
  aw, ax, ay, az = (a[..., i] for i in range(4))
  bw, bx, by, bz = (b[..., i] for i in range(4))
  return np.stack([
      aw * bw - ax * bx - ay * by - az * bz,
      aw * bx + ax * bw + ay * bz - az * by,
      aw * by - ax * bz + ay * bw + az * bx,
      aw * bz + ax * by - ay * bx + az * bw,
  ], axis=-1)


def quat_conjugate_np(q: np.ndarray) -> np.ndarray:
  """``q``'s conjugate (the inverse of a unit quaternion), f[..., 4]; ``mju_negQuat``."""
  return q * np.array([1.0, -1.0, -1.0, -1.0], q.dtype)


def quat_to_velocity_np(q: np.ndarray, dt: float) -> np.ndarray:
  """f64[..., 3] the angular velocity turning by unit quaternions ``q``
  (f64[..., 4]) in ``dt`` seconds, the short way round; ``mju_quat2Vel``."""
  axis = np.array(q[..., 1:], np.float64)
  sin_half = np.sqrt(axis[..., 0] * axis[..., 0] + axis[..., 1] * axis[..., 1] + axis[..., 2] * axis[..., 2])
  tiny = sin_half < _MJMINVAL
  axis = np.where(tiny[..., None], np.array([1.0, 0.0, 0.0]), axis * (1 / np.where(tiny, 1.0, sin_half))[..., None])
  speed = 2 * np.arctan2(sin_half, q[..., 0])
  speed = np.where(speed > np.pi, speed - 2 * np.pi, speed) / dt
  return axis * speed[..., None]


def quat_to_matrix(q: jax.Array) -> jax.Array:
  """f32[..., 3, 3] rotation matrices of unit quaternions ``q: f32[..., 4]``."""
  w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
  return jnp.stack([
      jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
      jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
      jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
  ], -2)


def rotation_angle(q1: jax.Array, q2: jax.Array) -> jax.Array:
  """f32[...] angle in radians of the rotation between unit quaternions ``f32[..., 4]``."""
  dot = jnp.abs(jnp.sum(q1 * q2, axis=-1))
  return 2.0 * jnp.arccos(jnp.clip(dot, 0.0, 1.0))


def rotation_angle_np(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
  """numpy twin of :func:`rotation_angle`."""
  dot = np.abs(np.sum(q1 * q2, axis=-1))
  return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def quat_exp(omega: jax.Array) -> jax.Array:
  """Unit quaternion of rotation vector ``omega`` (radians), components first:
  f32[3, N] -> f32[4, N]."""
  theta = jnp.sqrt(jnp.sum(omega * omega, axis=0))
  safe = jnp.where(theta > 1e-12, theta, 1.0)
  factor = jnp.where(theta > 1e-12, jnp.sin(0.5 * theta) / safe, 0.5)
  return jnp.concatenate([jnp.cos(0.5 * theta)[None], factor * omega])


def quat_from_rotvec(rotvec: jax.Array) -> jax.Array:
  """f32[4] unit quaternion of one rotation vector ``f32[3]`` (radians), by angle
  and axis (the initial-state randomization's form; :func:`quat_exp` is the
  codec's batched one)."""
  angle = jnp.linalg.norm(rotvec)
  safe = jnp.where(angle > 1e-12, angle, 1.0)
  axis = jnp.where(angle > 1e-12, rotvec / safe, jnp.array([1.0, 0.0, 0.0]))
  return jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * axis])
