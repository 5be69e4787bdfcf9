"""Kept poses and sweep margins of a block of worlds, in one compiled loop.

The geometry index needs, per world and tracked body, the pose at every kept
frame and the sweep margin of every interval between kept frames
(:func:`.geometry.sweep_margins`), both from forward kinematics on every
stored frame. `kept_poses` does the two in one pass per world without
materialising the poses of every stored frame: the same arithmetic as
:func:`.poses.body_poses` (tree order: parent frame, body offset, then the
body's joints) and `sweep_margins`, in float64 (the tests compare them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numba
import numpy as np

from mwbx.joints import JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE
from mwbx.queries import poses as poses_lib


class KinematicTree(NamedTuple):
  """What forward kinematics of the bodies placing some tracked ones needs of a model.

  Attributes:
    chain: i64[C] bodies placing the tracked ones, parents first.
    parent: i64[nbody] parent body; mocap: i64[nbody] mocap id (-1: none).
    body_pos: f64[nbody, 3] offset in the parent's frame, m; body_quat: f64[nbody, 4].
    jnt_start, jnt_count: i64[nbody] each body's joints.
    jnt_type, jnt_adr: i64[njnt] joint kind (mjtJoint) and qpos address.
    jnt_pos: f64[njnt, 3] anchor in the body frame, m; jnt_axis: f64[njnt, 3].
    qpos0: f64[nq] the reference configuration (hinge and slide zero).
  """

  chain: np.ndarray
  parent: np.ndarray
  mocap: np.ndarray
  body_pos: np.ndarray
  body_quat: np.ndarray
  jnt_start: np.ndarray
  jnt_count: np.ndarray
  jnt_type: np.ndarray
  jnt_adr: np.ndarray
  jnt_pos: np.ndarray
  jnt_axis: np.ndarray
  qpos0: np.ndarray


def tree(model: mujoco.MjModel, body_ids) -> KinematicTree:
  """The :class:`KinematicTree` placing the given bodies."""
  return KinematicTree(
      np.array(poses_lib.chain(model, body_ids), np.int64).reshape(-1),
      np.asarray(model.body_parentid, np.int64), np.asarray(model.body_mocapid, np.int64),
      np.asarray(model.body_pos, np.float64), np.asarray(model.body_quat, np.float64),
      np.asarray(model.body_jntadr, np.int64), np.asarray(model.body_jntnum, np.int64),
      np.asarray(model.jnt_type, np.int64).reshape(-1), np.asarray(model.jnt_qposadr, np.int64).reshape(-1),
      np.asarray(model.jnt_pos, np.float64).reshape(-1, 3), np.asarray(model.jnt_axis, np.float64).reshape(-1, 3),
      np.asarray(model.qpos0, np.float64))


@numba.njit(cache=True, nogil=True, inline="always")
def _mul(a, b, out):
  """Hamilton product of (w, x, y, z) quaternions into out."""
  w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
  x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
  y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
  z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
  out[0], out[1], out[2], out[3] = w, x, y, z


@numba.njit(cache=True, nogil=True, inline="always")
def _rotate(q, v, out):
  """v rotated by unit quaternion q into out (as `poses.quat_rotate`)."""
  tx = 2.0 * (q[2] * v[2] - q[3] * v[1])
  ty = 2.0 * (q[3] * v[0] - q[1] * v[2])
  tz = 2.0 * (q[1] * v[1] - q[2] * v[0])
  out[0] = v[0] + q[0] * tx + (q[2] * tz - q[3] * ty)
  out[1] = v[1] + q[0] * ty + (q[3] * tx - q[1] * tz)
  out[2] = v[2] + q[0] * tz + (q[1] * ty - q[2] * tx)


@numba.njit(cache=True, nogil=True, inline="always")
def _normalize(q):
  """q made unit in place; a zero quaternion becomes the identity."""
  norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
  if norm > 1e-15:
    for a in range(4):
      q[a] /= norm
  else:
    q[0], q[1], q[2], q[3] = 1.0, 0.0, 0.0, 0.0


@numba.njit(cache=True, nogil=True)
def _kinematics(qpos, tree, pos, quat):
  """Forward kinematics of one frame (tree: :class:`KinematicTree`): pos
  f64[nbody, 3], quat f64[nbody, 4] filled for the chain's bodies (row 0,
  the world, holds the identity)."""
  chain, parent, mocap, body_pos, body_quat = tree.chain, tree.parent, tree.mocap, tree.body_pos, tree.body_quat
  jnt_start, jnt_count, jnt_type, jnt_adr = tree.jnt_start, tree.jnt_count, tree.jnt_type, tree.jnt_adr
  jnt_pos, jnt_axis, qpos0 = tree.jnt_pos, tree.jnt_axis, tree.qpos0
  tmp = np.empty(3)
  tmp2 = np.empty(3)
  local = np.empty(4)
  q2 = np.empty(4)
  for i in range(chain.shape[0]):
    b = chain[i]
    par = parent[b]
    if mocap[b] >= 0:
      for a in range(3):
        pos[b, a] = body_pos[b, a]
      for a in range(4):
        quat[b, a] = body_quat[b, a]
      _normalize(quat[b])
    else:
      _rotate(quat[par], body_pos[b], tmp)
      for a in range(3):
        pos[b, a] = pos[par, a] + tmp[a]
      _mul(quat[par], body_quat[b], quat[b])
    for j in range(jnt_start[b], jnt_start[b] + jnt_count[b]):
      kind = jnt_type[j]
      adr = jnt_adr[j]
      if kind == 0:  # free
        for a in range(3):
          pos[b, a] = qpos[adr + a]
        for a in range(4):
          quat[b, a] = qpos[adr + 3 + a]
        _normalize(quat[b])
        continue
      _rotate(quat[b], jnt_pos[j], tmp)  # anchor = p + tmp
      if kind == 2:  # slide
        _rotate(quat[b], jnt_axis[j], tmp2)
        shift = qpos[adr] - qpos0[adr]
        for a in range(3):
          pos[b, a] += tmp2[a] * shift
        continue
      if kind == 1:  # ball
        for a in range(4):
          local[a] = qpos[adr + a]
        _normalize(local)
      else:  # hinge
        half = 0.5 * (qpos[adr] - qpos0[adr])
        local[0] = math.cos(half)
        s = math.sin(half)
        for a in range(3):
          local[a + 1] = s * jnt_axis[j, a]
      _mul(quat[b], local, q2)
      for a in range(4):
        quat[b, a] = q2[a]
      _rotate(quat[b], jnt_pos[j], tmp2)
      for a in range(3):
        pos[b, a] = pos[b, a] + tmp[a] - tmp2[a]
    _normalize(quat[b])


@numba.njit(cache=True, nogil=True)
def kept_poses(qpos, tree, body_ids, ipos, reach, stride, com_out, quat_out, sweep_out):
  """Poses at kept frames and sweep margins of a block of worlds.

  Args:
    qpos: f32[w, T, nq] stored frames, T = 1 + k stride.
    tree: the :class:`KinematicTree` of :func:`tree`.
    body_ids: i64[B]; ipos: f64[B, 3] COM in the body frame; reach: f64[B].
    stride: stored frames per interval.
    com_out: f32[B, w, k + 1, 3], quat_out: f32[B, w, k + 1, 4] poses at
      the kept frames; sweep_out: f32[B, w, k] margins (written).
  """
  n_worlds, n_frames = qpos.shape[0], qpos.shape[1]
  n_bodies = body_ids.shape[0]
  n_int = (n_frames - 1) // stride
  nbody = tree.parent.shape[0]
  pos = np.zeros((nbody, 3))
  quat = np.zeros((nbody, 4))
  quat[0, 0] = 1.0
  c = np.empty((stride + 1, n_bodies, 3))  # one interval's COMs and orientations
  q = np.empty((stride + 1, n_bodies, 4))
  tmp = np.empty(3)
  frame = np.empty(qpos.shape[2])
  for w in range(n_worlds):
    for i in range(n_int):
      for s in range(stride + 1):
        if s == 0 and i > 0:  # the previous interval's end
          c[0] = c[stride]
          q[0] = q[stride]
          continue
        for a in range(qpos.shape[2]):
          frame[a] = qpos[w, i * stride + s, a]
        _kinematics(frame, tree, pos, quat)
        for k in range(n_bodies):
          b = body_ids[k]
          _rotate(quat[b], ipos[k], tmp)
          for a in range(3):
            c[s, k, a] = pos[b, a] + tmp[a]
          for a in range(4):
            q[s, k, a] = quat[b, a]
      for k in range(n_bodies):
        if i == 0:
          for a in range(3):
            com_out[k, w, 0, a] = c[0, k, a]
          for a in range(4):
            quat_out[k, w, 0, a] = q[0, k, a]
        for a in range(3):
          com_out[k, w, i + 1, a] = c[stride, k, a]
        for a in range(4):
          quat_out[k, w, i + 1, a] = q[stride, k, a]
        to_ends = 0.0
        step = 0.0
        finite = True
        for s in range(stride + 1):
          for a in range(3):
            finite &= math.isfinite(c[s, k, a])
          for a in range(4):
            finite &= math.isfinite(q[s, k, a])
          near = math.inf
          for end in (0, stride):
            dc = math.sqrt((c[s, k, 0] - c[end, k, 0])**2 + (c[s, k, 1] - c[end, k, 1])**2
                           + (c[s, k, 2] - c[end, k, 2])**2)
            dot = abs(q[s, k, 0] * q[end, k, 0] + q[s, k, 1] * q[end, k, 1] + q[s, k, 2] * q[end, k, 2]
                      + q[s, k, 3] * q[end, k, 3])
            chord = 2.0 * math.sqrt(min(max(1.0 - dot * dot, 0.0), 1.0))
            near = min(near, dc + chord * reach[k])
          to_ends = max(to_ends, near)
          if s < stride:
            dc = math.sqrt((c[s + 1, k, 0] - c[s, k, 0])**2 + (c[s + 1, k, 1] - c[s, k, 1])**2
                           + (c[s + 1, k, 2] - c[s, k, 2])**2) / 2.0
            dot = abs(q[s + 1, k, 0] * q[s, k, 0] + q[s + 1, k, 1] * q[s, k, 1] + q[s + 1, k, 2] * q[s, k, 2]
                      + q[s + 1, k, 3] * q[s, k, 3])
            quarter = 2.0 * math.sqrt(min(max((1.0 - dot) / 2.0, 0.0), 1.0))
            step = max(step, dc + quarter * reach[k])
        sweep_out[k, w, i] = to_ends + step if finite else math.inf
    if n_int == 0:  # one stored frame: one kept pose, no interval
      for a in range(qpos.shape[2]):
        frame[a] = qpos[w, 0, a]
      _kinematics(frame, tree, pos, quat)
      for k in range(n_bodies):
        b = body_ids[k]
        _rotate(quat[b], ipos[k], tmp)
        for a in range(3):
          com_out[k, w, 0, a] = pos[b, a] + tmp[a]
        for a in range(4):
          quat_out[k, w, 0, a] = quat[b, a]


assert (JNT_FREE, JNT_BALL, JNT_SLIDE, JNT_HINGE) == (0, 1, 2, 3)  # the codes the loop tests
