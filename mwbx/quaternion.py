"""Quaternion arithmetic in JAX, (w, x, y, z) order, shared by the packages."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def multiply(a: jax.Array, b: jax.Array, axis: int = -1) -> jax.Array:
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
