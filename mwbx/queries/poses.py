"""Body poses from stored generalized coordinates, many frames at once.

`mujoco.mj_kinematics` maps one qpos to every body's pose; queries on whole
geometry and on orientation need the poses of a few bodies at every stored
frame of thousands of worlds. `body_poses` is the same forward kinematics
(tree order: parent frame, body offset, then the body's joints) written over
a leading frame axis in numpy, so a bank's frames go through it a block at a
time. `tests/queries/test_queries_orientation.py` checks it against `mj_kinematics`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mwbx.joints import JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """Hamilton product of f64[..., 4] (w, x, y, z) quaternions."""
  aw, ax, ay, az = np.moveaxis(a, -1, 0)
  bw, bx, by, bz = np.moveaxis(b, -1, 0)
  return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                   aw * bx + ax * bw + ay * bz - az * by,
                   aw * by - ax * bz + ay * bw + az * bx,
                   aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
  """v f64[..., 3] rotated by unit quaternions q f64[..., 4] (broadcast)."""
  w = q[..., :1]
  u = q[..., 1:]
  t = 2.0 * np.cross(u, v)
  return v + w * t + np.cross(u, t)


def quat_matrix(q: np.ndarray) -> np.ndarray:
  """f64[..., 3, 3] rotation matrices of unit quaternions f64[..., 4]."""
  w, x, y, z = np.moveaxis(q, -1, 0)
  return np.stack([
      np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
      np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
      np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
  ], -2)


def normalized(q: np.ndarray) -> np.ndarray:
  """Unit quaternions f64[..., 4]; a zero quaternion becomes the identity
  (as `mju_normalize4` does)."""
  norm = np.linalg.norm(q, axis=-1, keepdims=True)
  identity = np.zeros_like(q)
  identity[..., 0] = 1.0
  return np.where(norm > 1e-15, q / np.where(norm > 1e-15, norm, 1.0), identity)


def chain(model: mujoco.MjModel, body_ids) -> list[int]:
  """Bodies (ascending ids, so parents first) whose poses place the given
  bodies: the bodies themselves and their ancestors, without the world."""
  out = set()
  for body in np.asarray(body_ids, np.int64).reshape(-1).tolist():
    while body > 0:
      out.add(int(body))
      body = int(model.body_parentid[body])
  return sorted(out)


def body_poses(model: mujoco.MjModel, qpos: np.ndarray,
               body_ids) -> tuple[np.ndarray, np.ndarray]:
  """World poses of some bodies at many frames (forward kinematics).

  Args:
    model: the scene model.
    qpos: f[N, nq] generalized coordinates, one row per frame.
    body_ids: i[K] MuJoCo body ids.

  Returns:
    (xpos f64[N, K, 3] body frame origins, metres; xquat f64[N, K, 4] unit
    (w, x, y, z) orientations), as `mj_kinematics` computes them. Mocap
    bodies sit at their model pose.
  """
  qpos = np.asarray(qpos, np.float64)
  n = qpos.shape[0]
  body_ids = np.asarray(body_ids, np.int64).reshape(-1)
  pos = {0: np.zeros((n, 3))}
  quat = {0: np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (n, 1))}
  for b in chain(model, body_ids):
    parent = int(model.body_parentid[b])
    p = pos[parent] + quat_rotate(quat[parent], model.body_pos[b])
    q = quat_mul(quat[parent], np.broadcast_to(model.body_quat[b], (n, 4)))
    if int(model.body_mocapid[b]) >= 0:
      p = np.broadcast_to(model.body_pos[b], (n, 3)).copy()
      q = normalized(np.broadcast_to(model.body_quat[b], (n, 4)).copy())
    for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b] + model.body_jntnum[b])):
      kind = int(model.jnt_type[j])
      adr = int(model.jnt_qposadr[j])
      if kind == JNT_FREE:
        p = qpos[:, adr:adr + 3].copy()
        q = normalized(qpos[:, adr + 3:adr + 7])
        continue
      anchor = p + quat_rotate(q, model.jnt_pos[j])
      if kind == JNT_SLIDE:
        axis = quat_rotate(q, model.jnt_axis[j])
        p = p + axis * (qpos[:, adr:adr + 1] - model.qpos0[adr])
        continue
      if kind == JNT_BALL:
        local = normalized(qpos[:, adr:adr + 4])
      elif kind == JNT_HINGE:
        half = 0.5 * (qpos[:, adr] - model.qpos0[adr])
        local = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * model.jnt_axis[j]], axis=1)
      else:  # pragma: no cover - MuJoCo has no other joint types
        raise ValueError(f"joint type {kind}")
      q = quat_mul(q, local)
      p = anchor - quat_rotate(q, model.jnt_pos[j])
    pos[b] = p
    quat[b] = normalized(q)
  return (np.stack([pos[int(b)] for b in body_ids], axis=1),
          np.stack([quat[int(b)] for b in body_ids], axis=1))


def decoded_frames(bank, rows: np.ndarray, columns=None) -> list[np.ndarray]:
  """f32[n_w, nq] decoded stored qpos of bank rows (i64[k]), one per row."""
  return list(bank.qpos_store.frames_of_rows(np.asarray(rows, np.int64), columns=columns))


def padded(frames: list[np.ndarray], n_frames: int) -> np.ndarray:
  """f32[k, n_frames, nq]: each world's frames, its last frame held past its end
  (a world with no frames holds zeros)."""
  nq = frames[0].shape[1] if frames else 0
  out = np.zeros((len(frames), n_frames, nq), np.float32)
  for i, f in enumerate(frames):
    if len(f):
      out[i, :len(f)] = f[:n_frames]
      out[i, len(f):] = f[-1]
  return out
