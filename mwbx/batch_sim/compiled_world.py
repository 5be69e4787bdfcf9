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

import numpy as np

from mwbx.batch_sim import host_bookkeeping, host_loops, mujoco_c
from mwbx.host_jit import host_jit


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
def physics_step(model_adr, data_adr, xfrc_applied, wrench, data_ctrl, ctrl_table, k, state_out, free,
                 sensors_out, data_sensordata):
  """One ``mj_step`` of a world with the step's applied wrenches and control.

  Args:
    wrench: f64[nbody, 6] ``xfrc_applied`` of the step.
    ctrl_table: f64[N, nu] control per step (width 0: ``ctrl`` left alone); k: the step.
    state_out: f64[nstate] out: the full physics state after the step.
    sensors_out: f64[nsensordata] out unless ``free``: the sensors of the
      state the step started from.
  """
  xfrc_applied[:, :] = wrench
  if ctrl_table.shape[1] > 0:
    data_ctrl[:] = ctrl_table[min(k, ctrl_table.shape[0] - 1)]
  _step(model_adr, data_adr)
  _get_state(model_adr, data_adr, state_out.ctypes.data, _FULLPHYSICS)
  if not free:
    sensors_out[:] = data_sensordata


@host_jit
def run_world(row, model_adr, data_adr, xfrc_applied, data_sensordata, data_ctrl, ctrl_table,
              initial_states, n_frames, timestep, gravity, free, qpos_adr, dof_adr, ipos, iquat, sensordata, warmstart,
              states, key_data, p, carry, tracked, qpos_buf, com_buf, wrench_full, running):
  """Runs world ``row`` of a chunk until it finishes; returns seconds inside ``mj_step``.

  Args:
    row: chunk row of the world.
    model_adr, data_adr: ``MjModel._address`` and ``MjData._address`` (this
      thread's data).
    xfrc_applied: f64[nbody, 6], data_sensordata: f64[nsensordata] and
      data_ctrl: f64[nu], views of that ``MjData``'s arrays.
    ctrl_table: f64[n_frames · S, nu] control of each step
      (:func:`mwbx.controls.control_table`); width 0: ``ctrl`` is left alone.
    initial_states: f64[C, nstate] full physics states at time 0.
    n_frames: frames per world at most.
    timestep: physics step, s. gravity: f64[3], m/s**2.
    free: True to observe free bodies from the states (the model then steps
      without sensors); False to read MuJoCo's sensors.
    qpos_adr, dof_adr, ipos, iquat: :class:`free_bodies.FreeBodies` arrays.
    sensordata, warmstart, states: chunk buffers of
      :func:`host_loops.absorb_rows` (f32[C, S, nsensordata], f64[C, nv],
      f64[C, nstate]).
    key_data, p, carry, tracked, qpos_buf, com_buf, wrench_full, running: as
      :func:`host_bookkeeping.frame_update`.
  """
  n_steps = wrench_full.shape[1]
  nstate = initial_states.shape[1]
  nq = qpos_buf.shape[2]
  rows = np.full(1, row, np.int64)
  before = np.empty((1, nstate))
  after = np.empty((1, n_steps, nstate))
  sensors = np.zeros((1, n_steps, 0 if free else data_sensordata.size))
  ts = np.zeros(2, np.int64)
  _reset(model_adr, data_adr)
  _set_state(model_adr, data_adr, initial_states[row].ctypes.data, _FULLPHYSICS)
  physics = 0.0
  frame = 0
  while running[row] and frame < n_frames:
    _get_state(model_adr, data_adr, before[0].ctypes.data, _FULLPHYSICS)
    start = monotonic_seconds(ts)
    for s in range(n_steps):
      physics_step(model_adr, data_adr, xfrc_applied, wrench_full[row, s], data_ctrl, ctrl_table,
                   frame * n_steps + s, after[0, s], free, sensors[0, s], data_sensordata)
    physics += monotonic_seconds(ts) - start
    host_loops.absorb_rows(rows, before, after, sensors, timestep, 1 + nq, sensordata, warmstart,
                           states)
    if free:
      host_loops.observe_free_bodies(rows, before, after, timestep, gravity, 1, 1 + nq, qpos_adr,
                                     dof_adr, ipos, iquat, sensordata)
    host_bookkeeping.frame_update(rows, sensordata, key_data, p, carry, tracked, before, 1, frame,
                                  qpos_buf, com_buf, wrench_full, running)
    frame += 1
  return physics
