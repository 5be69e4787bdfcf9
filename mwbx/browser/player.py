"""Playback on the page: up to MAX_SLOTS worlds at one shared time.

A played world is decoded from the codec and put through forward kinematics
once (kept for the last few worlds played), then its poses go to one of the
stage's slots (:class:`mwbx.browser.scene.Stage`), whose meshes are already
on the clients: a sorter click sends poses, never meshes. The playback
thread and the GUI callbacks share the played worlds and the frame under one
lock.
"""

from __future__ import annotations

import collections
import threading
import time

import numpy as np

from mwbx.browser.scene import MAX_SLOTS
from mwbx.viewer.kinematics import body_trajectories

# Decoded worlds kept (trajectories of every moving body: T x B x 7 floats each).
KEPT_WORLDS = 16
# Poses sent to the page at most this often: at the recording rate (e.g.
# 250 Hz) the pose stream alone kept a browser busy for seconds, so a click's
# answer queued behind it; playback skips recorded frames instead and keeps
# real time.
DISPLAY_HZ = 30.0


class Player:
  """Plays worlds of ``session``'s bank on ``stage``.

  Args:
    session: the :class:`~mwbx.browser.session.Session` (its bank may grow).
    stage: the :class:`~mwbx.browser.scene.Stage` the worlds are drawn on.
    paused: a callable saying whether playback is paused.
    lock: the page's lock (an RLock), shared with the GUI callbacks; None: a new one.

  Attributes:
    lock: guards ``played``, ``frame`` and the stage's poses.
    played: world id -> slot, in play order.
    frame: the shared frame index (all played worlds show it; a shorter one
      holds its last frame).
  """

  def __init__(self, session, stage, paused=lambda: False, lock=None):
    self.session, self.stage, self.paused = session, stage, paused
    self.lock = threading.RLock() if lock is None else lock
    self.played: dict[int, int] = {}
    self.frame = 0
    self._poses: collections.OrderedDict = collections.OrderedDict()  # world -> (pos, quat)
    self._stop = threading.Event()
    self._thread = threading.Thread(target=self._loop, daemon=True, name="mwbx-playback")
    self._thread.start()

  def poses(self, world: int) -> tuple[np.ndarray, np.ndarray]:
    """(pos f64[T, B, 3], quat f64[T, B, 4]) of the stage's moving bodies in world ``world``."""
    world = int(world)
    with self.lock:
      if world in self._poses:
        self._poses.move_to_end(world)
        return self._poses[world]
    qpos = self.session.bank.qpos_frames(world).astype(np.float64)
    out = body_trajectories(self.stage.model, qpos, self.stage.pose_ids)
    with self.lock:
      self._poses[world] = out
      while len(self._poses) > KEPT_WORLDS:
        self._poses.popitem(last=False)
    return out

  def play(self, world: int, add: bool = False) -> int:
    """Plays ``world`` (alone, from the start; with ``add`` besides the ones
    playing, at the same time, the oldest dropped beyond MAX_SLOTS). Returns its slot."""
    world = int(world)
    poses = self.poses(world)
    server = self.stage.server
    with self.lock, server.atomic():
      if not add:
        for w in list(self.played):
          self._drop(w)
        self.frame = 0
      elif world in self.played:
        return self.played[world]
      elif len(self.played) >= MAX_SLOTS:
        self._drop(next(iter(self.played)))
      slot = min(set(range(MAX_SLOTS)) - set(self.played.values()))
      self.played[world] = slot
      pos, quat = poses
      f = min(self.frame, pos.shape[0] - 1)
      self.stage.pose(slot, pos[f], quat[f])
      self.stage.show(slot, world)
      self.stage.refresh_copies()
    return slot

  def _drop(self, world: int) -> None:
    self.stage.show(self.played.pop(world), None)

  def clear(self) -> None:
    """Stops playing every world."""
    with self.lock:
      for w in list(self.played):
        self._drop(w)
      self.stage.refresh_copies()

  def renamed(self, renamed: dict[int, int]) -> None:
    """The same worlds under new ids (a save gave them: old id -> id on
    disk): the played and decoded worlds follow, their labels too."""
    with self.lock:
      self.played = {renamed.get(w, w): slot for w, slot in self.played.items()}
      self._poses = collections.OrderedDict((renamed.get(w, w), v) for w, v in self._poses.items())
      for world, slot in self.played.items():
        self.stage.show(slot, world)

  def forget(self) -> None:
    """Drops the decoded worlds kept (the bank's model changed)."""
    with self.lock:
      self._poses.clear()
      self.played.clear()

  def seek(self, frame: int) -> None:
    with self.lock:
      self.frame = int(frame)
      self.show()

  def show(self) -> None:
    """Poses every played world at the shared frame."""
    with self.lock, self.stage.server.atomic():
      for world, slot in self.played.items():
        pos, quat = self._poses.get(world) or self.poses(world)
        f = min(self.frame, pos.shape[0] - 1)
        self.stage.pose(slot, pos[f], quat[f])

  def _loop(self) -> None:
    while not self._stop.is_set():
      fps = float(self.session.bank.record_fps)
      step = max(1, int(round(fps / DISPLAY_HZ)))  # recorded frames per shown frame
      with self.lock:
        if self.played and not self.paused():
          self.show()
          longest = max(self.poses(w)[0].shape[0] for w in self.played)
          self.frame = (self.frame + step) % longest
      time.sleep(step / fps)

  def stop(self) -> None:
    self._stop.set()
    self._thread.join(timeout=5)
