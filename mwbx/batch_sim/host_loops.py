"""Compiled per-frame host loops of the native sampling loop.

Between two ``rollout`` calls the loop copies each world's new state, warm
start and sensors into its chunk buffers, and each recorded world's ``qpos``,
COM and next wrenches out of the kernel's output. As numpy these are a dozen
calls per frame; as one compiled loop each (numba, cached on disk) they cost a
few microseconds, which matters next to a frame of physics that takes a few
milliseconds. Same arithmetic as the numpy form (tests compare them).
"""

from __future__ import annotations

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True)


@_jit
def absorb_rows(rows, before, after, sensors, timestep, qvel_start, sensordata, warmstart,
                states):
  """What one frame of ``NativeBackend.step`` output means, written in place.

  Args:
    rows: i64[n] chunk row of each stepped world.
    before: f64[n, nstate] states the frame started from.
    after: f64[n, S, nstate] states after each step.
    sensors: f64[n, S, nsensordata] sensors of each step.
    timestep: physics step, s.
    qvel_start: index of qvel in a state.
    sensordata: f32[C, S, nsensordata] out: sensors, NaN for worlds MuJoCo
      reset (their clock did not advance S steps: they diverged).
    warmstart: f64[C, nv] out: accelerations of the last step.
    states: f64[C, nstate] out: the last state.
  """
  n, n_steps, nstate = after.shape
  nv = warmstart.shape[1]
  for i in range(n):
    r = rows[i]
    reset = not abs(after[i, n_steps - 1, 0] - (before[i, 0] + n_steps * timestep)) <= 1e-6
    for s in range(n_steps):
      for j in range(sensors.shape[2]):
        sensordata[r, s, j] = np.float32(np.nan) if reset else np.float32(sensors[i, s, j])
    for j in range(nv):
      previous = after[i, n_steps - 2, qvel_start + j] if n_steps > 1 else before[i, qvel_start + j]
      warmstart[r, j] = (after[i, n_steps - 1, qvel_start + j] - previous) / timestep
    for j in range(nstate):
      states[r, j] = after[i, n_steps - 1, j]


@_jit
def take_frame(packed, n_steps, tracked, record_rows, before, qpos_start, frame, qpos_buf, com_buf,
               wrench_full):
  """Unpack the kernel's per-frame output and record the frame.

  Args:
    packed: f32[C, S*B*6 + B*3 + 2] per world: next wrenches, COM, record, running.
    n_steps: S.
    tracked: i64[B] MuJoCo body id of each tracked body.
    record_rows: i64[C] row of ``before`` holding each world's state s_k (-1: not stepped).
    before: f64[n, nstate] states s_k of the stepped worlds.
    qpos_start: index of qpos in a state.
    frame: frame index to record into.
    qpos_buf: f32[C, T, nq] out; com_buf: f32[C, T, B, 3] out; wrench_full:
      f64[C, S, nbody, 6] out.

  Returns:
    bool[C] worlds still running.
  """
  c = packed.shape[0]
  n_tracked = tracked.size
  nq = qpos_buf.shape[2]
  n_wrench = n_steps * n_tracked * 6
  running = np.zeros(c, np.bool_)
  for w in range(c):
    col = 0
    for s in range(n_steps):
      for b in range(n_tracked):
        for k in range(6):
          wrench_full[w, s, tracked[b], k] = packed[w, col]
          col += 1
    running[w] = packed[w, -1] > 0
    row = record_rows[w]
    if packed[w, -2] > 0 and row >= 0:
      for j in range(nq):
        qpos_buf[w, frame, j] = np.float32(before[row, qpos_start + j])
      for b in range(n_tracked):
        for k in range(3):
          com_buf[w, frame, b, k] = packed[w, n_wrench + 3 * b + k]
  return running
