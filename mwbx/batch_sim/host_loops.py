"""Compiled per-frame host loops of the native sampling loop.

After each frame (a ``rollout`` call, or a world's ``mj_step`` calls in
:mod:`compiled_world`) the loop copies each world's new state, warm start and
sensors into its chunk buffers. As numpy that is a dozen calls per frame;
as one compiled loop (numba, cached on disk) it costs a few microseconds, which
matters next to a frame of physics that takes a few milliseconds. Same
arithmetic as the numpy form (tests compare them). The bookkeeping that follows
is :mod:`host_bookkeeping`.
"""

from __future__ import annotations

import numpy as np

from mwbx.host_jit import host_jit
from mwbx.scene import COM_POS, LIN_ACC, LIN_VEL, SENSOR_WIDTH


@host_jit
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


@host_jit
def rotation_matrix(w, x, y, z):
  """The 3x3 rotation matrix of the unit quaternion (w, x, y, z), row by row
  (numba twin of ``mwbx.rotations.quat_to_matrix``; tests/codec/test_rotations.py)."""
  return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
          2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
          2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


@host_jit
def observe_free_bodies(rows, before, after, timestep, gravity, qpos_start, qvel_start, bodies, sensordata):
  """:func:`mwbx.batch_sim.free_bodies.observe` for the worlds of a frame, compiled.

  The sensor block of tracked free bodies from the states of the frame (see
  :mod:`mwbx.batch_sim.free_bodies`), in float64, rounded to float32.

  Args:
    rows: i64[n] chunk row of each stepped world.
    before: f64[n, nstate] states s_k the frame started from.
    after: f64[n, S, nstate] states s_{k+1} … s_{k+S}.
    timestep: physics step, s.
    gravity: f64[3] m/s².
    qpos_start, qvel_start: index of qpos and of qvel in a state.
    bodies: :class:`mwbx.batch_sim.free_bodies.FreeBodies` of the tracked
      bodies (free joints' addresses, COM and inertial frames in the body frame).
    sensordata: f32[C, S, B * SENSOR_WIDTH] out (NaN for worlds MuJoCo reset).
  """
  qpos_adr, dof_adr, ipos, iquat = bodies.qpos_adr, bodies.dof_adr, bodies.ipos, bodies.iquat
  n, n_steps, _ = after.shape
  n_bodies = qpos_adr.size
  vel = np.empty((n_steps + 1, n_bodies, 6))
  pose = np.empty((n_steps + 1, n_bodies, 7))
  for i in range(n):
    r = rows[i]
    if not abs(after[i, n_steps - 1, 0] - (before[i, 0] + n_steps * timestep)) <= 1e-6:
      for s in range(n_steps):
        for j in range(sensordata.shape[2]):
          sensordata[r, s, j] = np.float32(np.nan)
      continue
    for s in range(n_steps + 1):
      x = before[i] if s == 0 else after[i, s - 1]
      for b in range(n_bodies):
        a = qpos_start + qpos_adr[b]
        w, qx, qy, qz = x[a + 3], x[a + 4], x[a + 5], x[a + 6]
        norm = np.sqrt(w * w + qx * qx + qy * qy + qz * qz)
        w, qx, qy, qz = w / norm, qx / norm, qy / norm, qz / norm
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_matrix(w, qx, qy, qz)
        ox = r00 * ipos[b, 0] + r01 * ipos[b, 1] + r02 * ipos[b, 2]
        oy = r10 * ipos[b, 0] + r11 * ipos[b, 1] + r12 * ipos[b, 2]
        oz = r20 * ipos[b, 0] + r21 * ipos[b, 1] + r22 * ipos[b, 2]
        pose[s, b, 0] = x[a] + ox
        pose[s, b, 1] = x[a + 1] + oy
        pose[s, b, 2] = x[a + 2] + oz
        iw, ix, iy, iz = iquat[b, 0], iquat[b, 1], iquat[b, 2], iquat[b, 3]
        pose[s, b, 3] = w * iw - qx * ix - qy * iy - qz * iz
        pose[s, b, 4] = w * ix + qx * iw + qy * iz - qz * iy
        pose[s, b, 5] = w * iy - qx * iz + qy * iw + qz * ix
        pose[s, b, 6] = w * iz + qx * iy - qy * ix + qz * iw
        d = qvel_start + dof_adr[b]
        lx, ly, lz = x[d + 3], x[d + 4], x[d + 5]
        wx = r00 * lx + r01 * ly + r02 * lz
        wy = r10 * lx + r11 * ly + r12 * lz
        wz = r20 * lx + r21 * ly + r22 * lz
        vel[s, b, 0] = x[d] + wy * oz - wz * oy
        vel[s, b, 1] = x[d + 1] + wz * ox - wx * oz
        vel[s, b, 2] = x[d + 2] + wx * oy - wy * ox
        vel[s, b, 3] = wx
        vel[s, b, 4] = wy
        vel[s, b, 5] = wz
    for s in range(n_steps):
      for b in range(n_bodies):
        o = b * SENSOR_WIDTH
        for j in range(7):  # com_pos then quat, adjacent in the block
          sensordata[r, s, o + COM_POS + j] = np.float32(pose[s, b, j])
        for j in range(6):
          sensordata[r, s, o + LIN_VEL + j] = np.float32(vel[s, b, j])
          acc = (vel[s + 1, b, j] - vel[s, b, j]) / timestep
          sensordata[r, s, o + LIN_ACC + j] = np.float32(acc - gravity[j] if j < 3 else acc)
