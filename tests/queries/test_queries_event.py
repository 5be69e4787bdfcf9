"""Contact events and event queries, against references built here: a scene
whose order of events is known from free fall, and MuJoCo's own contact list
at every stored frame of the same stored worlds (queries answered by brute
force over per-frame sets of touching pairs)."""

import json
import logging
import math
import warnings
import zlib

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.errors import MwbxError
from mwbx.progress import NOTICE
from mwbx.events import actors_of, touch_margin
from mwbx.events.record import EVENTS_VERSION, STRENGTH_RELATIVE_ERROR
from mwbx.batch_sim.sampler import world_keys
from mwbx.search.solver import place_queries
from conftest import REPO
from event_scenes import FAST_XML, domino_row_xml

DROP_XML = """
<mujoco>
  <option timestep="0.00208333333333"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    <geom name="pad" type="box" pos="1 0 0.2" size="0.2 0.2 0.2"/>
    <geom type="box" pos="-2 0 0.05" size="0.05 0.05 0.05"/>
    <body name="low" pos="0 0 0.6"><freejoint/><geom type="sphere" size="0.05" mass="0.1"/></body>
    <body name="high" pos="0.5 0 1.1"><freejoint/><geom type="sphere" size="0.05" mass="0.1"/></body>
    <body name="onpad" pos="1 0 1.2"><freejoint/><geom type="sphere" size="0.05" mass="0.1"/></body>
  </worldbody>
</mujoco>
"""
G = 9.81


@pytest.fixture(scope="module")
def drop_bank(tmp_path_factory):
  folder = tmp_path_factory.mktemp("drop")
  (folder / "drop.xml").write_text(DROP_XML)
  (folder / "drop.yaml").write_text("scene: {mjcf: drop.xml, groups: {balls: [low, high]}}\nsim: {end_time: 1.0}\n")
  return mwbx.sample(mwbx.load_config(folder / "drop.yaml"), n_worlds=4, key=jax.random.key(0), backend="native")


@pytest.fixture(scope="module")
def quick_bank(quickstart_config):
  return mwbx.sample(quickstart_config, n_worlds=8, key=jax.random.key(3), backend="native")


def test_free_fall_gives_the_known_order_of_events(drop_bank):
  bank = drop_bank
  assert bank.event_actors == ("low", "high", "onpad", "floor", "pad", "world")
  fps = bank.record_fps
  # A sphere of radius r dropped from height z touches the floor after sqrt(2 (z - r) / g) s,
  # within the touch margin (2 mm) and a frame.
  for ball, z, other, top in (("low", 0.6, "floor", 0.0), ("high", 1.1, "floor", 0.0), ("onpad", 1.2, "pad", 0.4)):
    t = mwbx.queries.event.first_touch(bank, (ball,), (other,))
    expected = math.sqrt(2 * (z - 0.05 - top) / G)
    assert np.all(np.abs(t - expected) <= 1.5 / fps + math.sqrt(2 * 0.002 / G)), (ball, t, expected)
  order = mwbx.OrderQuery([("low", "floor"), ("onpad", "pad"), ("high", "floor")])
  backwards = mwbx.OrderQuery([("high", "floor"), ("low", "floor")])
  apart = mwbx.TouchQuery("balls", "onpad")
  unnamed = mwbx.TouchQuery(["low", "high", "onpad"], "world")
  early = mwbx.TouchQuery("low", "floor", window=(0.0, 0.2))
  each = mwbx.evaluate_each(bank, [order, backwards, apart, unnamed, early])
  assert each[:, 0].all() and not each[:, 1:].any()
  assert not mwbx.evaluate_each(bank, [mwbx.TouchQuery("high", "floor", sign="exclude")]).any()


def unperturbed(config):
  """``config`` with perturbations off: a world is then MuJoCo's plain steps
  from its initial state, which a reference can replay."""
  return config.model_copy(update={"perturb": config.perturb.model_copy(update={"enabled": False})})


def sample_unperturbed(config, n_worlds, seed=0):
  config = unperturbed(config)
  bank = mwbx.sample(config, n_worlds=n_worlds, key=jax.random.key(seed), backend="native")
  with mwbx.Sampler(config, backend="native") as sampler:
    _, init_keys, _ = world_keys(jax.random.key(seed), np.arange(n_worlds))
    qpos0, qvel0 = (np.asarray(x) for x in sampler._init(init_keys))
  return bank, qpos0, qvel0


def _reference_episodes(bank, qpos0, qvel0, row, held_ticks=None) -> set:
  """The episodes of a world replayed step by step with ``mj_step``:
  MuJoCo's contacts not in their gap, runs of steps broken by a frame's
  steps apart, each with its largest summed normal force and impulse. With
  the bank's sleep on, a pair touching at the step before whose actors have
  no awake tree (MuJoCo does not test them) still touches; ``held_ticks``
  (a list) gets how many steps that held."""
  model = bank.model
  if bank.run.get("sleep"):
    model = sleep_lib.sleeping_copy(model, sleep_lib.SleepSettings.from_record(bank.run["sleep"]))
  data = mujoco.MjData(model)
  actors = actors_of(model, list(bank.objects))
  trees = {}  # actor -> the kinematic trees of its geoms
  for g in range(model.ngeom):
    tree = int(model.body_treeid[model.geom_bodyid[g]])
    trees.setdefault(int(actors.geom_actor[g]), set()).update([tree] if tree >= 0 else [])
  for f in range(model.nflex):  # a flex moves with its vertex bodies' trees
    bodies = model.flex_vertbodyid[model.flex_vertadr[f]:model.flex_vertadr[f] + model.flex_vertnum[f]]
    trees.setdefault(int(actors.flex_actor[f]), set()).update(int(t) for t in model.body_treeid[bodies] if t >= 0)
  moving = lambda actor: any(data.tree_asleep[t] < 0 for t in trees.get(actor, ()))
  spf = bank.events.ticks_per_frame
  gap = spf * round(bank.record_fps / bank.query_fps)  # a query point's steps apart end an episode
  last_tick = (int(bank.frame_count[row]) - 1) * spf
  data.qpos[:], data.qvel[:] = qpos0[row], qvel0[row]
  force6 = np.zeros(6)
  touching: dict = {}  # pair -> (first, last seen, peak, impulse)
  done = []
  for tick in range(last_tick + spf):  # the last frame's steps are simulated too
    mujoco.mj_step(model, data)
    forces: dict = {}
    for i in range(data.ncon):
      c = data.contact[i]
      if c.exclude == 1:
        continue
      a, b = (int(actors.geom_actor[g]) if g >= 0 else int(actors.flex_actor[f]) for g, f in zip(c.geom, c.flex))
      if a == b:
        continue
      f = 0.0
      if c.efc_address >= 0:
        mujoco.mj_contactForce(model, data, i, force6)
        f = max(force6[0], 0.0)
      key = (min(a, b), max(a, b))
      forces[key] = forces.get(key, 0.0) + f
    for key, f in forces.items():
      first, _, peak, impulse = touching.get(key, (tick, tick, 0.0, 0.0))
      touching[key] = (first, tick, max(peak, f), impulse + f * model.opt.timestep)
    for key, (first, seen, peak, impulse) in list(touching.items()):
      if seen == tick - 1 and not (moving(key[0]) or moving(key[1])):  # asleep together: still touching
        touching[key] = (first, tick, peak, impulse)
        if held_ticks is not None:
          held_ticks.append(key)
    for key, (first, seen, peak, impulse) in list(touching.items()):
      if tick - seen >= gap:
        done.append((*key, first, seen, peak, impulse))
        del touching[key]
  done += [(*key, first, last_tick if seen >= last_tick else seen, peak, impulse)
           for key, (first, seen, peak, impulse) in touching.items()]
  return {(a, b, first, min(last, last_tick), peak, impulse) for a, b, first, last, peak, impulse in done
          if first <= last_tick}


def _check_events_against_reference(bank, qpos0, qvel0, held_ticks=None):
  rng = np.random.default_rng(0)
  actors = list(bank.event_actors)
  objects = list(bank.objects)
  rate = bank.record_fps * bank.events.ticks_per_frame
  assert bank.events.ticks_per_frame > 1
  for row in range(bank.n_worlds):
    expected = _reference_episodes(bank, qpos0, qvel0, row, held_ticks)
    lo, hi = bank.events.offsets[row], bank.events.offsets[row + 1]
    got = {tuple(r) for r in bank.events.rows[lo:hi].tolist()}
    assert got == {e[:4] for e in expected}, row
    strength = {tuple(r): s for r, s in zip(bank.events.rows[lo:hi].tolist(), bank.events.strength[lo:hi])}
    for e in expected:  # kept within STRENGTH_RELATIVE_ERROR
      np.testing.assert_allclose(strength[e[:4]], e[4:], rtol=STRENGTH_RELATIVE_ERROR + 1e-6, atol=1e-6)
    # Touch queries on random pairs and windows, against the episodes.
    for _ in range(12):
      a = {str(rng.choice(objects))}
      b = {str(rng.choice(actors))} - a or {actors[-1]}
      t0 = float(rng.uniform(0, 3)) if rng.random() < 0.5 else None
      t1 = None if rng.random() < 0.5 else (t0 or 0.0) + float(rng.uniform(0.05, 1.5))
      window = None if t0 is None and t1 is None else (t0, t1)
      got_t = mwbx.queries.event.first_touch(bank, tuple(a), tuple(b), window)[row]
      want = _brute_first(expected, actors, rate, (int(bank.frame_count[row]) - 1) * bank.events.ticks_per_frame,
                          a, b, window)
      assert got_t == pytest.approx(want) or (math.isinf(got_t) and math.isinf(want)), (row, a, b, window)


def _brute_first(episodes, actors, rate, last_tick, a, b, window) -> float:
  """The first tick time in the window at which the sides touch, tick by
  tick over the episodes (past the last tick, it holds)."""
  t0, t1 = window if window is not None else (None, None)
  on = [(first, last) for x, y, first, last, *_ in episodes
        if (actors[x] in a and actors[y] in b) or (actors[x] in b and actors[y] in a)]
  start = 0 if t0 is None else math.ceil(t0 * rate - 1e-9 * rate)
  for first, last in sorted(on):
    tick = max(first, start)
    if tick <= last or last >= last_tick:
      if t1 is None or tick <= math.floor(t1 * rate + 1e-9 * rate):
        return tick / rate
  return math.inf


def test_events_match_mujocos_contact_list_at_every_physics_step(quickstart_config):
  _check_events_against_reference(*sample_unperturbed(quickstart_config, 3, seed=3))


def test_flex_events_match_mujocos_contact_list_at_every_physics_step(tmp_path):
  """A cloth dropped over a dome: its contacts are the flex's."""
  from test_flex_scene import flex_config
  bank, qpos0, qvel0 = sample_unperturbed(flex_config(tmp_path), 2)
  assert "cloth" in bank.event_actors
  _check_events_against_reference(bank, qpos0, qvel0)
  assert mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "dome")]).all()
  assert not mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "floor", window=(0.0, 0.1))]).any()  # still falling


def test_an_interpolated_flex_touches_by_its_nodes():
  """The soft cube of configs/soft_steps.yaml (dof trilinear: its vertices
  belong to no body, 8 node bodies move it) lands on the steps as "jelly"."""
  config = mwbx.load_config(REPO / "configs" / "soft_steps.yaml")
  config = config.model_copy(update={"sim": config.sim.model_copy(update={"end_time": 0.8})})
  bank, qpos0, qvel0 = sample_unperturbed(config, 2)
  _check_events_against_reference(bank, qpos0, qvel0)
  assert mwbx.evaluate(bank, [mwbx.TouchQuery("jelly", ("step_0", "step_1", "step_2", "step_3"))]).all()


def test_refined_worlds_keep_their_parents_events_and_find_their_own(quick_bank):
  """Before the restart a refined world's episodes are its parent's; after
  it, those of the objects it moves itself are found at its every step (with
  their strength), the others are the parent's."""
  parent_world = int(quick_bank.world_ids[2])
  bank = mwbx.refine(quick_bank, parent_world, "ball", t_min=1.0, n_samples=3, key=jax.random.key(5),
                     backend="native")
  actors = list(bank.event_actors)
  spf = bank.events.ticks_per_frame
  restart = round(1.0 * bank.record_fps) * spf
  parent = quick_bank.events.world(quick_bank.row_of(parent_world))
  for world in bank.world_ids[-3:].tolist():
    row = bank.row_of(world)
    rows = bank.events.world(row)
    strength = bank.events.strength[bank.events.offsets[row]:bank.events.offsets[row + 1]]
    early = lambda r: {tuple(x) for x in r[r[:, 2] < restart, :3].tolist()}
    assert early(rows) == early(parent)
    lineage = bank.lineage[str(world)]
    moved = np.isin(rows[:, :2], [actors.index(o) for o in lineage["active"]]).any(axis=1)
    own = rows[:, 2] >= restart
    assert (own & moved).any() and not np.isnan(strength).any()
    # pairs it did not move are the parent's, episode for episode
    others = lambda r, m: {tuple(x) for x in r[(r[:, 2] >= restart) & ~m, :3].tolist()}
    parent_moved = np.isin(parent[:, :2], [actors.index(o) for o in lineage["active"]]).any(axis=1)
    assert others(rows, moved) == others(parent, parent_moved)


def test_events_are_saved_checked_and_refused_in_one_line_without_them(drop_bank, tmp_path):
  path = tmp_path / "bank"
  drop_bank.save(path)
  loaded = mwbx.Bank.load(path)
  np.testing.assert_array_equal(loaded.events.rows, drop_bank.events.rows)
  assert loaded.event_actors == drop_bank.event_actors
  manifest = json.loads((path / "manifest.json").read_text())
  entry = manifest["shards"][0]
  assert {"events_rows", "events_counts", "events_strength"} <= set(entry["checksums"])
  assert entry["events"]["version"] == EVENTS_VERSION
  assert entry["events"]["ticks_per_frame"] == loaded.events.ticks_per_frame > 1
  np.testing.assert_array_equal(loaded.events.strength, drop_bank.events.strength)
  assert drop_bank.events.nbytes < 0.05 * drop_bank.nbytes
  rows = path / "shards" / entry["name"] / "events_rows.npy"
  data = bytearray(rows.read_bytes())
  data[-1] ^= 0x01
  rows.write_bytes(bytes(data))
  with pytest.raises(MwbxError, match="checksum mismatch in events_rows"):
    mwbx.Bank.load(path, lazy=False)
  # A bank saved before events were recorded: one line saying so.
  without = drop_bank._take(np.arange(drop_bank.n_worlds), events=None)
  with pytest.raises(MwbxError, match=r"no contact events .* sample it again") as err:
    mwbx.evaluate(without, [mwbx.TouchQuery("low", "floor")])
  assert "\n" not in str(err.value)
  query_file = tmp_path / "touch.yaml"
  query_file.write_text("queries:\n  - {touch: [low, floor]}\n")
  with pytest.raises(MwbxError, match=rf"{query_file}: queries\[0\]: this bank has no contact events"):
    mwbx.load_queries(query_file, without)


def test_event_query_files_round_trip_and_name_mistakes(drop_bank, tmp_path):
  path = tmp_path / "q.yaml"
  path.write_text(
      "queries:\n"
      "  - {name: hit, touch: [low, floor], window: [0.0, 0.5]}\n"
      "  - {name: apart, touch: [balls, [onpad, pad]], sign: exclude}\n"
      "  - {name: chain, then: [[low, floor], [onpad, pad], [high, floor]]}\n")
  qs = mwbx.load_queries(path, bank=drop_bank)
  assert [type(q).__name__ for q in qs.queries] == ["TouchQuery", "TouchQuery", "OrderQuery"]
  assert qs.queries[1].b == ("onpad", "pad") and qs.queries[2].describe().count("then") == 2
  again = mwbx.load_queries(qs.save(tmp_path / "again.yaml"), bank=drop_bank)
  np.testing.assert_array_equal(mwbx.evaluate_each(drop_bank, again), mwbx.evaluate_each(drop_bank, qs))
  assert mwbx.evaluate_each(drop_bank, qs).all()
  assert place_queries(qs).all() and qs.queries[2].objects(drop_bank) == ["low", "onpad", "high"]
  for text, message in [
      ("{touch: [low, nobody]}", "unknown actor 'nobody'"),
      ("{touch: [low]}", "two sides"),
      ("{touch: [low, floor], box: [0, 0, 1, 1]}", "not box"),
      ("{then: [[low, floor]]}", "at least two touches"),
      ("{then: [[low, floor], [high, floor]], sign: exclude}", "not sign"),
      ("{touch: [low, floor], window: [2, 1]}", "window"),
  ]:
    path.write_text(f"queries:\n  - {text}\n")
    with pytest.raises(MwbxError) as err:
      mwbx.load_queries(path, bank=drop_bank)
    assert str(err.value).startswith(f"{path}: queries[0]") and message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_mwbx_query_answers_event_queries(drop_bank, tmp_path, capsys):
  drop_bank.save(tmp_path / "bank")
  queries = tmp_path / "q.yaml"
  queries.write_text("queries:\n  - {name: chain, then: [[low, floor], [high, floor]]}\n"
                     "  - {name: never, touch: [low, high]}\n")
  assert cli.main(["query", str(tmp_path / "bank"), str(queries), "--json"]) == 0
  report = json.loads(capsys.readouterr().out)
  counts = {q["name"]: q["matches"] for q in report["queries"]}
  assert counts == {"chain": 4, "never": 0}


def test_gaps_point_towards_the_touch(drop_bank):
  never = mwbx.TouchQuery("low", "high")
  gaps = mwbx.queries.query_gaps(drop_bank, [never, mwbx.TouchQuery("low", "pad"), mwbx.TouchQuery("low", "floor")])
  # The balls' centres stay about 0.5 m apart (less two radii); "low" never nears the pad.
  assert np.all((gaps[:, 0] > 0.3) & (gaps[:, 0] < 0.6)) and np.all(gaps[:, 1] > 0.3)
  assert np.all(gaps[:, 2] == 0)


def test_an_order_gap_with_a_touch_that_never_happens_is_finite_and_quiet(drop_bank):
  order = mwbx.OrderQuery(events=(("low", "floor"), ("low", "high"), ("high", "floor")))
  with warnings.catch_warnings():
    warnings.simplefilter("error")  # inf - inf in the ordering term was a RuntimeWarning
    gaps = mwbx.queries.query_gaps(drop_bank, [order])
  assert np.all(np.isfinite(gaps)) and np.all(gaps[:, 0] > 0.3)


def test_a_fast_impact_between_two_stored_frames_is_a_touch_with_its_impulse(tmp_path):
  (tmp_path / "fast.xml").write_text(FAST_XML)
  (tmp_path / "fast.yaml").write_text("scene: {mjcf: fast.xml}\nsim: {end_time: 1.75}\n")
  bank, qpos0, qvel0 = sample_unperturbed(mwbx.load_config(tmp_path / "fast.yaml"), 4)
  _check_events_against_reference(bank, qpos0, qvel0)  # every step's touch and impulse, as MuJoCo has them
  rate = bank.record_fps * bank.events.ticks_per_frame
  t = mwbx.queries.event.first_touch(bank, ("ball",), ("floor",))
  # free fall to the floor, to a physics step (not a frame)
  assert np.all(np.abs(t - math.sqrt(2 * 13.0 / G)) <= 2 / rate), t
  # The impulse that turns 16 m/s around: m (v_in + v_out), v_out between 0 and v_in.
  v = math.sqrt(2 * G * 13.0)
  hit = mwbx.queries.event.hardest_hit(bank, ("ball",), ("floor",))
  assert np.all((hit > 0.2 * v) & (hit < 0.2 * 2 * v + 0.2 * G * 0.2)), hit
  hard = mwbx.TouchQuery("ball", "floor", impulse=(0.2 * v, None))
  harder = mwbx.TouchQuery("ball", "floor", impulse=(10.0, None))
  forceful = mwbx.TouchQuery("ball", "floor", force=(100.0, None))
  assert mwbx.evaluate(bank, [hard]).all() and not mwbx.evaluate(bank, [harder]).any()
  assert mwbx.evaluate(bank, [forceful]).all()
  gaps = mwbx.queries.query_gaps(bank, [hard, harder])
  assert np.all(gaps[:, 0] == 0)
  np.testing.assert_allclose(gaps[:, 1], (10.0 - hit) / 10.0)  # the fraction of the impulse asked for it misses
  ids, values = mwbx.rank(bank, hard.error(bank), top=4)
  assert np.all(np.diff(values) <= 0) and values[0] == hit.max()
  # The impact lasts fewer steps than a frame holds: stored frames can fall either side of it.
  first_hit = [bank.events.world(i)[0] for i in range(bank.n_worlds)]
  assert all(r[3] - r[2] + 1 < bank.events.ticks_per_frame for r in first_hit), first_hit


# Boxes dropped onto the floor fall asleep there; the pendulum beside them
# never sleeps, so the world runs on while they lie still.
SLEEPY_XML = """
<mujoco>
  <option timestep="0.002"><flag sleep="enable"/></option>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    BOXES
    <body name="arm" pos="1 1 0.6"><joint name="swing" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.1" contype="0" conaffinity="0"/></body>
  </worldbody>
</mujoco>
"""


def test_touches_held_while_asleep_are_mujocos_contacts_before_they_slept(tmp_path):
  """With island sleep MuJoCo stops testing the contacts of sleeping trees:
  a box asleep on the floor keeps touching it to the end of the world, as a
  replay that holds a pair touching while neither side has an awake tree
  has it (the held steps are most of the run)."""
  boxes = "".join(f'<body name="box{i}" pos="{0.2 * i - 0.3:.2f} 0 0.25"><freejoint/>'
                  f'<geom type="box" size="0.05 0.05 0.05" mass="0.2"/></body>' for i in range(3))
  (tmp_path / "sleepy.xml").write_text(SLEEPY_XML.replace("BOXES", boxes))
  (tmp_path / "sleepy.yaml").write_text(
      "scene: {mjcf: sleepy.xml}\n"
      "randomize:\n  box0:\n    angular_velocity: {dist: normal, scale: [2, 2, 2]}\n"
      "sim: {end_time: 2.0, sleep: true}\n")
  bank, qpos0, qvel0 = sample_unperturbed(mwbx.load_config(tmp_path / "sleepy.yaml"), 2)
  assert bank.run["sleep"]["enabled"]
  held = []
  _check_events_against_reference(bank, qpos0, qvel0, held)
  last_tick = (bank.frame_count - 1) * bank.events.ticks_per_frame
  np.testing.assert_array_equal(bank.frame_count, round(2.0 * bank.record_fps) + 1)  # the arm swings on
  actors = list(bank.event_actors)
  for row in range(bank.n_worlds):
    rows = bank.events.world(row)
    for box in ("box0", "box1", "box2"):
      pair = {actors.index("floor"), actors.index(box)}
      episodes = [r for r in rows if {int(r[0]), int(r[1])} == pair]
      assert episodes and episodes[-1][3] == last_tick[row], (row, box, rows)
  assert len(held) > 0.5 * bank.n_worlds * 3 * last_tick.max(), len(held)  # held: most box-floor steps


def test_a_domino_row_knocks_down_in_order_as_mujoco_steps_it(tmp_path):
  """A chain reaction: the first domino tipped (its spin drawn per world),
  each knocks the next. Every episode, peak force and impulse is MuJoCo's at
  every step; each domino touches the next later than the one before it
  did, and the order query says so."""
  (tmp_path / "dominoes.xml").write_text(domino_row_xml())
  (tmp_path / "dominoes.yaml").write_text(
      "scene: {mjcf: dominoes.xml}\n"
      "randomize:\n  domino_0:\n    angular_velocity: {dist: uniform, mean: [0, 6, 0], scale: [0, 1.5, 0]}\n"
      "sim: {end_time: 2.0}\n")
  bank, qpos0, qvel0 = sample_unperturbed(mwbx.load_config(tmp_path / "dominoes.yaml"), 3)
  _check_events_against_reference(bank, qpos0, qvel0)
  knocks = np.stack([mwbx.queries.event.first_touch(bank, (f"domino_{k}",), (f"domino_{k + 1}",))
                     for k in range(5)], axis=1)
  assert np.isfinite(knocks).all() and (np.diff(knocks, axis=1) > 0).all(), knocks
  chain = mwbx.OrderQuery(tuple((f"domino_{k}", f"domino_{k + 1}") for k in range(5)))
  backwards = mwbx.OrderQuery(tuple((f"domino_{k}", f"domino_{k + 1}") for k in reversed(range(5))))
  assert mwbx.evaluate(bank, [chain]).all() and not mwbx.evaluate(bank, [backwards]).any()


def _write_events_v2(folder, entry, record, version):
  """Writes ``record`` into a saved shard as events version 1 (frames, no
  strength) or 2 (ticks; rows and bfloat16 strengths zlib'd in world order),
  the layouts banks sampled before kept."""
  columns = record.rows.T.astype(np.int64)
  columns[3] -= columns[2]
  arrays = {"events_rows": np.frombuffer(bytes([2]) + zlib.compress(columns.astype(np.uint16).tobytes()), np.uint8),
            "events_counts": record.counts.astype(np.int32)}
  if version == 2:
    top = (record.strength.astype(np.float32).view(np.uint32) >> 16).astype(np.uint16).reshape(-1)
    arrays["events_strength"] = np.frombuffer(zlib.compress(top.view(np.uint8).reshape(-1, 2).T.tobytes()), np.uint8)
  for name in ("events_rows", "events_counts", "events_strength"):
    (folder / f"{name}.npy").unlink()
    del entry["checksums"][name]
  for name, array in arrays.items():
    np.save(folder / f"{name}.npy", array)
    entry["checksums"][name] = mwbx.bank.checks.crc32(array)
  entry["events"] = {"version": version, "actors": entry["events"]["actors"]}
  if version == 2:
    entry["events"]["ticks_per_frame"] = record.ticks_per_frame


def test_a_bank_of_events_version_2_loads_the_same_episodes(drop_bank, tmp_path):
  path = tmp_path / "bank"
  drop_bank.save(path)
  manifest = json.loads((path / "manifest.json").read_text())
  entry = manifest["shards"][0]
  _write_events_v2(path / "shards" / entry["name"], entry, drop_bank.events, version=2)
  (path / "manifest.json").write_text(json.dumps(manifest))
  old = mwbx.Bank.load(path)
  assert old.events.ticks_per_frame == drop_bank.events.ticks_per_frame > 1
  np.testing.assert_array_equal(old.events.rows, drop_bank.events.rows)
  # bfloat16 keeps 7 bits of mantissa (within 0.8 %), the current layout within STRENGTH_RELATIVE_ERROR.
  np.testing.assert_allclose(old.events.strength, drop_bank.events.strength, rtol=2 * STRENGTH_RELATIVE_ERROR)


def test_a_bank_whose_events_were_found_on_frames_still_answers(drop_bank, tmp_path):
  """Events version 1 (frames, no strength): loaded at one tick a frame;
  touches answer as before, strength filters say why they cannot."""
  path = tmp_path / "bank"
  drop_bank.save(path)
  manifest = json.loads((path / "manifest.json").read_text())
  entry = manifest["shards"][0]
  spf = drop_bank.events.ticks_per_frame
  frames = mwbx.events.detect_events(drop_bank.model, actors_of(drop_bank.model, list(drop_bank.objects)),
                                     drop_bank.qpos_store.frames_of_rows(None),
                                     touch_margin(drop_bank.config["codec"]["e_pos"]))
  _write_events_v2(path / "shards" / entry["name"], entry, frames, version=1)
  (path / "manifest.json").write_text(json.dumps(manifest))
  seen = []
  handler = logging.Handler()
  handler.emit = lambda record: seen.append(record.getMessage())
  level = NOTICE.level
  NOTICE.addHandler(handler)
  NOTICE.setLevel(logging.INFO)
  try:
    old = mwbx.Bank.load(path)
  finally:
    NOTICE.removeHandler(handler)
    NOTICE.setLevel(level)
  assert [m for m in seen if "contact events known at the stored frames only" in m] == seen and len(seen) == 1
  assert old.events.ticks_per_frame == 1 and np.isnan(old.events.strength).all()
  np.testing.assert_array_equal(old.events.rows, frames.rows)
  t = mwbx.queries.event.first_touch(old, ("low",), ("floor",))
  np.testing.assert_allclose(t, mwbx.queries.event.first_touch(drop_bank, ("low",), ("floor",)),
                             atol=3 / drop_bank.record_fps)
  with pytest.raises(MwbxError, match="impulse: this bank's contact events were found on its stored frames"):
    mwbx.evaluate(old, [mwbx.TouchQuery("low", "floor", impulse=(0.1, None))])
  both = mwbx.events.EventRecord.concat([old.events, drop_bank.events])  # frames become steps: one record
  assert both.ticks_per_frame == spf
  np.testing.assert_array_equal(both.rows[:len(frames.rows), 2:], frames.rows[:, 2:] * spf)


def test_worlds_whose_episodes_overflow_are_found_on_their_frames(drop_bank, monkeypatch):
  from mwbx.events import steps
  monkeypatch.setattr(steps, "MIN_EPISODES", 1)
  monkeypatch.setattr(steps, "EPISODES_PER_ACTOR", 0)
  config = drop_bank.config
  bank = mwbx.sample(mwbx.config.Config.model_validate(config), n_worlds=2, key=jax.random.key(0), backend="native")
  frames = mwbx.events.detect_events(bank.model, actors_of(bank.model, list(bank.objects)),
                                     bank.qpos_store.frames_of_rows(None),
                                     touch_margin(bank.config["codec"]["e_pos"])).in_ticks(bank.events.ticks_per_frame)
  np.testing.assert_array_equal(bank.events.rows, frames.rows)
