"""Contact events found on the stored worlds.

At every recorded frame of a world, MuJoCo's own collision detection
(``mj_kinematics``, ``mj_flex`` where there are flexes, then ``mj_collision``,
as in a physics step) runs on the
stored state (the decoded ``qpos``: what every query sees) and two actors
(:mod:`mwbx.events.actors`) **touch** when it reports a contact between a geom
of each at a distance of at most the touch margin. The margin is
:data:`TOUCH_MARGIN_PER_E_POS` times the codec's position bound ``e_pos``: the
stored state is within ``e_pos`` of the simulated one, so a contact in the
simulation is within the margin in the stored state (a body resting on the
floor does not flicker in and out of touch). Runs of consecutive touching
frames are episodes (:mod:`mwbx.events.record`).

Sampling and refinement find the events of every new world this way, on
every engine, before the worlds join a bank.
"""

from __future__ import annotations

import copy
import threading
from typing import Iterable

import mujoco
import numpy as np

from mwbx.events.actors import Actors, qpos_actors
from mwbx.events.record import EventRecord
from mwbx.host_pool import LazyPool
from mwbx.progress import Progress

TOUCH_MARGIN_PER_E_POS = 2.0
# Scenes with at least this many actors find a frame's contacts from what moved since the last.
INCREMENTAL_MIN_ACTORS = 32
_POOL = LazyPool("mwbx-events")  # worlds, a thread per core


def touch_margin(e_pos: float) -> float:
  """The touch margin, metres, of a scene whose codec bounds positions by ``e_pos`` metres."""
  return TOUCH_MARGIN_PER_E_POS * float(e_pos)


def margin_model(model: mujoco.MjModel, margin: float) -> mujoco.MjModel:
  """A copy of ``model`` whose collision reports contacts up to ``margin``
  apart (its geoms' and its flexes' margins)."""
  out = copy.copy(model)
  out.geom_margin[:] = np.maximum(out.geom_margin, margin)
  if out.nflex:
    out.flex_margin[:] = np.maximum(out.flex_margin, margin)
  return out


def world_episodes(model: mujoco.MjModel, data: mujoco.MjData, actors: Actors, frames: np.ndarray,
                   margin: float, qpos_actor: np.ndarray | None = None) -> np.ndarray:
  """The contact episodes of one world.

  Args:
    model: :func:`margin_model` of the scene. data: scratch ``MjData`` of it.
    actors: the scene's actors.
    frames: f32[T, nq] the world's stored qpos frames.
    margin: touch margin, m.
    qpos_actor: optional i64[nq] the actor each coordinate moves
      (:func:`mwbx.events.actors.qpos_actors`): then a frame tests only the
      pairs with an actor that moved since the frame before, and the pairs of
      two that did not keep that frame's contacts (the same poses give the
      same contacts), as :func:`_frames_incremental` does.

  Returns:
    i32[n, 4] ``(a, b, first, last)`` sorted by ``(a, b, first)``.
  """
  if qpos_actor is not None and not model.nflex:
    filtered = active_pairs_model(model, actors, np.ones(len(actors.names), bool))
    if filtered is not None:
      return _frames_incremental(model, filtered, data, actors, frames, margin, qpos_actor)
  kinematics, collision = mujoco.mj_kinematics, mujoco.mj_collision
  # Flex vertices (and their bounding boxes) are placed by mj_flex, which a
  # physics step runs between the two: without it the collision sees every
  # vertex where the last call left it.
  flex = mujoco.mj_flex if model.nflex else None
  found_frames, found_geoms, found_flexes, found_dist = [], [], [], []
  qpos = data.qpos
  for f, frame in enumerate(np.asarray(frames, np.float64)):  # the per-frame loop stays minimal
    qpos[:] = frame
    kinematics(model, data)
    if flex is not None:
      flex(model, data)
    collision(model, data)
    n = data.ncon
    if n:
      contact = data.contact
      found_geoms.append(contact.geom[:n].copy())
      found_flexes.append(contact.flex[:n].copy())
      found_dist.append(contact.dist[:n].copy())
      found_frames.append(np.full(n, f, np.int64))
  if not found_frames:
    return np.zeros((0, 4), np.int32)
  sides = actors.of_contacts(np.concatenate(found_geoms), np.concatenate(found_flexes))
  return episodes(len(actors.names), np.concatenate(found_frames), sides, np.concatenate(found_dist), margin)


def _frames_incremental(model, filtered, data, actors: Actors, frames: np.ndarray, margin: float,
                        qpos_actor: np.ndarray) -> np.ndarray:
  """:func:`world_episodes` testing, at each frame, only the pairs with an
  actor whose stored coordinates changed since the frame before (in
  ``filtered``, a copy of ``model`` whose affinities this sets per frame:
  :func:`active_pairs_model`); the contacts of two actors that did not move
  are the frame before's. Resting bodies (asleep, or held by the codec) cost
  nothing after their first frame."""
  kinematics, collision = mujoco.mj_kinematics, mujoco.mj_collision
  n_actors = len(actors.names)
  geom_actor = np.asarray(actors.geom_actor, np.int64)
  contype = np.asarray(model.geom_contype, np.int64)
  conaffinity = np.asarray(model.geom_conaffinity, np.int64)
  affinity_on = conaffinity | (contype << _MASK_BITS)
  kept_sides, kept_dist = np.zeros((0, 2), np.int64), np.zeros(0)  # the frame before's contacts
  touching = np.zeros(0, np.int64)  # pair codes a * n_actors + b (a < b) touching at the frame before
  opened: dict[int, int] = {}  # pair code -> the first frame of its episode going on
  rows: list[tuple[int, int, int, int]] = []
  qpos = data.qpos
  previous = None
  frames = np.asarray(frames, np.float64)
  for f, frame in enumerate(frames):
    moved = np.ones(n_actors, bool)
    if previous is not None:
      moved[:] = False
      moved[qpos_actor[frame != previous]] = True
    previous = frame
    filtered.geom_conaffinity[:] = np.where(moved[geom_actor], affinity_on, 0)
    qpos[:] = frame
    kinematics(filtered, data)
    collision(filtered, data)
    n = data.ncon
    sides = actors.of_contacts(data.contact.geom[:n], data.contact.flex[:n]) if n else np.zeros((0, 2), np.int64)
    dist = data.contact.dist[:n].copy() if n else np.zeros(0)
    fresh = moved[sides[:, 0]] | moved[sides[:, 1]]  # explicit <pair>s are tested whatever moved
    still = ~moved[kept_sides[:, 0]] & ~moved[kept_sides[:, 1]]
    kept_sides = np.concatenate([sides[fresh], kept_sides[still]])
    kept_dist = np.concatenate([dist[fresh], kept_dist[still]])
    a, b = kept_sides[:, 0], kept_sides[:, 1]
    on = (a != b) & (kept_dist <= margin)
    now = np.unique(np.minimum(a, b)[on] * n_actors + np.maximum(a, b)[on])
    for code in np.setdiff1d(now, touching, assume_unique=True).tolist():
      opened[code] = f
    for code in np.setdiff1d(touching, now, assume_unique=True).tolist():
      rows.append((code // n_actors, code % n_actors, opened.pop(code), f - 1))
    touching = now
  rows += [(code // n_actors, code % n_actors, first, len(frames) - 1) for code, first in opened.items()]
  if not rows:
    return np.zeros((0, 4), np.int32)
  out = np.array(rows, np.int32)
  return out[np.lexsort((out[:, 2], out[:, 1], out[:, 0]))]


def episodes(n_actors: int, frame: np.ndarray, sides: np.ndarray, dist: np.ndarray, margin: float) -> np.ndarray:
  """Episodes from one world's contacts.

  Args:
    n_actors: how many actors the scene has.
    frame: i64[K] the frame of each contact. sides: i[K, 2] the actors of
      its two sides (:meth:`Actors.of_contacts`).
    dist: f64[K] its distance, m. margin: touch margin, m.

  Returns:
    i32[n, 4] ``(a, b, first, last)``: maximal runs of consecutive frames in
    which actors a < b touch, sorted by ``(a, b, first)``.
  """
  a, b = sides[:, 0], sides[:, 1]
  keep = (a != b) & (dist <= margin)
  pair = np.minimum(a, b)[keep] * n_actors + np.maximum(a, b)[keep]
  frame = frame[keep]
  if not pair.size:
    return np.zeros((0, 4), np.int32)
  code = np.unique(pair * (int(frame.max()) + 2) + frame)  # sorted by (pair, frame), once each
  pair, frame = np.divmod(code, int(frame.max()) + 2)
  # A run starts where the pair changes or the frame is not the next one.
  start = np.ones(len(code), bool)
  start[1:] = (pair[1:] != pair[:-1]) | (frame[1:] != frame[:-1] + 1)
  first = np.flatnonzero(start)
  last = np.append(first[1:], len(code)) - 1
  p = pair[first]
  return np.stack([p // n_actors, p % n_actors, frame[first], frame[last]], axis=1).astype(np.int32)


# contype/conaffinity bits a pair filter can re-plane (MuJoCo's masks are 32-bit).
_MASK_BITS = 16


def active_pairs_model(model: mujoco.MjModel, actors: Actors, active: np.ndarray) -> mujoco.MjModel | None:
  """A copy of ``model`` whose collision reports only contacts with a geom of
  an ``active`` actor (bool[n_actors]) on at least one side, as far as the
  original filter allows them; None where the masks do not fit (then every
  pair is tested).

  Geoms of inactive actors keep ``contype | conaffinity << 16`` and lose their
  affinity; active ones get ``conaffinity | contype << 16`` as well: an
  inactive pair then never passes the filter ``(ct1 & ca2) | (ct2 & ca1)``,
  and a pair with an active side passes exactly when it did before. Explicit
  ``<pair>`` contacts and flexes are not filtered (callers keep only the
  pairs they asked for).
  """
  contype = np.asarray(model.geom_contype, np.int64)
  conaffinity = np.asarray(model.geom_conaffinity, np.int64)
  if (contype >> _MASK_BITS).any() or (conaffinity >> _MASK_BITS).any():
    return None
  on = np.asarray(active, bool)[actors.geom_actor]
  out = copy.copy(model)
  out.geom_contype[:] = contype | (conaffinity << _MASK_BITS)
  out.geom_conaffinity[:] = np.where(on, conaffinity | (contype << _MASK_BITS), 0)
  return out


def detect_events(model: mujoco.MjModel, actors: Actors, frames: Iterable[np.ndarray], margin: float,
                  progress=None, total: int | None = None, first_frame=0, active=None) -> EventRecord:
  """The contact events of worlds from their stored frames.

  Args:
    model: the scene's model (not changed).
    actors: its actors (:func:`mwbx.events.actors_of`).
    frames: each world's f32[T, nq] stored qpos frames from ``first_frame``
      on, in bank row order.
    margin: touch margin, m (:func:`touch_margin`).
    progress: optional callback taking a :class:`mwbx.progress.Progress`
      (phase ``contact events``).
    total: how many worlds ``frames`` holds (for progress).
    first_frame: the frame number of the first frame given: one for every
      world, or i64[W] one per world.
    active: optional bool[W, n_actors]: each world's collision tests only
      pairs with an active actor (:func:`active_pairs_model`; refined
      worlds, whose other pairs are their parent's). Other pairs may still
      be reported.

  Example::

    actors = actors_of(bank.model, list(bank.objects))
    record = detect_events(bank.model, actors, bank.qpos_store.frames_of_rows(None), touch_margin(1e-3))
  """
  model = margin_model(model, margin)
  # Frame to frame testing only what moved pays in scenes of many actors (16 tower worlds: 1.38x);
  # with a few, MuJoCo's whole collision costs less than the bookkeeping (64 quickstart worlds: 0.1x).
  qpos_actor = qpos_actors(model, actors) if len(actors.names) >= INCREMENTAL_MIN_ACTORS else None
  scratch = threading.local()  # an MjData per thread of the pool (every model here has the same sizes)
  filtered = {}  # an active set -> its model
  if active is not None:
    for row in np.unique(np.asarray(active, bool), axis=0):
      filtered[row.tobytes()] = active_pairs_model(model, actors, row) or model

  def one_world(w: int, world_frames: np.ndarray) -> np.ndarray:
    data = getattr(scratch, "data", None)
    if data is None:
      data = scratch.data = mujoco.MjData(model)
    world_model = model if active is None else filtered[np.asarray(active[w], bool).tobytes()]
    # Frame to frame, only pairs with a moved actor are tested (on the full pair set: a refined
    # world's own filter is already in world_model's affinities, which the per-frame masks replace).
    rows = world_episodes(world_model, data, actors, world_frames, margin, qpos_actor if active is None else None)
    rows[:, 2:] += int(first_frame if np.ndim(first_frame) == 0 else first_frame[w])
    return rows

  # Worlds go to a thread per core: MuJoCo's collision runs without the GIL.
  frames = list(frames)
  jobs = [_POOL.get().submit(one_world, w, f) for w, f in enumerate(frames)] if len(frames) > 1 else []
  worlds = []
  try:
    for w, world_frames in enumerate(frames):
      worlds.append(jobs[w].result() if jobs else one_world(w, world_frames))
      if progress is not None and total:
        progress(Progress("contact events", w + 1, total, 0))
  except BaseException:  # Ctrl-C or an error: the worlds not started yet are not run
    for job in jobs:
      job.cancel()
    raise
  return EventRecord.from_worlds(worlds)


def spliced(parent: np.ndarray, after: np.ndarray, first: int) -> np.ndarray:
  """A refined world's episodes: its parent's before tick ``first`` (the
  part it shares with its parent), its own from there on.

  Args:
    parent: [n, 4] the parent's episodes ``(a, b, first, last)``, or [n, 6]
      with their strengths ``(…, peak force, impulse)``.
    after: [m, 4 or 6] the refined world's episodes found from ``first`` on.
    first: the first tick the refined world does not share.

  Returns:
    [k, 4 or 6] (the parent's dtype) sorted by ``(a, b, first)``; an episode
    of the parent still on at ``first - 1`` ends there, or goes on as the
    refined world's episode of that pair starting at ``first``
    (:func:`joined`).
  """
  before = parent[parent[:, 2] < first].copy()
  before[:, 3] = np.minimum(before[:, 3], first - 1)
  rows = np.concatenate([before, after]).astype(parent.dtype)
  return joined(rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))])


def joined(rows: np.ndarray) -> np.ndarray:
  """Episodes ``rows`` ([n, 4], or [n, 6] with strengths; sorted by ``(a, b,
  first)``) with each run of one pair's episodes that follow on without a
  break (one's first tick the one after the other's last: where a refined
  world's own simulation takes over from its parent's) as one episode: its
  last tick the run's, the larger peak force (NaN if a part's is unknown),
  the impulses added."""
  if len(rows) < 2:
    return rows
  starts = np.ones(len(rows), bool)
  starts[1:] = (rows[1:, 0] != rows[:-1, 0]) | (rows[1:, 1] != rows[:-1, 1]) | (rows[1:, 2] != rows[:-1, 3] + 1)
  if starts.all():
    return rows
  first = np.flatnonzero(starts)
  out = rows[first].copy()
  out[:, 3] = np.maximum.reduceat(rows[:, 3], first)
  if rows.shape[1] > 4:
    out[:, 4] = np.maximum.reduceat(rows[:, 4], first)  # unknown (NaN) if any part is
    out[:, 5] = np.add.reduceat(rows[:, 5], first)
  return out
