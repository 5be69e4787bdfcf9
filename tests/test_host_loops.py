"""The compiled host loops of the native sampler against their numpy form."""

import numpy as np

from mwbx.batch_sim import host_loops


def _absorb_numpy(before, after, sensors, timestep, qvel_start, nv):
  """What NativeBackend.absorb_frame computes, in numpy (the reference)."""
  n_steps = after.shape[1]
  bad = ~np.isclose(after[:, -1, 0], before[:, 0] + n_steps * timestep, rtol=0, atol=1e-6)
  sensors = sensors.copy()
  sensors[bad] = np.nan
  qvel = slice(qvel_start, qvel_start + nv)
  previous = after[:, -2] if n_steps > 1 else before
  return sensors.astype(np.float32), (after[:, -1, qvel] - previous[:, qvel]) / timestep, after[:, -1]


def test_absorb_rows_matches_numpy():
  rng = np.random.default_rng(0)
  c, n_steps, nstate, nsens, nq, nv, dt = 9, 4, 15, 11, 7, 6, 1 / 480
  rows = np.array([0, 2, 3, 7, 8])
  before = rng.normal(size=(rows.size, nstate))
  after = rng.normal(size=(rows.size, n_steps, nstate))
  after[:, :, 0] = before[:, :1] + dt * np.arange(1, n_steps + 1)
  after[2, -1, 0] = 0.0  # MuJoCo reset this world: its sensors must become NaN
  sensors = rng.normal(size=(rows.size, n_steps, nsens))
  sensordata = np.zeros((c, n_steps, nsens), np.float32)
  warmstart = np.zeros((c, nv))
  states = np.zeros((c, nstate))
  host_loops.absorb_rows(rows, before, after, sensors, dt, 1 + nq, sensordata, warmstart, states)
  want_s, want_w, want_x = _absorb_numpy(before, after, sensors, dt, 1 + nq, nv)
  np.testing.assert_array_equal(sensordata[rows], want_s)
  np.testing.assert_array_equal(warmstart[rows], want_w)
  np.testing.assert_array_equal(states[rows], want_x)
  assert np.isnan(sensordata[rows[2]]).all() and not np.isnan(sensordata[rows[1]]).any()
  untouched = np.setdiff1d(np.arange(c), rows)
  assert not sensordata[untouched].any() and not warmstart[untouched].any()
