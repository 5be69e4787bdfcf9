"""Contact budgets of the batched engines: the pilot, the budgeted MJX step
and MuJoCo Warp against MuJoCo C, and the overflow flag (never silent)."""

import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import mwbx
from mwbx.batch_sim import contact_budget, mjx_collision
from mwbx.batch_sim import sampler as sampler_lib

TESTS = pathlib.Path(__file__).parents[1]
PILE = TESTS / "scenes" / "contact_pile.yaml"

# A settling pile (3 stacked boxes, 4 balls, 16 contacts at rest) over 300
# steps (0.625 s): MJX in float32 and MuJoCo C in float64 agree on every free
# body's position to this many metres at every step, and on its orientation
# to this angle (radians), under the pilot's budget (26 of MJX's 46 dense
# contact slots).
_POSITION_TOLERANCE = 3e-3
_ROTATION_TOLERANCE = 0.03
_STEPS = 300


@pytest.fixture(scope="module")
def pile():
  return mwbx.Scene(mwbx.load_config(PILE))


@pytest.fixture(scope="module")
def pile_budget(pile):
  return sampler_lib.resolve_contact_budget(pile)


def _reference(model):
  """qpos f64[T, nq] of MuJoCo C and the steps with at least 12 contacts."""
  data = mujoco.MjData(model)
  qpos, crowded = [], 0
  for _ in range(_STEPS):
    mujoco.mj_step(model, data)
    qpos.append(data.qpos.copy())
    crowded += data.ncon >= 12
  return np.array(qpos), crowded


def _assert_agrees(model, qpos, reference):
  free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
  assert len(free) == 7
  for j in free:
    a = model.jnt_qposadr[j]
    np.testing.assert_allclose(qpos[:, a:a + 3], reference[:, a:a + 3], atol=_POSITION_TOLERANCE)
    q, r = qpos[:, a + 3:a + 7], reference[:, a + 3:a + 7]
    cos_half = np.abs(np.sum(q * r, axis=1)) / np.linalg.norm(q, axis=1) / np.linalg.norm(r, axis=1)
    assert (2 * np.arccos(np.clip(cos_half, 0, 1))).max() < _ROTATION_TOLERANCE, j


def test_pilot_sizes_a_budget_with_headroom(pile, pile_budget):
  counts = sampler_lib.pilot_counts(pile, n_worlds=2)
  assert counts.contacts >= 16 and counts.frames > 100  # the pile at rest has 16 contacts
  budget = contact_budget.budget_from_counts(counts, 1.5)
  assert budget.max_contact_points >= 1.5 * counts.contact_points
  assert budget.max_geom_pairs >= 1.5 * counts.geom_pairs
  assert budget.nconmax >= 1.5 * counts.contacts and budget.njmax >= 1.5 * counts.rows
  assert "pilot (2 worlds" in budget.source
  # Config values win and are named.
  fixed = contact_budget.budget_from_counts(counts, 1.5, {"max_geom_pairs": 3})
  assert fixed.max_geom_pairs == 3 and fixed.source.startswith("config (max_geom_pairs) + pilot")
  assert pile_budget.source.startswith("pilot (8 worlds")
  # A config giving every value runs no pilot.
  given = mwbx.config.MjxSection(max_contact_points=5, max_geom_pairs=2, nconmax=9, njmax=30)
  assert sampler_lib.resolve_contact_budget(pile, given) == contact_budget.ContactBudget(5, 2, 9, 30, "config")


def test_budgeted_mjx_step_matches_mujoco_c(pile, pile_budget):
  reference, crowded = _reference(pile.model)
  assert crowded >= 200  # contact-rich for most of the horizon
  model = contact_budget.budgeted_model(pile, pile_budget)
  dense = mjx.make_data(pile.model, impl="jax")._impl.contact.dist.shape[0]
  budgeted = mjx.make_data(model, impl="jax")._impl.contact.dist.shape[0]
  assert budgeted < dense, (budgeted, dense)  # the budget binds (26 of 46 slots)
  mx = mjx.put_model(model, impl="jax")
  check = contact_budget.JaxOverflowCheck(model)
  assert check.can_overflow

  def rollout(d):
    def step(d, _):
      d = mjx_collision.step(mx, d)
      return d, (d.qpos, check(d))
    return jax.lax.scan(step, d, None, length=_STEPS)[1]

  qpos, overflow = jax.jit(rollout)(mjx.make_data(model, impl="jax"))
  assert not np.asarray(overflow).any()
  _assert_agrees(model, np.asarray(qpos), reference)


def test_mjx_warp_step_matches_mujoco_c(pile, pile_budget):
  pytest.importorskip("warp")
  from mwbx.batch_sim.mjx_backend import MjxBackend
  reference, _ = _reference(pile.model)
  backend = MjxBackend(pile.model, "warp", budget=pile_budget)
  m = pile.model
  d0 = backend.make_data(jnp.asarray(m.qpos0, jnp.float32)[None], jnp.zeros((1, m.nv), jnp.float32))

  def rollout(d):
    def step(d, _):
      d = backend.step(d, jnp.zeros((1, m.nbody, 6), jnp.float32))
      return d, (d.qpos[0], backend.overflow(d)[0])
    return jax.lax.scan(step, d, None, length=_STEPS)[1]

  qpos, overflow = jax.jit(rollout)(d0)
  assert not np.asarray(overflow).any()
  _assert_agrees(m, np.asarray(qpos), reference)


def test_mujoco_warp_overflow_flags_the_worlds_over_budget(pile):
  """MuJoCo Warp with pools too small for the pile (4 contacts, 16 rows per
  world): its overflow counters flag every world."""
  pytest.importorskip("warp")
  from mwbx.batch_sim.mjx_backend import MjxBackend
  m = pile.model
  backend = MjxBackend(m, "warp", budget=contact_budget.ContactBudget(4, 2, 4, 16, "test"))
  d = backend.make_data(jnp.tile(jnp.asarray(m.qpos0, jnp.float32), (2, 1)), jnp.zeros((2, m.nv), jnp.float32))

  def rollout(d):
    def step(d, _):
      d = backend.step(d, jnp.zeros((2, m.nbody, 6), jnp.float32))
      return d, backend.overflow(d)
    return jax.lax.scan(step, d, None, length=60)[1]

  overflow = np.asarray(jax.jit(rollout)(d))  # bool[T, W]
  assert overflow[-1].all()  # (under the pilot's budget none is: test_mjx_warp_step_matches_mujoco_c)


def _pile_states(model, n: int, seed: int = 0) -> np.ndarray:
  """f64[n, nq] states of the pile: MuJoCo C runs from jittered starts, sampled every 7 steps."""
  rng = np.random.default_rng(seed)
  data = mujoco.MjData(model)
  out = []
  while len(out) < n:
    mujoco.mj_resetData(model, data)
    for j in range(model.njnt):
      a = model.jnt_qposadr[j]
      data.qpos[a:a + 2] += rng.uniform(-0.04, 0.04, 2)
    for k in range(140):
      mujoco.mj_step(model, data)
      if k % 7 == 6:
        out.append(data.qpos.copy())
  return np.array(out[:n])


@pytest.mark.parametrize("caps", [(2, 64), (64, 6), (3, 10)])
def test_overflow_flag_never_misses_a_dropped_contact(pile, caps):
  """Budgeted MJX against dense MJX on the same states: wherever the budget
  dropped an active contact (fewer active contacts kept than the dense step
  has), the world is flagged; and the flag is not raised everywhere."""
  pairs, points = caps
  budget = contact_budget.ContactBudget(points, pairs, 0, 0, "test")
  small = contact_budget.budgeted_model(pile, budget)
  check = contact_budget.JaxOverflowCheck(small)
  states = jnp.asarray(_pile_states(pile.model, 96), jnp.float32)

  def active(m):
    mx, d0 = mjx.put_model(m, impl="jax"), mjx.make_data(m, impl="jax")

    def one(q):
      d = mjx_collision.forward(mx, d0.replace(qpos=q))
      c = d._impl.contact
      return jnp.sum(c.dist < c.includemargin), check(d) if m is small else False
    return jax.jit(jax.vmap(one))(states)

  dense, _ = active(pile.model)
  kept, flagged = (np.asarray(x) for x in active(small))
  dropped = kept < np.asarray(dense)
  assert dropped.any()  # the caps bite on some states ...
  assert not (dropped & ~flagged).any()  # ... and every state that lost a contact is flagged
  assert not flagged.all()  # states that lost none mostly pass


def test_too_small_budget_flags_every_world_and_keeps_it_out_of_matches():
  config = mwbx.load_config(PILE)
  sim = config.sim.model_copy(update={"mjx": mwbx.config.MjxSection(
      max_contact_points=4, max_geom_pairs=2, nconmax=4, njmax=16), "end_time": 0.25})
  config = config.model_copy(update={"sim": sim})
  with mwbx.Sampler(config, backend="mjx", chunk_size=8) as sampler:
    assert sampler.contact_budget.source == "config"
    bank, _ = sampler.run(8, jax.random.key(0))
  flagged = (bank.flags & mwbx.FLAG_CONTACT_OVERFLOW) != 0
  assert flagged.all()  # the pile needs 16 contacts from its first frames
  assert not bank.valid.any()
  summary = bank.summary()
  assert summary["contact_overflow"] == 8 and summary["unstable"] == 0 and summary["valid"] == 0
  assert bank.run["contact_budget"]["max_contact_points"] == 4


def test_config_rejects_a_bad_budget(tmp_path):
  path = tmp_path / "bad.yaml"
  path.write_text(PILE.read_text().replace("sim: {", "sim: {mjx: {max_contact_points: 0}, "))
  with pytest.raises(mwbx.MwbxError, match=r"sim\.mjx\.max_contact_points"):
    mwbx.load_config(path)


def test_info_prints_the_budget_and_counts_flagged_worlds(tiny_native_bank, tmp_path, capsys):
  import dataclasses
  from mwbx import cli
  flags = tiny_native_bank.flags.copy()
  flags[:3] |= mwbx.FLAG_CONTACT_OVERFLOW
  budget = contact_budget.ContactBudget(12, 5, 13, 42, "pilot (8 worlds, 755 frames, headroom 1.5)")
  bank = dataclasses.replace(tiny_native_bank, flags=flags,
                             run={**tiny_native_bank.run, "contact_budget": budget._asdict()})
  assert bank.summary()["contact_overflow"] == 3 and bank.summary()["unstable"] == 0
  bank.save(tmp_path / "bank")
  assert cli.main(["info", str(tmp_path / "bank")]) == 0
  out = capsys.readouterr().out
  assert f"({bank.n_worlds - 3} valid, 0 unstable, 3 over the contact budget)" in out
  assert "contact budget      max_contact_points 12, max_geom_pairs 5 (jax); nconmax 13, njmax 42" in out
  assert "from pilot (8 worlds, 755 frames, headroom 1.5)" in out


def test_awake_dofs_size_nvmax_with_headroom_and_old_records_load():
  """MuJoCo Warp's nvmax: the pilot's most dofs awake at once with headroom
  and slack, never above nv; none (0) where the pilot did not sleep; a run
  record from before nvmax loads with 0."""
  counts = contact_budget.PilotCounts(3, 8, 5, 4, 20, worlds=8, frames=100, awake_dofs=30, dofs=600)
  assert contact_budget.budget_from_counts(counts, 1.5).nvmax == 45
  assert contact_budget.budget_from_counts(counts._replace(awake_dofs=590), 1.5).nvmax == 600
  assert contact_budget.budget_from_counts(counts._replace(awake_dofs=0), 1.5).nvmax == 0
  budget = contact_budget.budget_from_counts(counts, 1.5)
  assert "nvmax 45" in budget.describe()
  record = budget._asdict()
  assert contact_budget.ContactBudget.from_dict(record) == budget
  del record["nvmax"]
  assert contact_budget.ContactBudget.from_dict(record).nvmax == 0


def test_awake_dofs_counts_what_a_hit_wakes():
  """Two boxes resting asleep from the start and a ball rolling into the
  first: the most dofs awake at once are the ball's and the box's it wakes
  (6 + 6), never the far box's."""
  mjcf = ('<mujoco><option timestep="0.002"><flag sleep="enable"/></option><worldbody>'
          '<geom type="plane" size="3 3 0.1"/>'
          '<body name="near" pos="0.3 0 0.05" sleep="init"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>'
          '<body name="far" pos="2 2 0.05" sleep="init"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>'
          '<body name="ball" pos="0 0 0.05"><freejoint/><geom type="sphere" size="0.05"/></body>'
          '</worldbody></mujoco>')
  model = mujoco.MjModel.from_xml_string(mjcf)
  qvel = np.zeros((1, model.nv))
  qvel[0, 12] = 2.0  # the ball rolls towards the near box
  assert contact_budget.awake_dofs(model, model.qpos0[None], qvel, 400) == 12
