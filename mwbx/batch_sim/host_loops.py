"""Compiled per-frame host loops of the native sampling loop.

After each ``rollout`` call the loop copies each world's new state, warm start
and sensors into its chunk buffers. As numpy that is a dozen calls per frame;
as one compiled loop (numba, cached on disk) it costs a few microseconds, which
matters next to a frame of physics that takes a few milliseconds. Same
arithmetic as the numpy form (tests compare them). The bookkeeping that follows
is :mod:`host_bookkeeping`.
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
