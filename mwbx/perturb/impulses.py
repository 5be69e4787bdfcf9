"""Plausible impulse perturbations at impacts (paper §2), for ONE body.

After each physics step the velocity change a body got from contacts and
constraints (the step's change minus what gravity alone gives) is compared with
thresholds ``C_v`` (m/s²) and ``C_ω`` (rad/s²) on its magnitude per second.
Where a threshold is exceeded, a perturbation ``m·d`` is drawn: the direction
``d`` from a Phong lobe ``p(d) ∝ cosⁿθ`` about the impulse direction (the
paper's "sinⁿ distribution, commonly used in the Phong lighting model"), the
signed magnitude ``m`` uniform in ``[-α‖Δv‖, α‖Δv‖]``. So ``‖m·d‖ ≤ α‖Δv‖``
holds for every sample by construction: that is the plausibility bound.

The perturbation is applied as a wrench at the centre of mass during the next
physics step (``force = mass·Δv_pert/dt``, ``torque = I_world·Δω_pert/dt``),
which works for free bodies and articulated links on every backend.

All functions are pure JAX on one body; vmap them over bodies and worlds.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mwbx import rotations


class PerturbParams(NamedTuple):
  """Perturbation parameters (floats, may be traced).

  Attributes:
    alpha: magnitude fraction α of ‖Δv‖ (paper: 0.1).
    lobe_exponent: n of the ``cosⁿθ`` lobe about ‖Δv‖'s direction.
    linear_threshold: C_v, m/s².
    angular_threshold: C_ω, rad/s².
  """

  alpha: float = 0.1
  lobe_exponent: float = 20.0
  linear_threshold: float = 100.0
  angular_threshold: float = 2000.0


def velocity_change(lin_acc: jax.Array, ang_acc: jax.Array, gravity: jax.Array, dt: float):
  """The step's velocity change not explained by gravity.

  Args:
    lin_acc: f32[3] centre-of-mass acceleration of the step, m/s².
    ang_acc: f32[3] angular acceleration, rad/s².
    gravity: f32[3] the model's gravity, m/s².
    dt: physics timestep, s.

  Returns:
    (delta_v f32[3] m/s, delta_w f32[3] rad/s).
  """
  return dt * (lin_acc - gravity), dt * ang_acc


def orthonormal_basis(axis: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Two unit vectors orthogonal to the unit vector ``axis`` and each other."""
  # Cross with the world axis least aligned with ``axis``: never degenerate.
  helper = jnp.eye(3, dtype=axis.dtype)[jnp.argmin(jnp.abs(axis))]
  u = jnp.cross(axis, helper)
  u = u / jnp.linalg.norm(u)
  return u, jnp.cross(axis, u)


def lobe_direction(u_theta: jax.Array, u_phi: jax.Array, axis: jax.Array, exponent: float) -> jax.Array:
  """A unit vector of the Phong lobe ``p(d) ∝ cosⁿθ`` about ``axis`` from two uniforms.

  ``cos θ = u_theta^(1/(n+1))`` is the inverse CDF of the angle density
  ``(n+1)·cosⁿθ·sinθ`` on the hemisphere about ``axis``; ``φ = 2π·u_phi``.

  Args:
    u_theta, u_phi: uniforms in [0, 1).
    axis: f32[3] any nonzero vector (normalized here); zero gives +x.
    exponent: lobe exponent n ≥ 0 (0 = uniform hemisphere).

  Returns:
    f32[3] unit direction.
  """
  norm = jnp.linalg.norm(axis)
  axis = jnp.where(norm > 0, axis / jnp.where(norm > 0, norm, 1.0), jnp.array([1.0, 0.0, 0.0], axis.dtype))
  cos_theta = u_theta ** (1.0 / (exponent + 1.0))
  sin_theta = jnp.sqrt(jnp.maximum(0.0, 1.0 - cos_theta * cos_theta))
  phi = 2.0 * jnp.pi * u_phi
  e1, e2 = orthonormal_basis(axis)
  d = cos_theta * axis + sin_theta * (jnp.cos(phi) * e1 + jnp.sin(phi) * e2)
  return d / jnp.linalg.norm(d)


def sample_lobe_direction(key: jax.Array, axis: jax.Array, exponent: float) -> jax.Array:
  """:func:`lobe_direction` with its two uniforms drawn from ``key``."""
  u = jax.random.uniform(key, (2,), axis.dtype)
  return lobe_direction(u[0], u[1], axis, exponent)


def perturbation_from_uniforms(u: jax.Array, delta: jax.Array, alpha: float, exponent: float) -> jax.Array:
  """``m·d`` from three uniforms ``u``: d from the lobe about ``delta`` (u[0], u[1]),
  m uniform in ±α‖delta‖ (u[2])."""
  direction = lobe_direction(u[0], u[1], delta, exponent)
  magnitude = (2.0 * u[2] - 1.0) * alpha * jnp.linalg.norm(delta)
  return magnitude * direction


def impulse_wrench(dv: jax.Array, dw: jax.Array, mass: jax.Array, inertia: jax.Array,
                   quat: jax.Array, dt: float) -> jax.Array:
  """The wrench at the COM that changes a free body's velocity by (dv, dw) in one step.

  Args:
    dv: f32[3] linear velocity change, m/s.
    dw: f32[3] angular velocity change (world frame), rad/s.
    mass: body mass, kg.
    inertia: f32[3] principal moments of inertia, kg·m².
    quat: f32[4] orientation of the inertial frame (w, x, y, z).
    dt: timestep, s.

  Returns:
    f32[6] (force N, torque N·m) in the world frame, as in ``xfrc_applied``.
  """
  rot = rotations.quat_to_matrix(quat / jnp.linalg.norm(quat))
  inertia_world = rot @ jnp.diag(inertia) @ rot.T
  return jnp.concatenate([mass * dv, inertia_world @ dw]) / dt
