"""mwbx.events.steps, the per-step episode kernels, on contacts written here."""

import numpy as np

from mwbx.events import steps

N_ACTORS = 4
DT = 0.01


def run(touches, n_ticks, gap=3, moving=None, cap=16, last_tick=None):
  """Episodes of ``touches`` {tick: [(a, b, force), ...]}; ``moving``: {tick: bool[N_ACTORS]}."""
  open_ = steps.new_episodes(N_ACTORS)
  rows, strength = np.zeros((cap, 4), np.int32), np.zeros((cap, 2), np.float32)
  for tick in range(n_ticks):
    for a, b, force in touches.get(tick, []):
      steps.touch(open_, N_ACTORS, a, b, force, tick)
    awake = (moving or {}).get(tick, np.ones(N_ACTORS, bool))
    steps.end_tick(open_, N_ACTORS, tick, gap, DT, awake, rows, strength)
  n = steps.finish(open_, N_ACTORS, n_ticks - 1 if last_tick is None else last_tick, rows, strength)
  return n, rows[:min(n, cap)], strength[:min(n, cap)]


def test_a_short_break_joins_a_long_one_ends_and_forces_add_per_tick():
  touches = {t: [(2, 1, 1.0), (1, 2, 2.0)] for t in (1, 2, 5)}  # two contacts a tick: 3 N
  touches.update({t: [(1, 2, 4.0)] for t in (9, 10)})
  touches[6] = [(3, 3, 9.0), (0, -1, 9.0)]  # inside one actor, and no actor: not events
  n, rows, strength = run(touches, 14)
  assert n == 2
  np.testing.assert_array_equal(rows, [[1, 2, 1, 5], [1, 2, 9, 10]])  # apart 2 ticks < gap: one episode
  np.testing.assert_allclose(strength, [[3.0, 9 * DT], [4.0, 8 * DT]])


def test_asleep_pairs_hold_their_touch_and_the_end_holds():
  asleep = np.array([True, False, False, True])  # 1 and 2 asleep (not tested by MuJoCo), 3 static-like
  touches = {0: [(1, 2, 5.0), (0, 3, 1.0)], 1: [(0, 3, 1.0)]}
  n, rows, strength = run(touches, 20, moving={t: asleep for t in range(1, 20)})
  # 1-2 touched at tick 0 and then slept: touching to the end (which holds); 0-3 ended at 1
  np.testing.assert_array_equal(rows, [[0, 3, 0, 1], [1, 2, 0, 19]])
  np.testing.assert_allclose(strength[1], [5.0, 5 * DT])


def test_finish_cuts_at_the_last_stored_tick_and_reports_overflow():
  touches = {t: [(0, 1, 1.0)] for t in range(10)}
  touches[12] = [(0, 2, 1.0)]  # after the last stored tick: dropped
  n, rows, _ = run(touches, 14, last_tick=8)
  np.testing.assert_array_equal(rows, [[0, 1, 0, 8]])
  many = {2 * t: [(0, 1, 1.0)] for t in range(5)}
  n, _, _ = run(many, 12, gap=1, cap=2)
  assert n == 5  # more than the buffer holds: the caller finds them another way
