"""One world from its initial state to rest or end time, in one compiled call.

The native backend's fast path: a numba function (no GIL) steps one world with
MuJoCo's C ``mj_step`` (:mod:`mujoco_c`) frame after frame and runs the same
per-frame work as the lockstep loop on it: the frame's states and sensors
(:func:`host_loops.absorb_rows`), the free-body observation
(:func:`host_loops.observe_free_bodies`) and the bookkeeping, recording and
next wrenches (:func:`host_bookkeeping.frame_update`), each called for the one
row. A thread per core pulls worlds from a shared counter, each with its own
``MjData``, so there is no per-frame barrier between worlds, no Python per frame,
and a world that runs long does not hold the others back.

World ``i`` still depends on ``(config, run key, i)`` alone: its rows of the
chunk buffers are written by the one thread that runs it, and ``MjData`` is
reset before every world.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from mwbx.batch_sim import free_bodies as free_bodies_lib
from mwbx.batch_sim import host_bookkeeping, host_loops, mujoco_c, sleep, world
from mwbx.events import steps as steps_lib
from mwbx.events.actors import Actors, actor_trees
from mwbx.host_jit import borrowed, held, host_jit


class WorldInputs(NamedTuple):
  """What every world of a chunk steps and is observed with (read only).

  Attributes:
    ctrl_table: f64[n_frames · S, nu] actuator control of each step from step 0
      (:func:`mwbx.controls.control_table`, the actuators' units); width 0:
      ``ctrl`` is left alone.
    n_frames: frames per world at most (end_frame + 1).
    timestep: physics step, s.
    gravity: f64[3] m/s².
    free: True to observe the tracked bodies from the states (the model then
      steps without sensors); False to read MuJoCo's sensors.
    free_bodies: :class:`free_bodies.FreeBodies` of the tracked bodies
      (:func:`free_bodies.host_arrays`; empty arrays unless ``free``).
    rest_when_asleep: a world whose every tree sleeps (MuJoCo's island
      sleep, :mod:`sleep`) is at rest and stops.
  """

  ctrl_table: np.ndarray
  n_frames: int
  timestep: float
  gravity: np.ndarray
  free: bool
  free_bodies: free_bodies_lib.FreeBodies
  rest_when_asleep: bool = False


class StepEventInputs(NamedTuple):
  """How a compiled loop finds contact events at every physics step
  (:mod:`mwbx.events.steps`); :func:`step_event_inputs` makes them.

  Attributes:
    on: False: no events (the arrays may be empty).
    contact_words: i64[10] the :class:`mujoco_c.ContactLayout`, in its order.
    geom_actor: i32[ngeom] each geom's actor; flex_actor: i32[max(nflex, 1)] each flex's.
    n_actors: how many actors.
    actor_tree_start: i64[n_actors + 1], actor_trees: i64[k] each actor's
      kinematic trees (CSR; static actors none).
    sleep: the model sleeps (an actor then moves only while a tree of it is awake).
    gap: steps apart that end an episode (the sampler's: the physics steps of a query point).
    pyramidal: the model's friction cones are pyramidal (a contact's normal
      force is then the sum of its pyramid's edge forces, as ``mj_contactForce`` has it).
  """

  on: bool
  contact_words: np.ndarray
  geom_actor: np.ndarray
  flex_actor: np.ndarray
  n_actors: int
  actor_tree_start: np.ndarray
  actor_trees: np.ndarray
  sleep: bool
  gap: int = 1
  pyramidal: bool = True


class EventBuffers(NamedTuple):
  """Each world's episodes, written by the thread that runs it.

  Attributes:
    rows: i32[C, cap, 4] ``(a, b, first, last)``, steps. strength: f32[C, cap, 2] N, N·s.
    count: i64[C] episodes of each world (more than cap: overflowed).
  """

  rows: np.ndarray
  strength: np.ndarray
  count: np.ndarray


def step_event_inputs(model, actors: Actors | None, gap: int) -> StepEventInputs:
  """The :class:`StepEventInputs` of a model and its actors, ``gap`` the
  steps apart that end an episode (off where ``actors`` is None or the
  contacts cannot be read here)."""
  layout = mujoco_c.contact_layout()
  on = actors is not None and layout is not None
  n_actors = len(actors.names) if actors is not None else 0
  trees = actor_trees(model, actors) if on else [[] for _ in range(n_actors)]
  flex_actor = np.asarray(actors.flex_actor if actors is not None else [], np.int32)
  return StepEventInputs(
      on=on, contact_words=np.asarray(layout if layout is not None else [0] * len(mujoco_c.ContactLayout._fields),
                                      np.int64),
      geom_actor=np.asarray(actors.geom_actor if actors is not None else [], np.int32),
      flex_actor=flex_actor if flex_actor.size else np.full(1, -1, np.int32), n_actors=n_actors,
      actor_tree_start=np.concatenate([[0], np.cumsum([len(t) for t in trees])]).astype(np.int64),
      actor_trees=np.asarray([t for ts in trees for t in ts], np.int64),
      sleep=bool(model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP)), gap=int(gap),
      pyramidal=int(model.opt.cone) == int(mujoco.mjtCone.mjCONE_PYRAMIDAL))


def event_buffers(n_worlds: int, events: StepEventInputs) -> EventBuffers:
  """Empty :class:`EventBuffers` for ``n_worlds`` worlds (none where ``events`` is off)."""
  cap = steps_lib.episode_capacity(events.n_actors) if events.on else 0
  return EventBuffers(np.zeros((n_worlds, cap, 4), np.int32), np.zeros((n_worlds, cap, 2), np.float32),
                      np.zeros(n_worlds, np.int64))


# Where each of the ContactLayout's words sits in ``contact_words`` (its field order).
_NCON, _ARENA, _CONTACT, _STRIDE, _GEOM, _FLEX, _EXCLUDE, _EFC, _DIM, _EFC_FORCE = (
    mujoco_c.ContactLayout._fields.index(name) for name in (
        "ncon", "arena", "contact", "stride", "geom", "flex", "exclude", "efc_address", "dim", "efc_force"))


@host_jit
def _side_actor(events, a32, rec, w, k):
  """The actor of side ``k`` of the contact at byte ``rec`` of the arena: its geom's, or its flex's."""
  g = a32[(rec + w[_GEOM]) // 4 + k]
  return events.geom_actor[g] if g >= 0 else events.flex_actor[max(a32[(rec + w[_FLEX]) // 4 + k], 0)]


@host_jit
def read_contacts(data, events, open_, tick):
  """Every actor pair touching in the contacts of the step just taken
  (:func:`mwbx.events.steps.touch`), with its normal force read from the
  step's ``efc_force``."""
  w = events.contact_words
  h32, h64, a32, a64 = data.header_i32, data.header_i64, data.arena_i32, data.arena_f64
  if h64.size == 0:
    return
  ncon = h32[w[_NCON]]
  start = h64[w[_CONTACT]] - h64[w[_ARENA]]
  efc = (h64[w[_EFC_FORCE]] - h64[w[_ARENA]]) // 8  # efc_force as a word of the arena
  stride = w[_STRIDE]
  if ncon <= 0 or start < 0 or start % 8 != 0 or start + ncon * stride > 4 * a32.size or efc < 0:
    return
  for i in range(ncon):
    rec = start + i * stride
    if a32[(rec + w[_EXCLUDE]) // 4] == steps_lib.EXCLUDE_IN_GAP:
      continue
    a = _side_actor(events, a32, rec, w, 0)
    b = _side_actor(events, a32, rec, w, 1)
    force = 0.0
    adr = a32[(rec + w[_EFC]) // 4]
    if adr >= 0:
      dim = a32[(rec + w[_DIM]) // 4]
      edges = 2 * (dim - 1) if events.pyramidal and dim > 1 else 1
      if efc + adr + edges <= a64.size:
        for k in range(edges):
          force += a64[efc + adr + k]
    steps_lib.touch(open_, events.n_actors, a, b, force, tick)


class WorldEvents(NamedTuple):
  """One world's step events as its loop keeps them (:func:`new_world_events`).

  Attributes:
    open_: :class:`mwbx.events.steps.OpenEpisodes`.
    moving: bool[n_actors] scratch: the actors with an awake tree.
    rows, strength: the world's rows of the chunk's :class:`EventBuffers`.
  """

  open_: steps_lib.OpenEpisodes
  moving: np.ndarray
  rows: np.ndarray
  strength: np.ndarray


@host_jit
def new_world_events(events, event_buffers, row):
  """A fresh :class:`WorldEvents` for world ``row`` (one actor's worth where ``events`` is off)."""
  n_actors = events.n_actors if events.on else 1
  moving = np.ones(n_actors, np.bool_)
  for a in range(n_actors):  # static actors never move (sleeping scenes recompute the objects')
    moving[a] = (not events.on) or events.actor_tree_start[a + 1] > events.actor_tree_start[a]
  return WorldEvents(steps_lib.new_episodes(n_actors), moving, event_buffers.rows[row],
                     event_buffers.strength[row])


@host_jit
def step_events(data, events, world_events, tick, timestep):
  """The events of one physics step of a world (after its ``mj_step``)."""
  w = world_events
  read_contacts(data, events, w.open_, tick)
  if events.sleep:
    steps_lib.actors_moving(data.tree_asleep, events.actor_tree_start, events.actor_trees, w.moving)
  steps_lib.end_tick(w.open_, events.n_actors, tick, events.gap, timestep, w.moving, w.rows, w.strength)


@host_jit
def finish_events(events, world_events, last_tick):
  """The world's episode count once it ended at ``last_tick`` (:func:`mwbx.events.steps.finish`)."""
  w = world_events
  return steps_lib.finish(w.open_, events.n_actors, last_tick, w.rows, w.strength)


_step = mujoco_c.mj_step
_reset = mujoco_c.mj_resetData
_get_state = mujoco_c.mj_getState
_set_state = mujoco_c.mj_setState
_clock = mujoco_c.clock_gettime
_CLOCK = mujoco_c.CLOCK_MONOTONIC
_FULLPHYSICS = mujoco_c.STATE_FULLPHYSICS


@host_jit
def monotonic_seconds(ts):
  """Monotonic clock, s (``ts``: i64[2] scratch for the timespec)."""
  _clock(_CLOCK, ts.ctypes.data)
  return ts[0] + 1e-9 * ts[1]


@host_jit
def physics_step(data, wrench, ctrl_table, k, state_out, free, sensors_out):
  """One ``mj_step`` of a world with the step's applied wrenches and control.

  Args:
    data: :class:`mujoco_c.MjDataViews` of the world's ``MjData``.
    wrench: f64[nbody, 6] ``xfrc_applied`` of the step.
    ctrl_table: f64[N, nu] control per step (width 0: ``ctrl`` left alone); k: the step.
    state_out: f64[nstate] out: the full physics state after the step.
    sensors_out: f64[nsensordata] out unless ``free``: the sensors of the
      state the step started from.
  """
  data.xfrc_applied[:, :] = wrench
  if ctrl_table.shape[1] > 0:
    data.ctrl[:] = ctrl_table[min(k, ctrl_table.shape[0] - 1)]
  _step(data.model_adr, data.data_adr)
  _get_state(data.model_adr, data.data_adr, state_out.ctypes.data, _FULLPHYSICS)
  if not free:
    sensors_out[:] = data.sensordata


# The loop reads the clock around every PHYSICS_CLOCK_EVERY-th mj_step only, and
# counts that step's time for each of them: two clock reads a step cost about
# 4 % of a step on the quickstart (a virtual machine's clock is slow to read).
PHYSICS_CLOCK_EVERY = 8


@host_jit
def run_world(row, data, inputs, initial_states, buffers, running, events, event_buffers, tree_frames):
  """Runs world ``row`` of a chunk until it finishes; returns seconds inside
  ``mj_step`` (estimated from every :data:`PHYSICS_CLOCK_EVERY`-th step).

  Args:
    row: chunk row of the world.
    data: :class:`mujoco_c.MjDataViews` of this thread's ``MjData``.
    inputs: the chunk's :class:`WorldInputs`.
    initial_states: f64[C, nstate] full physics states at time 0.
    buffers: the chunk's :class:`host_bookkeeping.ChunkBuffers` (row ``row`` written).
    running: bool[C] as :func:`host_bookkeeping.frame_update` (out).
    events: :class:`StepEventInputs`; event_buffers: :class:`EventBuffers` (row ``row`` written).
    tree_frames: i64[C, 2] (row ``row`` added to where the model sleeps): per
      frame stepped, the kinematic trees asleep at its end and the model's trees.
  """
  # The arguments without reference counting from here on (the caller holds them).
  data, inputs, initial_states, b, running, events, event_buffers, tree_frames = borrowed(
      (data, inputs, initial_states, buffers, running, events, event_buffers, tree_frames))
  free = inputs.free
  n_steps = b.wrench_full.shape[1]
  nstate = initial_states.shape[1]
  nq = b.qpos_buf.shape[2]
  owned = (np.full(1, row, np.int64), np.empty((1, nstate)), np.empty((1, n_steps, nstate)),
           np.zeros((1, n_steps, 0 if free else data.sensordata.size)), np.zeros(2, np.int64),
           new_world_events(events, event_buffers, row))
  rows, before, after, sensors, ts, world_events = borrowed(owned)  # this world's scratch, held to the end
  _reset(data.model_adr, data.data_adr)
  _set_state(data.model_adr, data.data_adr, initial_states[row].ctypes.data, _FULLPHYSICS)
  physics = 0.0
  frame = 0
  while running[row] and frame < inputs.n_frames:
    _get_state(data.model_adr, data.data_adr, before[0].ctypes.data, _FULLPHYSICS)
    for s in range(n_steps):
      k = frame * n_steps + s
      timed = k % PHYSICS_CLOCK_EVERY == 0
      start = monotonic_seconds(ts) if timed else 0.0
      physics_step(data, b.wrench_full[row, s], inputs.ctrl_table, k, after[0, s], free, sensors[0, s])
      if timed:
        physics += PHYSICS_CLOCK_EVERY * (monotonic_seconds(ts) - start)
      if events.on:
        step_events(data, events, world_events, k, inputs.timestep)
    host_loops.absorb_rows(rows, before, after, sensors, inputs.timestep, 1 + nq, b.sensordata, b.warmstart,
                           b.states)
    if free:
      host_loops.observe_free_bodies(rows, before, after, inputs.timestep, inputs.gravity, 1, 1 + nq,
                                     inputs.free_bodies, b.sensordata)
    host_bookkeeping.frame_update(rows, b, before, 1, frame, running)
    if inputs.rest_when_asleep:
      asleep, trees = sleep.asleep_count(data.tree_asleep), data.tree_asleep.size
      tree_frames[row, 0] += asleep
      tree_frames[row, 1] += trees
      if running[row] and sleep.every_tree(asleep, trees):
        b.carry.status[row] = world.AT_REST  # nothing moves until something wakes it: nothing will
        running[row] = False
    frame += 1
  if events.on:
    event_buffers.count[row] = finish_events(events, world_events, (b.carry.frame_count[row] - 1) * n_steps)
  held(owned)
  return physics
