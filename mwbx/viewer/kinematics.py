"""Body poses for display: forward kinematics on decoded generalized coordinates.

No physics runs here: `mujoco.mj_kinematics` maps each recorded `qpos` frame to
body positions and orientations, which become meshcat animation tracks.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mwbx.viewer.errors import ViewerError


def body_trajectories(model: mujoco.MjModel, qpos: np.ndarray,
                      body_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """World poses of some bodies over a recording.

  qpos: f[T, nq] generalized coordinates, one row per recorded frame.
  body_ids: i32[K] MuJoCo body ids.
  Returns (pos f64[T, K, 3] metres, quat f64[T, K, 4] wxyz), quaternions made
  sign-continuous over time so interpolating between frames takes the short way.
  """
  qpos = np.asarray(qpos, np.float64)
  if qpos.ndim != 2 or qpos.shape[1] != model.nq:
    raise ViewerError(f"qpos frames must have shape [T, nq={model.nq}], got {qpos.shape}")
  body_ids = np.asarray(body_ids, np.int64)
  n_frames = qpos.shape[0]
  pos = np.zeros((n_frames, body_ids.size, 3))
  quat = np.zeros((n_frames, body_ids.size, 4))
  data = mujoco.MjData(model)
  for t in range(n_frames):
    data.qpos[:] = qpos[t]
    mujoco.mj_kinematics(model, data)
    pos[t] = data.xpos[body_ids]
    quat[t] = data.xquat[body_ids]
  return pos, continuous_quaternions(quat)


def continuous_quaternions(quat: np.ndarray) -> np.ndarray:
  """Flip signs along axis 0 so consecutive quaternions have a non-negative dot.

  quat: f64[T, ..., 4] (q and -q are the same rotation). Returns a copy.
  """
  quat = np.array(quat, np.float64)
  if quat.shape[0] < 2:
    return quat
  dots = np.sum(quat[1:] * quat[:-1], axis=-1)
  flips = np.cumprod(np.where(dots < 0.0, -1.0, 1.0), axis=0)
  quat[1:] *= flips[..., None]
  return quat


def pad_frames(values: np.ndarray, n_frames: int) -> np.ndarray:
  """Extend f[T, ...] to f[n_frames, ...] by holding the last frame, so worlds
  with shorter recordings stay at rest while longer ones finish playing."""
  if values.shape[0] >= n_frames:
    return values[:n_frames]
  tail = np.repeat(values[-1:], n_frames - values.shape[0], axis=0)
  return np.concatenate([values, tail], axis=0)
