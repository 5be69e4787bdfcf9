"""A world as a NumPy ``.npz`` file: decoded ``qpos`` and every body's pose."""

from __future__ import annotations

import io
import os
import pathlib

import numpy as np

from mwbx.export import target
from mwbx.export.poses import world_poses


def export_npz(bank, world: int, path: str | os.PathLike, *, start: float = 0.0,
               stop: float | None = None) -> pathlib.Path:
  """Writes world ``world``'s decoded motion to ``path`` (a ``.npz`` file).

  Every recorded frame in ``[start, stop]`` s is written, at ``bank.record_fps``.

  Arrays in the file (T frames, nq coordinates, nbody bodies including the
  world body, MuJoCo body ids as indices):

  * ``qpos``: f32[T, nq] decoded generalized coordinates, exactly
    ``bank.qpos_frames(world)`` (m, unit wxyz quaternions, rad or m);
  * ``xpos``: f64[T, nbody, 3] body origins in the world frame, m;
  * ``xquat``: f64[T, nbody, 4] body orientations, unit wxyz quaternions;
  * ``present``: bool[T, nbody] False while a body's object is absent;
  * ``times``: f64[T] s; ``frames``: i64[T] recorded frame numbers;
  * ``body_names``: str[nbody]; ``fps``, ``world``: scalars.

  Args:
    bank: a :class:`mwbx.Bank`.
    world: world id.
    path: the ``.npz`` file to write: a new file, or a regular file replaced
      whole or not at all (a symlink, FIFO, device or directory is refused).
    start, stop: time span, s (default: the whole recording).

  Returns:
    the path written.

  Raises:
    MwbxError: naming the world, span, file or folder at fault.

  Example:
    >>> export_npz(bank, 3, "world3.npz")
    >>> np.load("world3.npz")["xpos"].shape     # (T, nbody, 3)
  """
  target.check_target(path, "npz")  # before decoding: a bad name costs nothing
  poses = world_poses(bank, world, start=start, stop=stop)
  buffer = io.BytesIO()
  np.savez_compressed(buffer, qpos=poses.qpos, xpos=poses.xpos, xquat=poses.xquat, present=poses.present,
                      times=poses.times, frames=poses.frames, body_names=np.asarray(poses.body_names, str),
                      fps=np.float64(poses.fps), world=np.int64(poses.world))
  return target.write_bytes(path, buffer.getvalue(), "npz", what="npz export")
