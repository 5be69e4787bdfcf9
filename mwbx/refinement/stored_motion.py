"""Stored-motion playback for refinement (paper §5, Fig. 7 LOAD-STORED-MOTION).

A refined world replays its parent's *decoded* path for every object that is
not simulated: ``qpos`` at the frames, ``qvel`` by differentiating the decoded
path with ``mujoco.mj_differentiatePos`` (the chord velocity from frame f to
f + 1), and between frames ``mj_integratePos`` of that velocity, so that the
playback passes exactly through every stored frame. The same path gives the
ghosts' and the inactive objects' body positions (forward kinematics of the
decoded frames) and the metrics of the part of the world before t_min.

Everything here runs once per refinement on the host (a few hundred frames
of one world); the per-step work is array indexing in the loops.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import mujoco
import numpy as np

from mwbx import scene as scene_lib

from mwbx import rotations
from mwbx.batch_sim import world


class StoredPath(NamedTuple):
  """The parent world's decoded motion over the refined worlds' horizon.

  Frames past the parent's last recorded frame hold it (zero velocity): a
  parent that came to rest stays at rest.

  Attributes:
    qpos: f32[F, nq] decoded frames (frame f at f / record_fps s).
    qvel: f32[F, nv] chord velocity from frame f to f + 1, qvel units.
    com: f32[F, B, 3] tracked bodies' centres of mass, m.
    quat: f32[F, B, 4] tracked bodies' inertial-frame orientations (w, x, y, z).
    lin_vel: f32[F, B, 3] COM chord velocity from frame f to f + 1, m/s.
    ang_vel: f32[F, B, 3] chord angular velocity (world frame), rad/s.
    n_parent: frames the parent recorded.
  """

  qpos: np.ndarray
  qvel: np.ndarray
  com: np.ndarray
  quat: np.ndarray
  lin_vel: np.ndarray
  ang_vel: np.ndarray
  n_parent: int


def stored_path(model: mujoco.MjModel, frames: np.ndarray, body_ids: np.ndarray, n_frames: int,
                frame_time: float) -> StoredPath:
  """Playback arrays of one decoded path.

  Args:
    model: the scene model.
    frames: f32[T, nq] decoded qpos of the parent (T >= 1).
    body_ids: i32[B] tracked body ids.
    n_frames: F, frames to cover (held after T).
    frame_time: seconds between frames (1 / record_fps).
  """
  t = len(frames)
  n = max(n_frames, t)
  qpos = np.concatenate([frames, np.repeat(frames[-1:], n - t, axis=0)]).astype(np.float64)
  qvel = np.zeros((n, model.nv))
  for f in range(t - 1):
    mujoco.mj_differentiatePos(model, qvel[f], frame_time, qpos[f], qpos[f + 1])
  data = mujoco.MjData(model)
  com = np.zeros((t, len(body_ids), 3))
  quat = np.zeros((t, len(body_ids), 4))
  for f in range(t):
    data.qpos[:] = qpos[f]
    mujoco.mj_kinematics(model, data)
    com[f] = data.xipos[body_ids]
    for i, b in enumerate(body_ids):
      mujoco.mju_mat2Quat(quat[f, i], data.ximat[b])
  hold = lambda x: np.concatenate([x, np.repeat(x[-1:], n - t, axis=0)])
  com, quat = hold(com), hold(quat)
  lin_vel = np.zeros_like(com)
  lin_vel[:-1] = np.diff(com, axis=0) / frame_time
  ang_vel = np.zeros_like(com)
  last = min(t, n) - 1
  # world-frame rotation q_{f+1} q_f^-1 as a rotation vector
  relative = rotations.quat_multiply_np(quat[1:last + 1], rotations.quat_conjugate_np(quat[:last]))
  ang_vel[:last] = rotations.quat_to_velocity_np(relative, frame_time)
  return StoredPath(qpos=qpos.astype(np.float32), qvel=qvel.astype(np.float32),
                    com=com.astype(np.float32), quat=quat.astype(np.float32),
                    lin_vel=lin_vel.astype(np.float32), ang_vel=ang_vel.astype(np.float32), n_parent=t)


def central_velocity(model: mujoco.MjModel, path: StoredPath, frame: int, frame_time: float) -> np.ndarray:
  """f32[nv] qvel at a frame by a central difference of the decoded path.

  One-sided at the ends of the parent's recording (and zero for a one-frame
  recording). This is the restart velocity of the objects refined at t_min.
  """
  lo, hi = max(frame - 1, 0), min(frame + 1, path.n_parent - 1)
  v = np.zeros(model.nv)
  if hi > lo:
    mujoco.mj_differentiatePos(model, v, (hi - lo) * frame_time,
                               path.qpos[lo].astype(np.float64), path.qpos[hi].astype(np.float64))
  return v.astype(np.float32)


def step_targets(model: mujoco.MjModel, path: StoredPath, steps_per_frame: int, dt: float) -> np.ndarray:
  """f32[F * S, nq] playback ``qpos`` at every physics step.

  Step ``f·S + j`` is ``mj_integratePos(qpos[f], qvel[f], j·dt)``: the path
  between frames at the chord velocity, exactly ``qpos[f]`` at ``j = 0`` and
  reaching ``qpos[f + 1]`` at ``j = S``. (Its ``qvel`` is ``qvel[f]``.)
  """
  n = len(path.qpos)
  out = np.zeros((n * steps_per_frame, model.nq))
  for f in range(n):
    base = path.qpos[f].astype(np.float64)
    v = path.qvel[f].astype(np.float64)
    out[f * steps_per_frame] = base
    for j in range(1, steps_per_frame):
      q = base.copy()
      mujoco.mj_integratePos(model, q, v, j * dt)
      out[f * steps_per_frame + j] = q
  return out.astype(np.float32)


def prefix_metrics(path: StoredPath, frame: int, frame_time: float, dt: float, gravity: np.ndarray,
                   rest_linear_speed: float, rest_angular_speed: float, linear_threshold: float,
                   gap_frames: int) -> np.ndarray:
  """f32[B, M] metric accumulators (world.METRIC_NAMES order) over frames 0…frame.

  Computed from the decoded path at the record rate: angular travel as the
  sum of frame-to-frame rotation angles, rest time as the last frame moving
  faster than the rest speeds (-inf if none), collisions as rising edges of
  ``‖Δv − g·h‖ > C_v·dt`` between frame chords (an estimate: the stored path
  holds no per-step accelerations), path length and highest COM z. Orientation
  error is left 0 (the loop computes it against frame 0).
  """
  com = path.com[:frame + 1].astype(np.float64)
  quat = path.quat[:frame + 1].astype(np.float64)
  b = com.shape[1]
  out = np.zeros((b, len(world.METRIC_NAMES)), np.float32)
  out[:, world.MAX_HEIGHT] = com[:, :, 2].max(axis=0)
  out[:, world.REST_TIME] = -np.inf
  if frame == 0:
    return out
  angles = rotations.rotation_angle_np(quat[:-1], quat[1:])  # [frame, B]
  steps = np.linalg.norm(np.diff(com, axis=0), axis=-1)
  out[:, world.ANGULAR_TRAVEL] = angles.sum(axis=0)
  out[:, world.PATH_LENGTH] = steps.sum(axis=0)
  moving = (steps / frame_time >= rest_linear_speed) | (angles / frame_time >= rest_angular_speed)
  last = np.where(moving.any(axis=0), frame - 1 - np.argmax(moving[::-1], axis=0), -1)
  out[:, world.REST_TIME] = np.where(last >= 0, last * frame_time, -np.inf)
  if frame >= 2:
    vel = np.diff(com, axis=0) / frame_time  # [frame, B, 3]
    dv = np.diff(vel, axis=0) - gravity * frame_time
    impact = np.linalg.norm(dv, axis=-1) > linear_threshold * dt
    count = np.zeros(b)
    since = np.full(b, 1 << 30)
    for row in impact:
      count += row & (since > gap_frames)
      since = np.where(row, 0, since + 1)
    out[:, world.COLLISIONS] = count
  return out


class ContactFreeModels:
  """Copies of the scene model in which chosen objects collide with nothing,
  one per set of objects (made on first use and kept): the native loop's
  models for worlds whose inactive objects are those sets.

  An inactive object is put back on its stored path before the physics steps
  and reports its stored motion, so contacts of its own would only cost
  collision and solver time: an active object never touches it (the
  interaction test activates it first), and what it does to the scene or to
  other inactive objects is overwritten. Where another moving body could
  touch an object (a moving body that is not an object of the scene, or a
  flex), the model is used unchanged.

  With ``sleep_inactive`` (the compiled loop) the copies also let MuJoCo's
  island sleep hold the inactive objects: the loop puts their trees to sleep
  (:attr:`sleeps`), so ``mj_step`` skips them altogether instead of moving
  bodies whose motion is overwritten. The copies enable sleeping with the
  inactive trees allowed to sleep; every other tree keeps the scene's policy
  where the scene sleeps, and never sleeps where it does not, so the active
  objects step exactly as without it (MuJoCo: awake trees are bit-identical
  with sleep on or off). Only where no equality or tendon ties trees
  together (a sleeping tree tied to an awake one wakes) and the integrator
  is not RK4 (which does not sleep).

  Args:
    model: the scene model.
    object_names: the O objects (root body names).
    sleep_inactive: put inactive objects to sleep where the scene allows.
  """

  MAX_CACHED = 256  # sets of objects kept; beyond that the cache starts over

  def __init__(self, model: mujoco.MjModel, object_names, sleep_inactive: bool = False):
    self.model = model
    body_object = scene_lib.object_body_mask(model, object_names)  # bool[O, nbody]
    self.geom_object = body_object[:, model.geom_bodyid]  # bool[O, ngeom]
    body_moves = (model.body_weldid != 0) | (model.body_mocapid >= 0)
    may_collide = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    stranger = body_moves[model.geom_bodyid] & ~self.geom_object.any(axis=0) & may_collide
    self.enabled = model.nflex == 0 and not stranger.any()
    # bool[O, ntree] the kinematic trees of each object (static bodies have none)
    self.tree_object = np.zeros((len(body_object), model.ntree), bool)
    for o, bodies in enumerate(body_object):
      trees = model.body_treeid[bodies]
      self.tree_object[o, trees[trees >= 0]] = True
    self.sleeps = bool(sleep_inactive and self.enabled and model.neq == 0 and model.ntendon == 0
                       and model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4)
    self._scene_sleeps = bool(model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP))
    self._cache: dict = {}

  def __call__(self, inactive: np.ndarray) -> list:
    """One model per row of ``inactive: bool[n, O]``."""
    if not self.enabled:
      return [self.model] * len(inactive)
    models = []
    for i, row in enumerate(np.packbits(inactive, axis=1)):
      key = row.tobytes()
      variant = self._cache.get(key)
      models.append(variant if variant is not None else self._make(key, inactive[i]))
    return models

  def _make(self, key: bytes, inactive: np.ndarray) -> mujoco.MjModel:
    if len(self._cache) >= self.MAX_CACHED:
      self._cache.clear()
    variant = self.model
    if inactive.any():
      variant = copy.copy(self.model)  # mj_copyModel
      off = self.geom_object[inactive].any(axis=0)
      variant.geom_contype[off] = 0
      variant.geom_conaffinity[off] = 0
      if self.sleeps:
        variant.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        if not self._scene_sleeps:
          variant.tree_sleep_policy[:] = mujoco.mjtSleepPolicy.mjSLEEP_NEVER
        variant.tree_sleep_policy[self.tree_object[inactive].any(axis=0)] = mujoco.mjtSleepPolicy.mjSLEEP_ALLOWED
    self._cache[key] = variant
    return variant
