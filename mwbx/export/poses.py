"""One world's motion as arrays: decoded ``qpos`` and every body's pose.

What every export writes comes from here: the world's recorded ``qpos``
frames as the bank decodes them (``Bank.qpos_frames``, bit-exact for a raw
store, within the codec's bounds of what was simulated for a compressed one)
and forward kinematics on each frame (``mujoco.mj_kinematics``, the viewer's
:func:`mwbx.viewer.kinematics.body_trajectories`). No physics runs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.viewer.kinematics import body_trajectories

# Slack on frame boundaries (frames): a time given to the microsecond still
# lands on its frame.
_FRAME_SLACK = 1e-6
# Highest clip rate, Hz, unless the recording's own rate is higher: beyond
# it frames only repeat, and their arrays would fill memory.
MAX_FPS = 1000.0


class WorldPoses(NamedTuple):
  """Decoded motion of one world over a clip.

  Attributes:
    world: the world id.
    fps: frames per second of this clip (``record_fps`` unless resampled).
    record_fps: the bank's recording rate, Hz.
    times: f64[T] seconds since the world started, of each clip frame
      (``times[k] = start + k / fps``; at the recording rate ``frames / record_fps``).
    frames: i64[T] the recorded frame shown at each clip frame (the nearest
      one when resampled).
    qpos: f32[T, nq] decoded generalized coordinates, exactly as
      ``bank.qpos_frames`` returns them (m for translations, unit wxyz
      quaternions, rad or m for hinges and slides).
    body_names: the model's body names by MuJoCo body id (``body_names[0]``
      is the world body; unnamed bodies are ``body<id>``).
    xpos: f64[T, nbody, 3] body frame origins in the world frame, m.
    xquat: f64[T, nbody, 4] body orientations in the world frame, unit wxyz
      quaternions, signs continuous over time.
    present: bool[T, nbody] False while a body belongs to an object absent
      from the world then (``bank.absent``: parked out of sight).
  """

  world: int
  fps: float
  record_fps: float
  times: np.ndarray
  frames: np.ndarray
  qpos: np.ndarray
  body_names: tuple[str, ...]
  xpos: np.ndarray
  xquat: np.ndarray
  present: np.ndarray


def body_names(model: mujoco.MjModel) -> tuple[str, ...]:
  """Every body's name by MuJoCo body id, ``body<id>`` for unnamed ones."""
  return tuple(model.body(b).name or f"body{b}" for b in range(model.nbody))


def clip_frames(n_frames: int, record_fps: float, fps: float | None = None, start: float = 0.0,
                stop: float | None = None) -> tuple[np.ndarray, np.ndarray]:
  """Which recorded frames a clip shows, and when.

  Args:
    n_frames: frames recorded (frame f at f / record_fps s).
    record_fps: the recording rate, Hz.
    fps: the clip's rate, Hz; None keeps every recorded frame in the clip.
    start, stop: the clip's time span, s (stop None or past the end: the end).

  Returns:
    (frames i64[T], times f64[T] s): each clip frame's recorded frame (the
    nearest one when resampled) and its time, ``start + k / fps``.

  Raises:
    MwbxError: naming fps, start or stop when they are not finite, fps is
      not positive or above max(MAX_FPS, record_fps), or the span holds no frame.

  Example:
    >>> clip_frames(601, 120.0, fps=30.0)[0][:3]   # every 4th frame
    array([0, 4, 8])
  """
  duration = (n_frames - 1) / record_fps
  for name, value in (("fps", fps), ("start", start), ("stop", stop)):
    number = isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
    if value is not None and not (number and math.isfinite(value)):
      raise MwbxError(f"{name}: must be a finite number, got {value!r}")
  if fps is not None and fps <= 0:
    raise MwbxError(f"fps: must be positive, got {fps!r}")
  most = max(MAX_FPS, float(record_fps))
  if fps is not None and fps > most:  # every clip frame is kept in memory: a huge rate would exhaust it
    raise MwbxError(f"fps: must be at most {most:g} frames per second, got {fps!r}")
  if stop is not None and stop < 0:
    raise MwbxError(f"stop: must be >= 0 s, got {stop!r}")
  stop = duration if stop is None else min(float(stop), duration)
  if start < 0 or start > stop:
    raise MwbxError(f"start: must be in [0, {stop:g}] s (the clip ends at {stop:g} s), got {start!r}")
  if fps is None:
    first = math.ceil(start * record_fps - _FRAME_SLACK)
    last = math.floor(stop * record_fps + _FRAME_SLACK)
    frames = np.arange(first, last + 1, dtype=np.int64)
    return frames, frames / float(record_fps)
  count = math.floor((stop - start) * fps + _FRAME_SLACK) + 1
  times = float(start) + np.arange(count, dtype=np.float64) / float(fps)
  frames = np.clip(np.rint(times * record_fps), 0, n_frames - 1).astype(np.int64)
  return frames, times


def presence(bank, world: int, model: mujoco.MjModel, times: np.ndarray) -> np.ndarray:
  """bool[T, nbody] whether each body is in world ``world`` at ``times`` (s):
  False for the bodies of the objects ``bank.absent(world)`` names, over
  their absent spans (every body of an object's kinematic trees)."""
  present = np.ones((times.size, model.nbody), bool)
  objects = dict(bank.objects)
  for name, (since, until) in bank.absent(world).items():
    roots = {int(model.body_rootid[model.body(b).id]) for b in objects.get(name, ())}
    bodies = np.flatnonzero(np.isin(model.body_rootid, list(roots)))
    away = (times >= since) & (times < until)
    present[np.ix_(away, bodies)] = False
  return present


def world_poses(bank, world: int, *, fps: float | None = None, start: float = 0.0,
                stop: float | None = None) -> WorldPoses:
  """Decodes one world and runs forward kinematics on each of its frames.

  Args:
    bank: a :class:`mwbx.Bank`.
    world: world id.
    fps: clip rate, Hz; None (default) keeps every recorded frame
      (``bank.record_fps``), else the nearest recorded frame to each
      ``start + k / fps``.
    start, stop: time span, s (default: the whole recording).

  Returns:
    the :class:`WorldPoses` of the clip.

  Raises:
    MwbxError: naming the world when the bank does not hold it, it has no
      frames or non-finite ones (an unstable world), or naming a bad fps/span.

  Example:
    >>> poses = world_poses(bank, 3)
    >>> poses.xpos.shape        # (T, nbody, 3), metres
    (601, 9, 3)
  """
  world = int(world)
  n_frames = int(bank.frame_count[bank.row_of(world)])
  if n_frames == 0:
    raise MwbxError(f"world {world}: no recorded frames (frame_count is 0)")
  frames, times = clip_frames(n_frames, float(bank.record_fps), fps, start, stop)
  if frames.size == 0:
    raise MwbxError(f"world {world}: no recorded frame between {start:g} and {stop:g} s")
  first = int(frames.min())
  qpos = bank.qpos_frames(world, first, int(frames.max()) + 1)[frames - first]
  if not np.all(np.isfinite(qpos)):
    raise MwbxError(f"world {world}: its recorded coordinates are not finite (an unstable world); "
                    "nothing to export")
  model = bank.model
  xpos, xquat = body_trajectories(model, qpos, np.arange(model.nbody))
  return WorldPoses(world=world, fps=float(bank.record_fps if fps is None else fps),
                    record_fps=float(bank.record_fps), times=times, frames=frames, qpos=qpos,
                    body_names=body_names(model), xpos=xpos, xquat=xquat,
                    present=presence(bank, world, model, times))
