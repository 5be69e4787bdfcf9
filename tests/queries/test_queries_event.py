"""Contact events and event queries, against references built here: a scene
whose order of events is known from free fall, and MuJoCo's own contact list
at every stored frame of the same stored worlds (queries answered by brute
force over per-frame sets of touching pairs)."""

import json
import math
import warnings

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.errors import MwbxError
from mwbx.events import actors_of, touch_margin
from mwbx.search.solver import place_queries
from conftest import REPO

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


def _reference_touching(bank, world: int) -> list[set]:
  """Per stored frame, the set of touching actor-name pairs: MuJoCo's contact
  list (mj_forward) on the decoded state, distances within the touch margin."""
  model = bank.model()
  margin = touch_margin(bank.config["codec"]["e_pos"])
  model.geom_margin[:] = np.maximum(model.geom_margin, margin)
  model.flex_margin[:] = np.maximum(model.flex_margin, margin)
  data = mujoco.MjData(model)
  names = actors_of(model, list(bank.objects))
  frames = []
  for qpos in bank.qpos_frames(world):
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    pairs = set()
    for i in range(data.ncon):
      a, b = (names.names[names.geom_actor[g] if g >= 0 else names.flex_actor[f]]  # a flex's side: its flex
              for g, f in zip(data.contact.geom[i], data.contact.flex[i]))
      if a != b and data.contact.dist[i] <= margin:
        pairs.add(frozenset((a, b)))
    frames.append(pairs)
  bank._model = None  # the margins above were set on the bank's own model
  return frames


def test_events_match_mujocos_contact_list_at_every_stored_frame(quick_bank):
  _check_events_against_reference(quick_bank)


def test_flex_events_match_mujocos_contact_list_at_every_stored_frame(tmp_path):
  """A cloth dropped over a dome: its contacts are the flex's, found where
  its vertices are at each stored frame (mj_forward places them)."""
  from test_flex_scene import flex_config
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=2, key=jax.random.key(0), backend="native")
  assert "cloth" in bank.event_actors
  _check_events_against_reference(bank)
  assert mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "dome")]).all()
  assert not mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "floor", window=(0.0, 0.1))]).any()  # still falling


def test_an_interpolated_flex_touches_by_its_nodes(tmp_path):
  """The soft cube of configs/soft_steps.yaml (dof trilinear: its vertices
  belong to no body, 8 node bodies move it) lands on the steps as "jelly"."""
  config = mwbx.load_config(REPO / "configs" / "soft_steps.yaml")
  config = config.model_copy(update={"sim": config.sim.model_copy(update={"end_time": 0.8})})
  bank = mwbx.sample(config, n_worlds=2, key=jax.random.key(0), backend="native")
  _check_events_against_reference(bank)
  assert mwbx.evaluate(bank, [mwbx.TouchQuery("jelly", ("step_0", "step_1", "step_2", "step_3"))]).all()


def _check_events_against_reference(bank):
  fps = bank.record_fps
  rng = np.random.default_rng(0)
  actors = list(bank.event_actors)
  objects = list(bank.objects)
  for row, world in enumerate(bank.world_ids.tolist()):
    frames = _reference_touching(bank, world)
    # The stored episodes are the runs of the reference's per-frame sets.
    expected = set()
    for pair in set().union(*frames):
      on = [pair in p for p in frames]
      f = 0
      while f < len(on):
        if on[f]:
          g = f
          while g + 1 < len(on) and on[g + 1]:
            g += 1
          a, b = sorted(actors.index(n) for n in pair)
          expected.add((a, b, f, g))
          f = g + 1
        else:
          f += 1
    assert {tuple(r) for r in bank.events.world(row).tolist()} == expected, world
    # Touch queries on random pairs and windows, against the per-frame sets.
    for _ in range(12):
      a = {str(rng.choice(objects))}
      b = {str(rng.choice(actors))} - a or {"floor"}
      t0 = float(rng.uniform(0, 3)) if rng.random() < 0.5 else None
      t1 = None if rng.random() < 0.5 else (t0 or 0.0) + float(rng.uniform(0.05, 1.5))
      window = None if t0 is None and t1 is None else (t0, t1)
      got = mwbx.queries.event.first_touch(bank, tuple(a), tuple(b), window)[row]
      want = _brute_first(frames, fps, a, b, window)
      assert got == pytest.approx(want) or (math.isinf(got) and math.isinf(want)), (world, a, b, window, got, want)


def _brute_first(frames, fps, a, b, window) -> float:
  """The first stored frame time in the window at which the sides touch, from
  the per-frame sets alone (past the last frame, the last frame holds)."""
  t0, t1 = window if window is not None else (None, None)
  hit = [any((x in a and y in b) or (x in b and y in a) for x, y in (tuple(p) for p in pairs)) for pairs in frames]
  f = 0
  while True:
    t = f / fps
    if t1 is not None and t > t1 + 1e-9:
      return math.inf
    if f >= len(hit) and (not hit[-1] or t1 is None and t0 is None):
      return math.inf
    if hit[min(f, len(hit) - 1)] and (t0 is None or t >= t0 - 1e-9):
      return t
    if f >= len(hit) and t0 is not None and t >= t0 - 1e-9 and not hit[-1]:
      return math.inf
    f += 1


def test_refined_worlds_get_the_events_of_their_stored_frames(quick_bank):
  bank = mwbx.refine(quick_bank, int(quick_bank.world_ids[2]), "ball", t_min=1.0, n_samples=3,
                     key=jax.random.key(5), backend="native")
  model = bank.model()
  actors = actors_of(model, list(bank.objects))
  for world in bank.world_ids[-3:].tolist():
    fresh = mwbx.events.detect_events(model, actors, [bank.qpos_frames(world)],
                                      touch_margin(bank.config["codec"]["e_pos"]))
    np.testing.assert_array_equal(fresh.rows, bank.events.world(bank.row_of(world)))


def test_events_are_saved_checked_and_refused_in_one_line_without_them(drop_bank, tmp_path):
  path = tmp_path / "bank"
  drop_bank.save(path)
  loaded = mwbx.Bank.load(path)
  np.testing.assert_array_equal(loaded.events.rows, drop_bank.events.rows)
  assert loaded.event_actors == drop_bank.event_actors
  manifest = json.loads((path / "manifest.json").read_text())
  entry = manifest["shards"][0]
  assert {"events_rows", "events_counts"} <= set(entry["checksums"]) and entry["events"]["version"] == 1
  assert drop_bank.events.nbytes < 0.05 * drop_bank.nbytes
  rows = path / "shards" / entry["name"] / "events_rows.npy"
  data = bytearray(rows.read_bytes())
  data[-1] ^= 0x01
  rows.write_bytes(bytes(data))
  with pytest.raises(MwbxError, match="checksum mismatch in events_rows"):
    mwbx.Bank.load(path, lazy=False)
  # A bank saved before events were recorded: one line saying so.
  without = drop_bank._take(np.arange(drop_bank.n_worlds))
  without.events = None
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
