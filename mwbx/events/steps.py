"""Contact events found during the simulation, at every physics step.

After each ``mj_step`` MuJoCo's contact list holds the contacts of the state
the step started from, and ``efc_force`` the forces the step's solve gave
them. Two actors (:mod:`mwbx.events.actors`) **touch** at that step when
MuJoCo reports a contact between a geom (or flex) of each that is not in its
margin's gap (``mjContact.exclude`` is not 1: the contacts the solver acts on,
and those it leaves to a sleeping island or a body without dofs): MuJoCo's
own contact, no margin added. An episode is a run of steps in which they
touch, broken only by a separation of at least ``gap`` steps (the sampler's
gap is the physics steps of one query point, 1/30 s by default: a ball
skipping along a ramp or settling on a floor leaves it for 2–30 ms many
times a second, which a viewer does not see and a query's time does not
resolve; counting each would make the quickstart's episodes 8 times as
many); its strength is the largest normal force over its steps and the
normal impulse, the sum of normal force times the timestep.

A pair whose actors both sleep (or are static) is not tested by MuJoCo: its
touch holds as it was until one of them wakes (nothing moved). Forces are
not computed for a sleeping island: its steps add no impulse.

These kernels are written for ONE world and called from the compiled loops
(:mod:`mwbx.batch_sim.compiled_world`, :mod:`mwbx.refinement.compiled_refinement`);
they know nothing of MuJoCo: the loop hands over the step's touching pairs.

Example (what a loop does, in numba)::

  open_ = new_episodes(n_actors)
  for tick in range(n_steps):
    mj_step(...)
    for a, b, normal_force in the step's touching contacts:
      touch(open_, n_actors, a, b, normal_force, tick)
    end_tick(open_, n_actors, tick, gap, timestep, moving, out_rows, out_strength)
  count = finish(open_, n_actors, last_tick, out_rows, out_strength)
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mwbx.host_jit import host_jit

NOT_OPEN = -1
# ``mjContact.exclude`` of a contact in its margin's gap: reported, not touching.
EXCLUDE_IN_GAP = 1
# Episode rows kept per world at least, and per actor beyond that: a world
# with more drops the rest and is flagged (its events are then found on its
# stored frames).
MIN_EPISODES = 4096
EPISODES_PER_ACTOR = 64


def episode_capacity(n_actors: int) -> int:
  """Episode rows a world's buffer holds (:data:`MIN_EPISODES`, :data:`EPISODES_PER_ACTOR`)."""
  return max(MIN_EPISODES, EPISODES_PER_ACTOR * int(n_actors))


class OpenEpisodes(NamedTuple):
  """One world's episodes going on, indexed by pair code ``a * n_actors + b`` (a < b).

  Attributes:
    first: i32[P] the first tick of the pair's open episode; NOT_OPEN if none.
    seen: i32[P] the last tick the pair touched.
    force: f64[P] the pair's normal force summed over this tick's contacts, N.
    peak: f64[P] the open episode's largest normal force, N.
    impulse: f64[P] its normal impulse so far, N·s.
    codes: i32[P] the open pairs' codes, ``n[0]`` of them first.
    n: i64[2] (open pairs, episode rows written to the world's buffer so far).
  """

  first: np.ndarray
  seen: np.ndarray
  force: np.ndarray
  peak: np.ndarray
  impulse: np.ndarray
  codes: np.ndarray
  n: np.ndarray


@host_jit
def new_episodes(n_actors):
  """An empty :class:`OpenEpisodes` for ``n_actors`` actors."""
  p = n_actors * n_actors
  return OpenEpisodes(np.full(p, NOT_OPEN, np.int32), np.full(p, NOT_OPEN, np.int32), np.zeros(p),
                      np.zeros(p), np.zeros(p), np.zeros(p, np.int32), np.zeros(2, np.int64))


@host_jit
def touch(open_, n_actors, a, b, normal_force, tick):
  """Actors ``a`` and ``b`` touch at ``tick`` through one contact carrying
  ``normal_force`` (N); contacts inside one actor are not events."""
  if a == b or a < 0 or b < 0:
    return
  lo, hi = min(a, b), max(a, b)
  code = lo * n_actors + hi
  if open_.seen[code] != tick:
    open_.seen[code] = tick
    open_.force[code] = 0.0
    if open_.first[code] == NOT_OPEN:
      open_.first[code] = tick
      open_.peak[code] = 0.0
      open_.impulse[code] = 0.0
      open_.codes[open_.n[0]] = code
      open_.n[0] += 1
  open_.force[code] += max(normal_force, 0.0)


@host_jit
def _write(open_, code, n_actors, last, out_rows, out_strength):
  """Ends the pair's open episode at tick ``last``: one row of the world's buffer."""
  row = open_.n[1]
  if row < out_rows.shape[0]:
    out_rows[row, 0] = code // n_actors
    out_rows[row, 1] = code % n_actors
    out_rows[row, 2] = open_.first[code]
    out_rows[row, 3] = last
    out_strength[row, 0] = open_.peak[code]
    out_strength[row, 1] = open_.impulse[code]
  open_.n[1] += 1
  open_.first[code] = NOT_OPEN


@host_jit
def end_tick(open_, n_actors, tick, gap, timestep, moving, out_rows, out_strength):
  """After every :func:`touch` of ``tick``: the open pairs that touched add
  their force; a pair touching at the tick before whose actors are neither
  ``moving`` (bool[n_actors]: an awake tree; MuJoCo did not test the pair)
  still touches; a pair apart for ``gap`` ticks ends at the last tick it
  touched (a row of the world's i32[cap, 4] ``out_rows`` and f32[cap, 2]
  ``out_strength``)."""
  kept = 0
  for i in range(open_.n[0]):
    code = open_.codes[i]
    seen = open_.seen[code]
    if seen == tick:
      f = open_.force[code]
      open_.peak[code] = max(open_.peak[code], f)
      open_.impulse[code] += f * timestep
    elif seen == tick - 1 and not (moving[code // n_actors] or moving[code % n_actors]):
      open_.seen[code] = tick
    elif tick - seen >= gap:
      _write(open_, code, n_actors, seen, out_rows, out_strength)
      continue
    open_.codes[kept] = code
    kept += 1
  open_.n[0] = kept


@host_jit
def finish(open_, n_actors, last_tick, out_rows, out_strength):
  """Ends the world at ``last_tick`` (its last stored frame's): episodes
  still touching there end there (they go on), the others at their last
  touch; those begun after it are dropped and those ending after it end
  there. Returns the world's episode count, sorted by (a, b, first) in
  ``out_rows[:count]``; more than ``len(out_rows)``: the buffer overflowed
  (its rows are incomplete)."""
  for i in range(open_.n[0]):
    code = open_.codes[i]
    _write(open_, code, n_actors, max(open_.seen[code], last_tick) if open_.seen[code] >= last_tick
           else open_.seen[code], out_rows, out_strength)
  open_.n[0] = 0
  n = open_.n[1]
  if n > out_rows.shape[0]:
    return n
  kept = 0
  for i in range(n):
    if out_rows[i, 2] <= last_tick:
      out_rows[kept] = out_rows[i]
      out_rows[kept, 3] = min(out_rows[i, 3], last_tick)
      out_strength[kept] = out_strength[i]
      kept += 1
  key = (out_rows[:kept, 0].astype(np.int64) * n_actors + out_rows[:kept, 1]) * (last_tick + 2) \
      + out_rows[:kept, 2]
  order = np.argsort(key, kind="mergesort")
  out_rows[:kept] = out_rows[:kept][order]
  out_strength[:kept] = out_strength[:kept][order]
  return kept


@host_jit
def actors_moving(tree_asleep, actor_tree_start, actor_trees, moving):
  """bool[n_actors] ``moving`` (out): an actor moves while any of its trees
  is awake (``tree_asleep`` < 0); an actor with no tree (static) never does.
  ``actor_trees[actor_tree_start[a]:actor_tree_start[a + 1]]`` are actor a's."""
  for a in range(len(actor_tree_start) - 1):
    moving[a] = False
    for k in range(actor_tree_start[a], actor_tree_start[a + 1]):
      if tree_asleep[actor_trees[k]] < 0:
        moving[a] = True
        break


# The same episodes inside a jitted scan (MJX): the JAX twin of new_episodes,
# touch and end_tick for ONE world, vmapped over the batch by the caller, and
# of the row buffer they write; finish runs on the host (finish_track).


class EpisodeTrack(NamedTuple):
  """One world's contact episodes as a jitted loop keeps them: the JAX twin
  of :class:`OpenEpisodes` with its row buffer (pair code ``a * n_actors + b``).

  Attributes:
    first: i32[P] the first tick of the pair's open episode; NOT_OPEN if none.
    seen: i32[P] the last tick the pair touched.
    peak: f32[P] the open episode's largest normal force, N.
    impulse: f32[P] its normal impulse so far, N·s.
    rows: i32[cap, 4] ended episodes ``(a, b, first, last)``, in the order ended.
    strength: f32[cap, 2] their ``(peak force, impulse)``.
    count: i32[] episodes ended so far (more than cap: the buffer overflowed).
  """

  first: jax.Array
  seen: jax.Array
  peak: jax.Array
  impulse: jax.Array
  rows: jax.Array
  strength: jax.Array
  count: jax.Array


def new_track(n_actors: int, cap: int) -> EpisodeTrack:
  """An empty :class:`EpisodeTrack` for ``n_actors`` actors and ``cap`` rows."""
  p = n_actors * n_actors
  return EpisodeTrack(jnp.full(p, NOT_OPEN, jnp.int32), jnp.full(p, NOT_OPEN, jnp.int32), jnp.zeros(p, jnp.float32),
                      jnp.zeros(p, jnp.float32), jnp.zeros((cap, 4), jnp.int32), jnp.zeros((cap, 2), jnp.float32),
                      jnp.zeros((), jnp.int32))


def pair_touches(side_a: jax.Array, side_b: jax.Array, touching: jax.Array, normal_force: jax.Array,
                 n_actors: int) -> tuple[jax.Array, jax.Array]:
  """(bool[P], f32[P]) which actor pairs touch in one world's step and their
  normal force summed over its contacts, from its contacts' actors
  (``side_a``, ``side_b``: i32[K], -1: none), whether each touches (bool[K])
  and its normal force (f32[K], N); as :func:`touch` counts them (contacts
  inside one actor are not events)."""
  lo, hi = jnp.minimum(side_a, side_b), jnp.maximum(side_a, side_b)
  real = touching & (lo >= 0) & (lo != hi)
  code = jnp.where(real, lo * n_actors + hi, 0)
  p = n_actors * n_actors
  touches = jnp.zeros(p, jnp.int32).at[code].add(real.astype(jnp.int32)) > 0
  force = jnp.zeros(p, jnp.float32).at[code].add(jnp.where(real, jnp.maximum(normal_force, 0.0), 0.0))
  return touches, force


def track_tick(track: EpisodeTrack, touches: jax.Array, force: jax.Array, tick, n_actors: int, gap: int,
               timestep: float, still: jax.Array | None = None, live=True) -> EpisodeTrack:
  """One tick of one world (:func:`touch` then :func:`end_tick`): pairs
  touching (bool[P], ``force`` f32[P] N) open or go on and add their force;
  an open pair that touched at the tick before and is ``still`` (bool[P]: its
  actors all asleep, so not tested) still touches; a pair apart for ``gap``
  ticks ends at the last tick it touched (a row written). A world not
  ``live`` (bool[]: it has ended) changes nothing."""
  touches = touches & live
  if still is not None:
    held = ~touches & still & (track.first != NOT_OPEN) & (track.seen == tick - 1) & live
    track = track._replace(seen=jnp.where(held, tick, track.seen))
  opening = touches & (track.first == NOT_OPEN)
  first = jnp.where(opening, tick, track.first)
  peak = jnp.where(opening, 0.0, track.peak)
  impulse = jnp.where(opening, 0.0, track.impulse)
  seen = jnp.where(touches, tick, track.seen)
  peak = jnp.where(touches, jnp.maximum(peak, force), peak)
  impulse = jnp.where(touches, impulse + force * timestep, impulse)
  ending = (first != NOT_OPEN) & ~touches & (tick - seen >= gap) & live
  cap = track.rows.shape[0]
  slot = track.count + jnp.cumsum(ending) - 1
  slot = jnp.where(ending & (slot < cap), slot, cap)  # cap: dropped (out of bounds)
  codes = jnp.arange(first.shape[0], dtype=jnp.int32)
  row = jnp.stack([codes // n_actors, codes % n_actors, first, seen], axis=1)
  rows = track.rows.at[slot].set(row, mode="drop")
  strength = track.strength.at[slot].set(jnp.stack([peak, impulse], axis=1), mode="drop")
  return EpisodeTrack(jnp.where(ending, NOT_OPEN, first), seen, peak, impulse, rows, strength,
                      track.count + ending.sum().astype(jnp.int32))


def finish_track(first: np.ndarray, seen: np.ndarray, peak: np.ndarray, impulse: np.ndarray, rows: np.ndarray,
                 strength: np.ndarray, count: int, n_actors: int, last_tick: int) -> int:
  """:func:`finish` of one world's :class:`EpisodeTrack` (host arrays;
  ``rows`` and ``strength`` are written in place): returns its episode count,
  sorted in ``rows[:count]``, or more than ``len(rows)`` where it overflowed."""
  codes = np.flatnonzero(first != NOT_OPEN).astype(np.int32)
  p = first.shape[0]
  codes_buf = np.zeros(p, np.int32)
  codes_buf[:codes.size] = codes
  open_ = OpenEpisodes(first.astype(np.int32).copy(), seen.astype(np.int32).copy(), np.zeros(p),
                       peak.astype(np.float64), impulse.astype(np.float64), codes_buf,
                       np.array([codes.size, count], np.int64))
  return finish(open_, n_actors, last_tick, rows, strength)
