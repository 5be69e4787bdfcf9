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


def run_jax(touches, n_ticks, gap=3, cap=16, last_tick=None):
  """The JAX twin (steps.track_tick in a jitted scan, steps.finish_track) on
  the same touches: every actor awake (MJX does not sleep)."""
  import jax
  import jax.numpy as jnp
  k = max((len(v) for v in touches.values()), default=1)
  side_a = np.full((n_ticks, k), -1, np.int32)
  side_b = np.full((n_ticks, k), -1, np.int32)
  force = np.zeros((n_ticks, k), np.float32)
  for tick, contacts in touches.items():
    for i, (a, b, f) in enumerate(contacts):
      side_a[tick, i], side_b[tick, i], force[tick, i] = a, b, f

  @jax.jit
  def scan(track, xs):
    def body(track, x):
      a, b, f, tick = x
      touching, pair_force = steps.pair_touches(a, b, jnp.ones(a.shape, bool), f, N_ACTORS)
      return steps.track_tick(track, touching, pair_force, tick, N_ACTORS, gap, DT), None
    return jax.lax.scan(body, track, xs)[0]

  track = scan(steps.new_track(N_ACTORS, cap), (side_a, side_b, force, jnp.arange(n_ticks, dtype=jnp.int32)))
  track = jax.tree.map(np.array, track)
  n = steps.finish_track(track.first, track.seen, track.peak, track.impulse, track.rows, track.strength,
                         int(track.count), N_ACTORS, n_ticks - 1 if last_tick is None else last_tick)
  return n, track.rows[:min(n, cap)], track.strength[:min(n, cap)]


def test_the_jax_twin_finds_the_same_episodes_as_the_host_kernels():
  """Random contacts (several a tick, repeated pairs, contacts inside one
  actor or with none), short and long breaks, a cut before the end and an
  overflowing buffer: the jitted tracker's episodes and strengths are the
  host kernels' (forces summed in float32 there: 1e-5)."""
  rng = np.random.default_rng(0)
  compared = 0
  for trial in range(20):
    n_ticks = int(rng.integers(5, 60))
    touches = {}
    for tick in range(n_ticks):
      if rng.random() < 0.5:
        touches[tick] = [(int(rng.integers(-1, N_ACTORS)), int(rng.integers(0, N_ACTORS)), float(rng.random() * 5))
                         for _ in range(int(rng.integers(1, 4)))]
    gap = int(rng.integers(1, 5))
    cap = 16 if trial % 4 else 3
    last = n_ticks - 1 - int(rng.integers(0, 4))
    host = run(touches, n_ticks, gap=gap, cap=cap, last_tick=last)
    twin = run_jax(touches, n_ticks, gap=gap, cap=cap, last_tick=last)
    assert host[0] == twin[0], trial
    if host[0] <= cap:
      np.testing.assert_array_equal(twin[1], host[1])
      np.testing.assert_allclose(twin[2], host[2], rtol=1e-5, atol=1e-6)
      compared += host[0]
  assert compared > 20
