"""Contact events found inside the MJX scan (mwbx/batch_sim/mjx_events.py),
against the same batch replayed step by step with the backend's own step,
each step's contacts read on the host in plain loops, contact by contact, as
``mj_contactForce`` reads a contact's normal force (its first row, or the sum
over a pyramid's edges). A fast impact (a ball at 16 m/s off a stiff floor,
in contact for less than a stored frame) and a domino row (each knocks
the next); forces checked against physics too: dominoes at rest press on the
floor with their weight, the ball's impulse turns 16 m/s around.
(``mjx.get_data`` is no reference here: it keeps the first contact slots
with ``dist <= 0`` and drops constraint rows with a zero Jacobian.)"""


import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.batch_sim.sampler import world_keys
from mwbx.events import actors_of
from mwbx.events.record import STRENGTH_RELATIVE_ERROR
from mwbx.refinement import run_refinement
from event_scenes import FAST_XML, domino_row_xml

DOMINO_XML = domino_row_xml(4)
# Episode strengths are stored within STRENGTH_RELATIVE_ERROR; MJX sums a step's force in float32.
STRENGTH_RTOL = STRENGTH_RELATIVE_ERROR + 1e-4


def _config(tmp_path, name, xml, yaml_tail, impl="jax"):
  # The ball from 13 m lands at 1.63 s; the row's last domino is knocked by 0.55-0.61 s.
  (tmp_path / f"{name}.xml").write_text(xml)
  (tmp_path / f"{name}.yaml").write_text(
      f"scene: {{mjcf: {name}.xml}}\nperturb: {{enabled: false}}\n{yaml_tail}"
      f"sim: {{end_time: {1.75 if name == 'fast' else 0.75}, mjx_impl: {impl}}}\n")
  return mwbx.load_config(tmp_path / f"{name}.yaml")


def _replayed_episodes(config, n_worlds, seed=0):
  """(bank sampled on MJX, per world the set of its episodes replayed)."""
  with mwbx.Sampler(config, backend="mjx") as sampler:
    bank, _ = sampler.run(n_worlds, jax.random.key(seed))
    _, init_keys, _ = world_keys(jax.random.key(seed), np.arange(n_worlds))
    qpos0, qvel0 = sampler._init(init_keys)
    backend = sampler.backend
    model = backend.model
    actors = actors_of(model, list(bank.objects))
    spf = bank.events.ticks_per_frame
    gap = spf * round(bank.record_fps / bank.query_fps)  # a query point's steps apart end an episode
    d = backend.make_data(jnp.asarray(qpos0), jnp.asarray(qvel0))
    xfrc = jnp.zeros((n_worlds, model.nbody, 6), jnp.float32)
    last_ticks = (np.asarray(bank.frame_count) - 1) * spf
    n_ticks = int(last_ticks.max()) + spf

    def one_step(d, _):  # the backend's own step, and what the host reads of its contacts
      d = backend.step(d, xfrc)
      c = d._impl.contact
      return d, (c.dist, c.includemargin, c.dim, c.efc_address, c.geom, d._impl.efc_force)

    # Every step's contacts at once (one call, not one per step), read below step by step.
    every_step = jax.device_get(jax.jit(lambda d: jax.lax.scan(one_step, d, length=n_ticks)[1])(d))
    open_ = [dict() for _ in range(n_worlds)]
    done = [[] for _ in range(n_worlds)]
    for tick in range(n_ticks):
      forces = [dict() for _ in range(n_worlds)]
      dist, margin, dims, addresses, geoms, efc_force = (np.asarray(x[tick]) for x in every_step)  # [W, ncon]
      dims, addresses = (np.broadcast_to(x, dist.shape) for x in (dims, addresses))
      geoms = np.broadcast_to(geoms, dist.shape + (2,))
      pyramidal = model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
      for w, i in zip(*np.nonzero(dist < margin)):  # the contacts not in their margin's gap
        a, b = (int(actors.geom_actor[g]) for g in geoms[w, i])
        if a == b:
          continue
        dim, adr = int(dims[w, i]), int(addresses[w, i])
        rows = 2 * (dim - 1) if pyramidal and dim > 1 else 1
        f = float(sum(efc_force[w, adr + k] for k in range(rows))) if adr >= 0 else 0.0
        key = (min(a, b), max(a, b))
        forces[w][key] = forces[w].get(key, 0.0) + max(f, 0.0)
      for w in range(n_worlds):
        if tick > last_ticks[w] + spf - 1:
          continue
        for key, f in forces[w].items():
          first, _, peak, impulse = open_[w].get(key, (tick, tick, 0.0, 0.0))
          open_[w][key] = (first, tick, max(peak, f), impulse + f * model.opt.timestep)
        for key, (first, seen, peak, impulse) in list(open_[w].items()):
          if tick - seen >= gap:
            done[w].append((*key, first, seen, peak, impulse))
            del open_[w][key]
    episodes = []
    for w in range(n_worlds):
      last = int(last_ticks[w])
      found = done[w] + [(*key, first, last if seen >= last else seen, peak, impulse)
                         for key, (first, seen, peak, impulse) in open_[w].items()]
      episodes.append({(a, b, first, min(end, last), peak, impulse) for a, b, first, end, peak, impulse in found
                       if first <= last})
  return bank, episodes


def _check(bank, episodes):
  assert bank.events.ticks_per_frame > 1
  for row, expected in enumerate(episodes):
    lo, hi = bank.events.offsets[row], bank.events.offsets[row + 1]
    got = {tuple(r) for r in bank.events.rows[lo:hi].tolist()}
    assert got == {e[:4] for e in expected}, row  # recall 100 %, none invented, to the step
    strength = {tuple(r): s for r, s in zip(bank.events.rows[lo:hi].tolist(), bank.events.strength[lo:hi])}
    for e in expected:
      np.testing.assert_allclose(strength[e[:4]], e[4:], rtol=STRENGTH_RTOL, atol=1e-6)


def test_mjx_finds_a_fast_impact_and_a_domino_row_at_every_step(tmp_path):
  """One scene, one compile: a ball thrown down at 16 m/s onto a stiff floor
  (in contact for fewer steps than a stored frame holds) beside a domino row
  whose first domino is tipped (each knocks the next)."""
  ball = ('<body name="ball" pos="-1 0 0.45"><freejoint/>'
          '<geom type="sphere" size="0.05" mass="0.2" solref="-1e6 -10"/></body>')
  config = _config(tmp_path, "dominoes", DOMINO_XML.replace("</worldbody>", ball + "</worldbody>"),
                   "randomize:\n  domino_0:\n    angular_velocity: {dist: uniform, mean: [0, 6, 0], scale: [0, 1.5, 0]}\n"
                   "  ball:\n    linear_velocity: {dist: uniform, mean: [0, 0, -16], scale: [0, 0, 0.5]}\n")
  bank, episodes = _replayed_episodes(config, 2)
  _check(bank, episodes)  # every touch, none invented, to the step; strengths
  actors = list(bank.event_actors)
  ball_floor = sorted([actors.index("ball"), actors.index("floor")])
  for w in range(bank.n_worlds):
    rows, strength = bank.events.world(w), bank.events.strength[bank.events.offsets[w]:bank.events.offsets[w + 1]]
    k = next(k for k, r in enumerate(rows) if sorted(r[:2]) == ball_floor)
    assert rows[k][3] - rows[k][2] + 1 < bank.events.ticks_per_frame, rows[k]  # shorter than a frame
    assert strength[k, 1] > 0.2 * 15.5, strength[k]  # its impulse stops the ball (and throws it back)
  chain = mwbx.OrderQuery(tuple((f"domino_{k}", f"domino_{k + 1}") for k in range(3)))
  assert mwbx.evaluate(bank, [chain]).all()
  # The last domino stands on the floor until knocked: its first episode's
  # peak is at least its weight (0.05 kg), its impulse its weight times that time.
  pair = sorted([actors.index("domino_3"), actors.index("floor")])
  for w in range(bank.n_worlds):
    rows, strength = bank.events.world(w), bank.events.strength[bank.events.offsets[w]:bank.events.offsets[w + 1]]
    first = next(k for k, r in enumerate(rows) if sorted(r[:2]) == pair)
    assert strength[first, 0] >= 0.05 * 9.81 * 0.99
    knocked = mwbx.queries.event.first_touch(bank, ("domino_2",), ("domino_3",))[w]
    assert strength[first, 1] >= 0.05 * 9.81 * knocked * 0.95, (strength[first], knocked)
  # Refined on MJX from before the ball lands: each child's own hit is found
  # at its steps too (on stored frames it would have no strength, and could
  # fall between two of them), after the restart; the dominoes' episodes
  # before it are the parent's.
  refined = run_refinement(bank, mwbx.RefineRequest(int(bank.world_ids[0]), ("ball",), t_min=0.01, n_samples=4,
                                                    backend="mjx", key=jax.random.key(1))).new
  restart = round(0.01 * bank.record_fps) * bank.events.ticks_per_frame
  for w in range(refined.n_worlds):
    rows = refined.events.world(w)
    strength = refined.events.strength[refined.events.offsets[w]:refined.events.offsets[w + 1]]
    k = next(k for k, r in enumerate(rows) if sorted(r[:2]) == ball_floor)
    assert rows[k][2] >= restart and rows[k][3] - rows[k][2] + 1 < bank.events.ticks_per_frame, rows[k]
    assert np.isfinite(strength).all() and strength[k, 1] > 0.2 * 15.5, strength[k]


def test_mujoco_warp_finds_the_fast_impact_as_native_does(tmp_path):
  """MuJoCo Warp's pooled contacts (each naming its world) give the fast
  impact's episode at the steps native MuJoCo has it, its strength within 1 %."""
  pytest.importorskip("warp")
  warp_bank = mwbx.sample(_config(tmp_path, "fast", FAST_XML, "", impl="warp"), n_worlds=2, key=jax.random.key(0),
                          backend="mjx")
  native = mwbx.sample(_config(tmp_path, "fast", FAST_XML, ""), n_worlds=2, key=jax.random.key(0), backend="native")
  np.testing.assert_array_equal(warp_bank.events.rows, native.events.rows)
  np.testing.assert_allclose(warp_bank.events.strength, native.events.strength, rtol=0.01)


def test_mujoco_warp_finds_a_cloths_touches_as_native_does(tmp_path):
  """A flex's contacts name the flex, not a geom: MuJoCo Warp's cloth over the
  dome touches at the steps native MuJoCo's does. Strengths agree within 15 %:
  the cloth rests on many contacts at once, which the two solvers share out
  differently (the box's one contact agrees within STRENGTH_RTOL)."""
  pytest.importorskip("warp")
  from test_flex_scene import flex_config
  config = flex_config(tmp_path)
  warp_config = config.model_copy(update={"sim": config.sim.model_copy(update={"mjx_impl": "warp"})})
  warp_bank = mwbx.sample(warp_config, n_worlds=2, key=jax.random.key(0), backend="mjx")
  native = mwbx.sample(config, n_worlds=2, key=jax.random.key(0), backend="native")
  cloth_dome = sorted(warp_bank.event_actors.index(a) for a in ("cloth", "dome"))
  assert (warp_bank.events.rows[:, :2] == cloth_dome).all(axis=1).sum() == 2  # one episode a world
  np.testing.assert_array_equal(warp_bank.events.rows, native.events.rows)
  box = np.isin(warp_bank.events.rows[:, :2], warp_bank.event_actors.index("box")).any(axis=1)
  np.testing.assert_allclose(warp_bank.events.strength[box], native.events.strength[box], rtol=STRENGTH_RTOL)
  np.testing.assert_allclose(warp_bank.events.strength[~box], native.events.strength[~box], rtol=0.15)
