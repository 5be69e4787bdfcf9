"""mwbx.search: query gaps, guided proposals and the unattended solve loop.

Scene: tests/refine_scenes/tiny (a sphere dropped onto a resting one, a third
far away, 0.5 s). Goals are region queries on where the spheres end.
"""

import dataclasses
import doctest
import json
import pathlib
import re

import jax
import numpy as np
import optax
import pytest
import scipy.stats

from conftest import load_script
import mwbx
from mwbx import cli as mwbx_cli
from mwbx.queries import Query, query_gaps
from mwbx.search import objects as search_objects
from mwbx.search import proposal as proposal_lib
from mwbx.queries.paths import body_radii
from mwbx.search import solver
from mwbx.search import lexicase as search_lexicase
from mwbx.search import restarts as search_restarts
from mwbx.search.solver import DIVERGENCE_TOLERANCE, KeyStream, settle_time, stream_key

TESTS = pathlib.Path(__file__).parents[1]


@pytest.fixture(scope="module")
def tiny_sampler():
  with mwbx.Sampler(mwbx.load_config(TESTS / "refine_scenes" / "tiny.yaml"), backend="native") as sampler:
    yield sampler


@pytest.fixture(scope="module")
def tiny_bank(tiny_sampler):
  bank, _ = tiny_sampler.run(8, jax.random.key(0))
  return bank


# The striker bounces off the target a little farther than in any of the 8
# sampled worlds (asserted), and the target is not pushed far: refinement
# reaches it (children spread by about 5 mm).
REACHABLE = (
    Query.region((0.114, -0.1, 0.0), (0.125, 0.1, 0.2), bodies="striker", window=(0.5, None), name="striker_band"),
    Query.region((-0.029, -0.1, 0.0), (0.0, 0.1, 0.2), bodies="target", window=(0.5, None), name="target_short"),
)
# The far sphere never moves: nothing can lift it a metre.
UNREACHABLE = REACHABLE[:1] + (
    Query.region((1.0, -1.0, 1.0), (2.0, 1.0, 2.0), bodies="far", window=(0.4, None), name="far_flies"),)


def _reference_gap(bank, query: Query) -> np.ndarray:
  """Plain loops: an include query's gap is the smallest, over window points,
  of the largest distance outside the box's planes."""
  lo, hi = (np.asarray(x) for x in query.world_box)
  body = list(bank.body_names).index(query.bodies[0])
  t0 = query.window[0]
  out = np.zeros(bank.n_worlds)
  for w in range(bank.n_worlds):
    best = np.inf
    for k in range(bank.com.shape[1]):
      if k / bank.query_fps < t0 - 1e-9:
        continue
      p = np.asarray(bank.com[w, k, body], np.float64)
      best = min(best, max(0.0, *(p - hi), *(lo - p)))
    out[w] = best
  return out


def test_gaps_are_zero_exactly_where_queries_are_met(tiny_bank):
  met = mwbx.evaluate_each(tiny_bank, REACHABLE)
  gaps = query_gaps(tiny_bank, REACHABLE)
  assert gaps.shape == met.shape
  assert np.array_equal(gaps == 0, met)
  assert np.all(gaps[~met] >= mwbx.queries.gaps.MIN_GAP)
  for q, query in enumerate(REACHABLE):
    ref = _reference_gap(tiny_bank, query)
    graded = ~met[:, q] & (ref > 0)
    # The float32 plane distances of the kernel against float64 loops.
    np.testing.assert_allclose(gaps[graded, q], ref[graded], atol=1e-6)


def test_exclude_gap_is_depth_inside(tiny_bank):
  # Every world's target starts inside this box: the gap is how deep it goes.
  box = Query.region((-0.2, -0.2, 0.0), (0.2, 0.2, 0.2), bodies="target", sign="exclude", name="keep_out")
  gaps = query_gaps(tiny_bank, [box])[:, 0]
  com = np.asarray(tiny_bank.com[:, :, 1], np.float64)
  depth = np.minimum(com - (-0.2, -0.2, 0.0), (0.2, 0.2, 0.2) - com).min(axis=-1).max(axis=1)
  np.testing.assert_allclose(gaps, depth, atol=1e-6)


def test_unit_noise_reproduces_the_sampler(tiny_sampler, tiny_bank):
  # A world's unit noise from its own key gives the same world bit for bit.
  from mwbx.batch_sim.sampler import world_keys
  _, init_keys, _ = world_keys(jax.random.key(0), np.arange(8))
  noise = jax.vmap(tiny_sampler.scene.unit_noise)(init_keys)
  assert noise.shape == (8, 3)  # the striker's position only
  assert np.all(np.abs(np.asarray(noise)) <= 1.0)
  again, _ = tiny_sampler.run(8, jax.random.key(0), noise=np.asarray(noise))
  for w in range(8):
    np.testing.assert_array_equal(again.qpos_frames(w), tiny_bank.qpos_frames(w))
  with pytest.raises(mwbx.MwbxError, match=r"noise: expected finite f32\[8, 3\]"):
    tiny_sampler.run(8, jax.random.key(0), noise=np.zeros((8, 2)))


def test_initial_proposal_is_the_configured_distribution():
  uniform = np.array([True, False])
  _, z = proposal_lib.draw(proposal_lib.init_proposal(2), jax.random.key(1), 4000)
  u = np.asarray(proposal_lib.unit_from_latent(z, uniform))
  assert scipy.stats.kstest(u[:, 0], "uniform", args=(-1, 2)).pvalue > 1e-3
  assert np.abs(u[:, 0]).max() <= 1.0
  assert scipy.stats.kstest(u[:, 1], "norm").pvalue > 1e-3
  assert np.abs(u[:, 1]).max() <= proposal_lib.NORMAL_CLIP


def test_es_steps_move_the_proposal_toward_better_fitness():
  # Fitness peaks at latent 1.5 in dimension 0 and ignores dimension 1.
  optimizer = optax.adam(0.1)
  proposal = proposal_lib.init_proposal(2)
  state = optimizer.init(proposal)
  for i in range(60):
    eps, z = proposal_lib.draw(proposal, jax.random.key(i), 64)
    fitness = -np.abs(np.asarray(z)[:, 0] - 1.5)
    proposal, state = proposal_lib.es_step(proposal, state, eps, fitness, optimizer)
  mean, scale = np.asarray(proposal.mean), np.exp(np.asarray(proposal.log_scale))
  assert abs(mean[0] - 1.5) < 0.3, mean
  assert scale[0] < 0.5 * scale[1], scale  # narrowed where it matters only
  assert np.all(scale <= 1.0) and np.all(np.abs(mean) <= proposal_lib.MAX_MEAN)


def test_centered_ranks_share_ties():
  r = np.asarray(proposal_lib.centered_ranks(np.array([3.0, 1.0, 3.0, 0.0], np.float32)))
  np.testing.assert_allclose(r, [0.5 - 1 / 6, -0.5 + 1 / 3, 0.5 - 1 / 6, -0.5], atol=1e-6)


def test_guided_sampling_keeps_worlds_plausible_and_recorded(tiny_sampler):
  result = mwbx.search.guided_sample(tiny_sampler, REACHABLE, rounds=2, batch=8, key=jax.random.key(3),
                                     first_world=100)
  bank = result.bank
  assert bank.n_worlds == 16 and list(bank.world_ids) == list(range(100, 116))
  assert [r.worlds for r in result.rounds] == [8, 8]
  assert result.rounds[1].world_steps > 0
  scene = tiny_sampler.scene
  scale = np.asarray(scene.config.randomize["striker"].position.scale)
  start = np.asarray(scene.model.qpos0[:3])
  for world in bank.world_ids:
    noise = np.asarray(bank.lineage[str(int(world))]["proposal"]["noise"], np.float32)
    assert np.all(np.abs(noise) <= 1.0)  # inside the configured range
    qpos, _ = scene.initial_state_from_noise(noise)
    first = bank.qpos_frames(int(world))[0]
    # The stored first frame is the state the noise makes, within the codec's bound.
    np.testing.assert_allclose(first[:3], np.asarray(qpos)[:3], atol=scene.config.codec.e_pos + 1e-6)
    assert np.all(np.abs(first[:2] - start[:2]) <= scale[:2] + scene.config.codec.e_pos + 1e-6)


def test_solve_reaches_a_reachable_goal(tiny_bank):
  assert not mwbx.evaluate(tiny_bank, REACHABLE).any()  # not already solved by sampling
  result = mwbx.solve(tiny_bank, REACHABLE, budget=12, key=jax.random.key(0), samples=16, backend="native")
  assert result.solved, result.message
  assert result.message.startswith("solved: world")
  bank = result.bank
  assert mwbx.evaluate(bank, REACHABLE)[bank.row_of(result.world)]
  # Without event queries the search finds contact events for the children it keeps only: their
  # parent's before the restart, then found on their stored frames (a frame's resolution).
  from mwbx.events import actors_of, detect_events, touch_margin
  model = bank.model
  spf = bank.events.ticks_per_frame
  for world in bank.world_ids[tiny_bank.n_worlds:].tolist():
    restart = int(round(bank.lineage[str(world)]["t_min"] * bank.record_fps)) * spf
    fresh = detect_events(model, actors_of(model, list(bank.objects)), [bank.qpos_frames(world)],
                          touch_margin(bank.config["codec"]["e_pos"])).in_ticks(spf).rows
    stored = bank.events.world(bank.row_of(world))
    after = lambda rows: {tuple(r) for r in rows[rows[:, 2] > restart].tolist()}
    assert after(stored) == after(fresh), world
    parent = bank.events.world(bank.row_of(bank.lineage[str(world)]["parent"]))
    before = lambda rows: {tuple(r) for r in rows[rows[:, 2] < restart, :3].tolist()}
    assert before(stored) == before(parent), world
  # An ordinary refined world: its lineage leads back to a sampled world.
  ancestors = bank.ancestors(result.world)
  assert len(ancestors) >= 1 and ancestors[-1] in tiny_bank.world_ids
  entry = bank.lineage[str(result.world)]
  assert entry["parent"] == ancestors[0] and set(entry["objects"]) <= {"striker", "target"}
  # The far sphere was never asked for and never touched: its stored path is its ancestor's.
  root = int(ancestors[-1])
  far = list(bank.body_names).index("far")
  np.testing.assert_array_equal(bank.com[bank.row_of(result.world), :, far], tiny_bank.com[tiny_bank.row_of(root), :, far])
  steps = result.steps
  assert steps[-1].satisfied == 2 and steps[0].refined == -1
  assert all(a.world_steps <= b.world_steps for a, b in zip(steps, steps[1:]))
  # Each refinement says which queries it aimed at and which try on its world it was.
  names = {q.name for q in REACHABLE}
  refined = [s for s in steps if s.refined >= 0]
  assert refined and all(s.repaired and set(s.repaired) <= names and s.attempt >= 0 for s in refined)
  assert steps[0].repaired == () and steps[0].attempt == -1


def test_solve_out_of_budget_ends_with_the_best_world_and_a_message(tiny_bank):
  result = mwbx.solve(tiny_bank, UNREACHABLE, budget=3, key=jax.random.key(0), samples=8, backend="native")
  assert not result.solved and result.satisfied <= 1
  assert "far_flies" in result.unmet
  assert result.message.startswith("not solved (budget spent; 3 refinements"), result.message
  assert "far_flies" in result.message
  assert result.world in result.bank.world_ids
  with pytest.raises(mwbx.MwbxError, match="solve: not solved"):
    mwbx.solve(tiny_bank, UNREACHABLE, budget=1, samples=4, backend="native", throw=True)
  # What to try, in one paragraph: the blocking query with how many worlds meet it (none), more worlds.
  valid = int(np.asarray(result.bank.valid, bool).sum())
  sampled = int((np.asarray(tiny_bank.parent_world) < 0).sum())
  assert f"Closest: world {result.world} ({result.satisfied} of 2 queries" in result.advice, result.advice
  assert f"far_flies (0 of {valid} worlds)" in result.advice, result.advice
  assert f"--worlds {sampled}" in result.advice and "far_flies: loosen" in result.advice, result.advice
  assert "\n" not in result.advice


def test_solve_refuses_bad_arguments(tiny_bank):
  with pytest.raises(mwbx.MwbxError, match="at least one query"):
    mwbx.solve(tiny_bank, [])
  with pytest.raises(mwbx.MwbxError, match="budget.seconds must be > 0"):
    mwbx.search.Budget(seconds=-1)
  with pytest.raises(mwbx.MwbxError, match="samples, keep and tries_per_world"):
    mwbx.solve(tiny_bank, REACHABLE, samples=0)


def test_solve_takes_its_options_as_one_object_or_by_name(tiny_bank):
  """mwbx.SolveOptions and the same fields by name make the same search:
  the same refinements, worlds, best world and message; options and fields
  together are refused in one line."""
  fields = dict(budget=3, key=jax.random.key(0), samples=8, backend="native")
  options = mwbx.SolveOptions(**fields)
  assert mwbx.SolveOptions is mwbx.search.SolveOptions is solver.SolveOptions and "SolveOptions" in mwbx.__all__
  assert options.budget == mwbx.search.Budget(refinements=3) and options.keep == 4  # an int budget: refinements
  by_name = mwbx.solve(tiny_bank, UNREACHABLE, **fields)
  as_one = mwbx.solve(tiny_bank, UNREACHABLE, options)
  assert by_name.bank.world_ids.tolist() == as_one.bank.world_ids.tolist()
  assert by_name.bank.parent_world.tolist() == as_one.bank.parent_world.tolist()
  assert (by_name.world, by_name.satisfied, by_name.solved, by_name.unmet) == (
      as_one.world, as_one.satisfied, as_one.solved, as_one.unmet)
  refined = [s for s in as_one.steps if s.refined >= 0]
  assert as_one.steps[-1].refinements == by_name.steps[-1].refinements == len(refined) == 3

  def path(result):  # every step but its wall time
    return [(s.refinements, s.world_steps, s.satisfied, s.world, s.refined, s.objects, s.repaired, s.attempt,
             s.places) for s in result.steps]

  assert path(by_name) == path(as_one)
  np.testing.assert_array_equal([s.t_min for s in by_name.steps], [s.t_min for s in as_one.steps])
  seconds = re.compile(r"\d+ s\)")
  assert seconds.sub("", by_name.message) == seconds.sub("", as_one.message)
  with pytest.raises(TypeError, match=r"^solve: give options or its fields \(samples\), not both$") as refused:
    mwbx.solve(tiny_bank, UNREACHABLE, options, samples=4)
  assert "\n" not in str(refused.value)
  with pytest.raises(TypeError, match="unexpected keyword argument 'sample'"):
    mwbx.solve(tiny_bank, UNREACHABLE, sample=4)
  with pytest.raises(mwbx.MwbxError, match=r"samples, keep and tries_per_world must be >= 1, got 32, 0, 4"):
    mwbx.SolveOptions(keep=0)


QUERY_FILE = """\
queries:
  - name: striker_band
    region: {min: [0.114, -0.1, 0.0], max: [0.125, 0.1, 0.2]}
    bodies: [striker]
    window: [0.5, null]
  - name: target_short
    region: {min: [-0.029, -0.1, 0.0], max: [0.0, 0.1, 0.2]}
    bodies: [target]
    window: [0.5, null]
"""


def test_cli_solve_writes_the_bank_and_its_progress(tiny_bank, tmp_path, capsys):
  from mwbx import cli
  bank_dir = tmp_path / "tiny"
  tiny_bank.save(bank_dir)
  queries = tmp_path / "goal.yaml"
  queries.write_text(QUERY_FILE)
  code = cli.main(["solve", str(bank_dir), str(queries), "--budget", "12", "--samples", "16",
                   "--backend", "native"])
  captured = capsys.readouterr()
  out = captured.out
  assert code == 0, out
  assert "solved: world" in out and "lineage" in out
  world = int(out.split("solved: world ")[1].split()[0])
  # The progress lines say how far the best world is (the last: all met).
  solving = [line for line in captured.err.splitlines() if "solving" in line]
  assert solving[-1].endswith(f"; best world {world}: 2 of 2 met"), captured.err
  saved = mwbx.Bank.load(bank_dir)
  goal = mwbx.load_queries(queries, bank=saved)
  assert mwbx.evaluate(saved, goal)[saved.row_of(world)]
  assert (tmp_path / "tiny-solve.png").stat().st_size > 1000
  history = json.loads((tmp_path / "tiny-solve.json").read_text())
  assert history["solved"] and history["steps"][-1]["satisfied"] == 2
  assert all(step["repaired"] for step in history["steps"] if step["refined"] >= 0)  # what each refinement aimed at
  # A goal out of reach: exit status 1 with the message, the bank still written.
  far = tmp_path / "far.yaml"
  far.write_text(QUERY_FILE + "  - name: far_flies\n    region: {min: [1, -1, 1], max: [2, 1, 2]}\n"
                 "    bodies: [far]\n")
  code = cli.main(["solve", str(bank_dir), str(far), "--budget", "2", "--samples", "4", "--backend", "native",
                   "--out", str(tmp_path / "far_bank")])
  captured = capsys.readouterr()
  assert code == 1
  assert "not solved (budget spent; 2 refinements" in captured.out and "far_flies" in captured.out
  assert mwbx.Bank.load(tmp_path / "far_bank").n_worlds > tiny_bank.n_worlds


def test_solve_with_guided_rounds_adds_guided_worlds_first(tiny_bank):
  result = mwbx.solve(tiny_bank, UNREACHABLE, budget=1, samples=4, backend="native", guided_rounds=1,
                      guided_batch=8, key=jax.random.key(2))
  bank = result.bank
  guided = [i for i in bank.world_ids if "proposal" in bank.lineage.get(str(int(i)), {})]
  assert len(guided) == 8 and min(guided) == tiny_bank.next_world_id
  assert result.steps[0].world_steps > 0  # the guided worlds' steps count against the budget
  assert not result.solved and "far_flies" in result.message


def test_a_stall_reseeds_with_worlds_guided_at_the_blocking_query(tiny_bank):
  # Out of reach for the striker: the search stalls at once (patience 1) and
  # guided sampling aimed at the query adds worlds to the bank.
  far = Query.region((1.0, -1.0, 0.0), (2.0, 1.0, 0.5), bodies="striker", window=(0.5, None), name="striker_far")
  result = mwbx.solve(tiny_bank, [far], budget=3, samples=2, backend="native", patience=1, reseed_rounds=1,
                      guided_batch=4, key=jax.random.key(3))
  bank = result.bank
  guided = [i for i in bank.world_ids if "proposal" in bank.lineage.get(str(int(i)), {})]
  assert len(guided) >= 4 and len(guided) % 4 == 0
  assert not result.solved and result.unmet == ("striker_far",)


def test_search_key_streams_never_share_a_key():
  # The old scheme folded 2 + r (reseeding) and 1000 + r (refinement) into one
  # key: reseeding at refinement 998 drew refinement 0's key.
  key = jax.random.key(7)
  drawn = {(stream, i): tuple(np.asarray(jax.random.key_data(stream_key(key, stream, i))).tolist())
           for stream in KeyStream for i in range(1001)}
  assert len(set(drawn.values())) == len(drawn)
  # Each stream is the search key's: another key gives other draws.
  other = stream_key(jax.random.key(8), KeyStream.REFINE, 0)
  assert not np.array_equal(jax.random.key_data(other), jax.random.key_data(stream_key(key, KeyStream.REFINE, 0)))


def test_settle_time_is_when_the_bodies_stay_near_where_they_end(tiny_bank):
  """settle_time against a frame-by-frame reading of the stored path: from
  that frame on every chosen body stays within the tolerance of its last
  point, and at the frame before it one does not."""
  names = list(tiny_bank.body_names)
  moved = 0
  for row in range(tiny_bank.n_worlds):
    for chosen in (["striker"], ["target"], ["striker", "target"]):
      bodies = np.isin(names, chosen)
      t = settle_time(tiny_bank, row, bodies)
      frame = round(t * tiny_bank.query_fps)
      com = np.asarray(tiny_bank.com[row], np.float64)[:, bodies]
      radius = body_radii(tiny_bank.model, np.asarray(tiny_bank.body_ids)[bodies])
      near = (np.linalg.norm(com - com[-1], axis=-1) <= DIVERGENCE_TOLERANCE * radius + 1e-6).all(axis=-1)
      assert near[frame:].all(), (row, chosen, t)
      if frame > 0:
        moved += 1
        assert not near[frame - 1], (row, chosen, t)
  assert moved > 0  # the striker moves in every world: some settle time is after the start


def _lexicase_reference(met, order, score):
  """Lexicase selection as its papers state it, with sets: the worlds meeting
  each query in turn survive, unless none does."""
  alive = set(range(len(met)))
  for q in order:
    meeting = {w for w in alive if met[w][q]}
    alive = meeting or alive
  return max(sorted(alive), key=lambda w: score[w])


def test_lexicase_agrees_with_the_set_reference_and_picks_every_specialist():
  rng = np.random.default_rng(0)
  for _ in range(200):
    n, q = rng.integers(1, 9), rng.integers(1, 7)
    met = rng.random((n, q)) < 0.4
    score = rng.permutation(n).astype(float)  # distinct: one world left
    order = rng.permutation(q)
    assert search_lexicase.lexicase(met, order, score) == _lexicase_reference(met.tolist(), order, score)
  # World 0 meets most; world 1 alone meets query 3; world 2 meets a subset of world 0's: never picked.
  met = np.array([[1, 1, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]], bool)
  picks = {search_lexicase.lexicase(met, search_lexicase.query_order(np.ones(4, bool), rng), np.zeros(3))
           for _ in range(200)}
  assert picks == {0, 1}
  with pytest.raises(ValueError, match="no candidate"):
    search_lexicase.lexicase(np.zeros((0, 2), bool), np.arange(2), np.zeros(0))


def test_lexicase_orders_put_places_first_and_keep_picks_distinct():
  rng = np.random.default_rng(1)
  places = np.array([False, True, False, True, True])
  for _ in range(50):
    order = search_lexicase.query_order(places, rng)
    assert sorted(order) == list(range(5)) and set(order[:3]) == {1, 3, 4}
  assert search_lexicase.first_unmet(np.array([1, 0, 1, 0, 0], bool), np.array([4, 3, 0, 1, 2])) == [4, 3, 1]
  met = np.array([[1, 0], [1, 0], [0, 1], [0, 0]], bool)
  score = np.array([0.0, 1.0, 0.0, 5.0])
  kept = search_lexicase.lexicase_keep(met, score, 3, [np.array([0, 1])] * 5)
  # The best meeting query 0 (world 1, by score), then world 0, then the one meeting query 1.
  assert list(kept) == [1, 0, 2]
  assert list(search_lexicase.lexicase_keep(met, score, 9, [np.array([1, 0])] * 2)) == [2, 1]


def test_restart_arms_learn_the_arm_that_gains_per_goal():
  """Thompson sampling: an arm that gains is drawn more, for its goal only;
  arms repairing two queries are drawn only where two are unmet."""
  arms = search_restarts.RestartArms()
  rng = np.random.default_rng(2)
  late_single = search_restarts.ARMS.index(search_restarts.RestartArm(0.9, 1))
  for _ in range(40):
    arm = arms.draw("place", max_group=2, rng=rng)
    arms.record("place", arm, gained=(arm == late_single))
  draws = [arms.draw("place", max_group=2, rng=rng) for _ in range(200)]
  assert np.mean(np.equal(draws, late_single)) > 0.5
  assert arms.rates("place")[late_single] == arms.rates("place").max()
  np.testing.assert_array_equal(arms.rates("pose"), 0.5)  # poses learn apart: nothing yet
  singles = {arms.draw("pose", max_group=1, rng=rng) for _ in range(200)}
  assert {search_restarts.ARMS[a].group for a in singles} == {1} and len(singles) == len(search_restarts.FRACTIONS)
  assert all(0 < f < 1 for f in search_restarts.FRACTIONS)


def test_places_rank_before_poses():
  """A world with more places met ranks above one with more queries met in
  all (SIGGRAPH: letters in their slots beat letters upright elsewhere);
  among equal places, the fitness of every query, then the tie metric."""
  place = Query.region((0, 0, 0), (1, 1, 1), bodies="striker", name="place")
  pose = mwbx.OrientationQuery(bodies="striker", within_deg=20, axis="z", name="pose")
  np.testing.assert_array_equal(solver.place_queries([place, pose, place, pose]), [True, False, True, False])
  np.testing.assert_array_equal(solver.place_queries([pose, pose]), [True, True])  # poses only: all rank alike
  search = object.__new__(solver._Search)
  search.places = solver.place_queries([place, place, pose, pose, pose])
  search.scale = np.ones(5)
  gaps = np.array([
      [0.0, 0.0, 0.0, 0.0, 0.0],  # 0: everything
      [0.0, 5.0, 0.0, 0.0, 0.0],  # 1: one place short, every pose: 4 met
      [0.0, 0.0, 5.0, 5.0, 5.0],  # 2: every place, no pose: 2 met
      [0.0, 0.0, 1.0, 5.0, 5.0],  # 3: as 2, nearer a pose
      [0.0, 0.0, 1.0, 5.0, 5.0],  # 4: as 3, fewer collisions
  ])
  ties = np.array([0.0, 0.0, 0.0, 3.0, 1.0])
  assert list(search.rank_order(gaps, ties)) == [0, 4, 3, 2, 1]
  score = solver.nearness(gaps, ties, search.scale)
  assert score[4] > score[3] > score[2]  # among equals (worlds 2-4 meet the same): nearer, then fewer collisions


def test_solve_records_and_reports_the_places_its_best_world_meets(tiny_bank, tmp_path):
  pose = mwbx.OrientationQuery(bodies="striker", within_deg=20, axis="z", name="striker_up")
  queries = [REACHABLE[0], pose, REACHABLE[1]]
  notes = []
  result = mwbx.solve(tiny_bank, queries, budget=2, key=jax.random.key(0), samples=4, backend="native",
                      progress=lambda p: notes.append(p.note))
  met = mwbx.evaluate_each(result.bank, queries)
  for step in result.steps:
    row = result.bank.row_of(step.world)
    assert step.places == met[row, [0, 2]].sum() and step.satisfied == met[row].sum()
    if step.refined >= 0:  # the restart arm it drew, as a fraction of when its objects go wrong
      assert step.fraction in search_restarts.FRACTIONS and isinstance(step.gained, bool)
  assert notes and all(note.endswith(" of 2 places)") for note in notes)
  png = mwbx.search.progress_plot(result.steps, tmp_path / "solve.png")
  assert pathlib.Path(png).stat().st_size > 0


def test_refinement_yield_counts_each_refinement_once_by_its_parent(tiny_bank):
  """scripts/refinement_yield.py (where a search's refinements paid) against
  the search's own record: every refinement that kept children is counted
  once, under what its parent met, and the solved world's line improved."""
  script = load_script("refinement_yield")
  result = mwbx.solve(tiny_bank, REACHABLE, budget=12, key=jax.random.key(0), samples=16, backend="native")
  out = script.refinement_yield(result.bank, REACHABLE)
  refined = {(s.refined, round(s.t_min, 6), s.objects) for s in result.steps if s.refined >= 0}
  counted = sum(n for n, _ in out["by_parent_met"].values())
  assert counted == sum(n for n, _ in out["by_objects"].values()) == out["active"].size
  assert counted == sum(n for n, _ in out["by_restart"].values())
  assert all(t0 < t1 for t0, t1 in out["by_restart"])
  assert 1 <= counted <= len(refined)
  assert set(out["by_parent_met"]) <= {0, 1} and set(out["by_objects"]) <= {1, 2}
  assert all(0 <= better <= n for n, better in out["by_parent_met"].values())
  assert sum(better for _, better in out["by_parent_met"].values()) >= 1  # it went from < 2 met to 2
  assert (out["active"] >= 1).all()


def test_restart_probe_reports_what_each_restart_time_gains_loses_and_activates(tiny_bank):
  """scripts/restart_probe.py: the striker refined before it hits the target
  activates the target in every child and never the far sphere; the refined
  object is active from its restart frame; a query the world meets can only
  be lost, one it does not only gained."""
  script = load_script("restart_probe")
  world = int(tiny_bank.world_ids[0])
  parent = mwbx.evaluate_each(tiny_bank, REACHABLE)[0]
  fps = tiny_bank.record_fps
  for t_min in (0.05, 0.4):
    row = script.probe(tiny_bank, REACHABLE, world, ["striker"], t_min, 8, jax.random.key(3), backend="native")
    assert row["t_min"] == t_min and 1 <= row["valid"] <= 8
    assert row["parent_met"] == int(parent.sum())
    assert 0 <= row["mean_met"] <= row["best_met"] <= len(REACHABLE) and 0 <= row["better"] <= row["valid"]
    names = [q.name for q in REACHABLE]
    assert all(not parent[names.index(n)] and 1 <= k <= row["valid"] for n, k in row["gained"].items())
    assert all(parent[names.index(n)] and 1 <= k <= row["valid"] for n, k in row["lost"].items())
    count, at = row["activated"]["striker"]
    assert count == row["valid"] and at == pytest.approx(np.floor(t_min * fps) / fps)
    assert "far" not in row["activated"] and 1 <= row["active_mean"] <= 2
    if t_min == 0.05:  # it falls onto the target after 0.2 s
      assert row["activated"]["target"][0] == row["valid"] and row["activated"]["target"][1] > t_min


def test_a_mode_any_repair_leaves_alone_the_object_holding_another_query(tiny_bank):
  """Either G may fill either G slot on SIGGRAPH: repairing one G slot must
  not move the G that alone fills the other. Here: query 0 (mode any over
  striker and target) is met by the target alone, query 1 (the same bodies)
  by neither, so repairing query 1 refines the striker only, its restart
  judged by the striker's own variant of query 1."""
  end = np.asarray(tiny_bank.com)[0, int(tiny_bank.com_count[0]) - 1]
  names = list(tiny_bank.body_names)
  target, striker = end[names.index("target")], end[names.index("striker")]
  assert np.linalg.norm(target - striker) > 0.02  # boxes around one miss the other
  around_target = Query.region(target - 0.01, target + 0.01, bodies=["striker", "target"], mode="any", name="t")
  nowhere = Query.region((5.0, 5.0, 5.0), (6.0, 6.0, 6.0), bodies=["striker", "target"], mode="any", name="n")
  variants = nowhere.per_object(tiny_bank)
  assert sorted(variants) == ["striker", "target"]
  assert variants["striker"].bodies == ("body:striker",) and variants["striker"].mode == "any"
  assert REACHABLE[0].per_object(tiny_bank) == {}  # one object: nothing to choose
  assert dataclasses.replace(nowhere, sign="exclude").per_object(tiny_bank) == {}
  search = solver._Search(tiny_bank, [around_target, nowhere], solver.SolveOptions(budget=1, backend="native"), None)
  assert search.met[0, 0] and not search.met[0, 1]
  objects, query, met = search.repair_target(0, 1)
  assert objects == ["striker"] and query.bodies == ("body:striker",)
  np.testing.assert_array_equal(met, query_gaps(tiny_bank, [variants["striker"]])[:, 0] == 0)
  # Repairing query 0: no other query is held by one object alone, so both may move.
  objects, query, _ = search.repair_target(0, 0)
  assert sorted(objects) == ["striker", "target"] and query is around_target
  # With both bodies inside query 0's box, either may move: both stay spare.
  both = Query.region(np.minimum(target, striker) - 0.01, np.maximum(target, striker) + 0.01,
                      bodies=["striker", "target"], mode="any", name="b")
  search = solver._Search(tiny_bank, [both, nowhere], solver.SolveOptions(budget=1, backend="native"), None)
  assert sorted(search.repair_target(0, 1)[0]) == ["striker", "target"]


def test_search_docstring_examples_run():
  for module in (search_objects, search_lexicase):
    failed, tried = doctest.testmod(module, optionflags=doctest.ELLIPSIS)[:2]
    assert tried >= 1 and failed == 0, module.__name__


@pytest.mark.parametrize("flags, expected", [
    ([], (100, None, None)),
    (["--time-budget", "600"], (None, 600.0, None)),  # the README's command: the time is the limit
    (["--step-budget", "1e6"], (None, None, 1_000_000)),
    (["--budget", "7", "--time-budget", "60"], (7, 60.0, None)),
])
def test_a_time_budget_alone_is_not_cut_short_by_a_refinement_count(flags, expected):
  args = mwbx_cli.build_parser().parse_args(["solve", "BANK", "Q.yaml", *flags])
  budget = mwbx_cli._solve_budget(args, solver.Budget)
  assert (budget.refinements, budget.seconds, budget.world_steps) == expected
