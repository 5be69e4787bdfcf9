"""Observing free bodies from their states instead of MuJoCo's sensors.

The bookkeeping reads, per tracked body and step, the block of
:data:`mwbx.scene.SENSORS`. For a body whose only joint is a free joint hanging
off the world body, the states before and after a step already hold all of it:
the COM is ``pos + R·ipos``, its orientation ``quat ⊗ iquat``, the angular
velocity ``R·ω_local``, the COM velocity ``v + ω × R·ipos``, and the
accelerations are the velocity changes across the step over ``dt`` (the linear
one minus gravity, as MuJoCo's sensor reports it). So when every tracked body
is such a body, the backends step a copy of the model with sensors disabled:
the acceleration sensors alone make MuJoCo run its post-constraint pass every
step (up to 15–25 % of a step on CPU). Scenes with articulated objects keep the
sensors.

:func:`observe` is the kernel for ONE world (JAX, for MJX);
:func:`mwbx.batch_sim.host_loops.observe_free_bodies` is its compiled host
form for the native backend. Tests compare both with MuJoCo's sensors.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import rotations
from mwbx.joints import JNT_FREE
from mwbx.scene import SENSORS


class FreeBodies(NamedTuple):
  """Where each tracked free body lives in the state (static, host arrays).

  Attributes:
    qpos_adr: i64[B] qpos address of the body's free joint.
    dof_adr: i64[B] its dof address.
    ipos: f64[B, 3] COM in the body frame, m.
    iquat: f64[B, 4] inertial frame orientation in the body frame.
  """

  qpos_adr: np.ndarray
  dof_adr: np.ndarray
  ipos: np.ndarray
  iquat: np.ndarray


def free_bodies(model: mujoco.MjModel, body_ids) -> FreeBodies | None:
  """The tracked bodies' :class:`FreeBodies`, or None if one of them is not a
  free body hanging off the world body (its only joint a free joint)."""
  ids = np.asarray(body_ids, np.int64)
  joints = model.body_jntadr[ids]
  free = ((model.body_parentid[ids] == 0) & (model.body_jntnum[ids] == 1) & (joints >= 0)
          & (model.jnt_type[np.maximum(joints, 0)] == JNT_FREE))
  if ids.size == 0 or not free.all():
    return None
  return FreeBodies(model.jnt_qposadr[joints].astype(np.int64), model.jnt_dofadr[joints].astype(np.int64),
                    np.ascontiguousarray(model.body_ipos[ids]), np.ascontiguousarray(model.body_iquat[ids]))


def host_arrays(bodies: FreeBodies | None) -> tuple[bool, FreeBodies]:
  """(whether there are free bodies to observe from the states, ``bodies``
  for the compiled loops: empty arrays when ``bodies`` is None)."""
  if bodies is None:
    return False, FreeBodies(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
  return True, bodies


def quiet_copy(model: mujoco.MjModel) -> mujoco.MjModel:
  """A copy of ``model`` that steps with sensors disabled."""
  quiet = copy.copy(model)
  quiet.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
  return quiet


def observe(qpos: jax.Array, qvel: jax.Array, bodies: FreeBodies, dt: float, gravity: jax.Array) -> jax.Array:
  """The sensor block of ONE world's S steps from its S + 1 states.

  Args:
    qpos: f32[S + 1, nq] positions of s_k … s_{k+S}.
    qvel: f32[S + 1, nv] velocities of s_k … s_{k+S}.
    bodies: the tracked bodies (:func:`free_bodies`).
    dt: physics timestep, s.
    gravity: f32[3] m/s².

  Returns:
    f32[S, B * SENSOR_WIDTH] in :data:`mwbx.scene.SENSORS` order and units.
  """
  qa = np.asarray(bodies.qpos_adr)[:, None]
  da = np.asarray(bodies.dof_adr)[:, None]
  pos = qpos[:, qa + np.arange(3)]  # [S+1, B, 3]
  quat = qpos[:, qa + np.arange(3, 7)]
  quat = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
  rot = rotations.quat_to_matrix(quat)  # [S+1, B, 3, 3]
  offset = jnp.einsum("sbij,bj->sbi", rot, jnp.asarray(bodies.ipos, qpos.dtype))
  ang_vel = jnp.einsum("sbij,sbj->sbi", rot, qvel[:, da + np.arange(3, 6)])
  lin_vel = qvel[:, da + np.arange(3)] + jnp.cross(ang_vel, offset)
  com = pos + offset
  inertial_quat = rotations.quat_multiply(quat, jnp.asarray(bodies.iquat, qpos.dtype))
  lin_acc = (lin_vel[1:] - lin_vel[:-1]) / dt - gravity
  ang_acc = (ang_vel[1:] - ang_vel[:-1]) / dt
  part = {"com_pos": com[:-1], "quat": inertial_quat[:-1], "lin_vel": lin_vel[:-1], "ang_vel": ang_vel[:-1],
          "lin_acc": lin_acc, "ang_acc": ang_acc}
  block = jnp.concatenate([part[name] for name, _, _ in SENSORS], -1)  # the sensor block's order
  return block.reshape(block.shape[0], -1)
