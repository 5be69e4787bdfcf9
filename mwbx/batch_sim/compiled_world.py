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

import numpy as np

from mwbx.batch_sim import free_bodies as free_bodies_lib
from mwbx.batch_sim import host_bookkeeping, host_loops, mujoco_c, sleep, world
from mwbx.host_jit import host_jit


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


@host_jit
def run_world(row, data, inputs, initial_states, buffers, running):
  """Runs world ``row`` of a chunk until it finishes; returns seconds inside ``mj_step``.

  Args:
    row: chunk row of the world.
    data: :class:`mujoco_c.MjDataViews` of this thread's ``MjData``.
    inputs: the chunk's :class:`WorldInputs`.
    initial_states: f64[C, nstate] full physics states at time 0.
    buffers: the chunk's :class:`host_bookkeeping.ChunkBuffers` (row ``row`` written).
    running: bool[C] as :func:`host_bookkeeping.frame_update` (out).
  """
  b = buffers
  free = inputs.free
  n_steps = b.wrench_full.shape[1]
  nstate = initial_states.shape[1]
  nq = b.qpos_buf.shape[2]
  rows = np.full(1, row, np.int64)
  before = np.empty((1, nstate))
  after = np.empty((1, n_steps, nstate))
  sensors = np.zeros((1, n_steps, 0 if free else data.sensordata.size))
  ts = np.zeros(2, np.int64)
  _reset(data.model_adr, data.data_adr)
  _set_state(data.model_adr, data.data_adr, initial_states[row].ctypes.data, _FULLPHYSICS)
  physics = 0.0
  frame = 0
  while running[row] and frame < inputs.n_frames:
    _get_state(data.model_adr, data.data_adr, before[0].ctypes.data, _FULLPHYSICS)
    start = monotonic_seconds(ts)
    for s in range(n_steps):
      physics_step(data, b.wrench_full[row, s], inputs.ctrl_table, frame * n_steps + s, after[0, s], free,
                   sensors[0, s])
    physics += monotonic_seconds(ts) - start
    host_loops.absorb_rows(rows, before, after, sensors, inputs.timestep, 1 + nq, b.sensordata, b.warmstart,
                           b.states)
    if free:
      host_loops.observe_free_bodies(rows, before, after, inputs.timestep, inputs.gravity, 1, 1 + nq,
                                     inputs.free_bodies, b.sensordata)
    host_bookkeeping.frame_update(rows, b, before, 1, frame, running)
    if inputs.rest_when_asleep and running[row] and sleep.all_asleep(data.tree_asleep):
      b.carry.status[row] = world.AT_REST  # nothing moves until something wakes it: nothing will
      running[row] = False
    frame += 1
  return physics
