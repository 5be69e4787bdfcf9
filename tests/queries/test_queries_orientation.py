"""Orientation queries (upright, within an angle of a quaternion or of the
initial orientation; at the end or over a window) against MuJoCo's own
kinematics on the stored frames; query files, ranking, gaps, solve's view of
them, and `mwbx query` with the new kinds."""

import json

import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx import queries as mq
from mwbx.errors import MwbxError
from mwbx.queries import poses
from mwbx.search.objects import involved_objects
from mwbx.search.solver import deadline

import geometry_reference as ref


@pytest.fixture(scope="module")
def bank():
  return ref.shapes_bank(n_worlds=16, n_frames=41, seed=2, spin=1.5)


def test_forward_kinematics_matches_mujoco():
  xml = ref.SHAPES_XML.replace('<joint type="hinge" axis="0 1 0"/>',
                               '<joint type="hinge" axis="0 1 0.3" pos="0.01 0.02 0.03"/>'
                               '<joint type="slide" axis="1 0 0.2"/>')
  model = mujoco.MjModel.from_xml_string(xml)
  data = mujoco.MjData(model)
  qpos = np.random.default_rng(0).normal(size=(9, model.nq))
  pos, quat = poses.body_poses(model, qpos, np.arange(1, model.nbody))
  for t in range(len(qpos)):
    data.qpos[:] = qpos[t]
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(pos[t], data.xpos[1:], atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(quat[t] * data.xquat[1:], axis=1)), 1.0, atol=1e-12)


def _reference_errors(bank, body: str, error, window):
  """f64[W] the largest error over the stored frames of the window (the last
  frame without one), from mj_kinematics, plain loops."""
  model = bank.model
  data = mujoco.MjData(model)
  bid = model.body(body).id
  out = []
  for row in range(bank.n_worlds):
    q = bank.qpos_store.row_frames(row)
    last = len(q) - 1
    if window is None:
      frames = [last]
    else:
      t0, t1 = window
      f0 = 0 if t0 is None else min(int(round(t0 * bank.record_fps)), last)
      f1 = last if t1 is None else min(int(round(t1 * bank.record_fps)), last)
      frames = range(f0, max(f0, f1) + 1)
    data.qpos[:] = q[0]
    mujoco.mj_kinematics(model, data)
    start = data.xquat[bid].copy()
    worst = -np.inf
    for f in frames:
      data.qpos[:] = q[f]
      mujoco.mj_kinematics(model, data)
      worst = max(worst, error(data.xmat[bid].reshape(3, 3), data.xquat[bid], start))
    out.append(worst)
  return np.array(out)


def _upright(axis, up):
  return lambda mat, quat, start: float(np.arccos(np.clip(mat @ axis @ up, -1, 1)))


def _to_quat(target):
  def err(mat, quat, start):
    t = start if target is None else np.asarray(target)
    return float(2 * np.arccos(min(1.0, abs(float(quat @ t)))))
  return err


CASES = [
    (dict(axis="z"), _upright(np.array([0, 0, 1.0]), np.array([0, 0, 1.0]))),
    (dict(axis="-y", up=(1, 0, 1)), _upright(np.array([0, -1.0, 0]), np.array([1, 0, 1.0]) / np.sqrt(2))),
    (dict(target=(0.5, 0.5, 0.5, 0.5)), _to_quat([0.5, 0.5, 0.5, 0.5])),
    (dict(target="initial"), _to_quat(None)),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_orientation_errors_and_answers_match_the_reference(bank, case):
  goal, error = CASES[case]
  for body, window in [("crate", None), ("lower", (0.05, 0.2)), ("gem", (0.25, None))]:
    expected = _reference_errors(bank, body, error, window)
    q = mwbx.OrientationQuery(bodies=body, window=window, within_deg=60, **goal)
    np.testing.assert_allclose(mwbx.orientation_error(bank, q), expected, atol=2e-6)
    theta = float(np.median(expected))  # about half the worlds within
    inc = mwbx.OrientationQuery(bodies=body, window=window, within_deg=np.degrees(theta) + 1e-4, **goal)
    exc = mwbx.OrientationQuery(bodies=body, window=window, within_deg=np.degrees(theta) + 1e-4,
                                sign="exclude", **goal)
    each = mwbx.evaluate_each(bank, [inc, exc])
    np.testing.assert_array_equal(each[:, 0], expected <= theta + 1e-6)
    np.testing.assert_array_equal(each[:, 1], ~each[:, 0])
    assert 0 < each[:, 0].sum() < bank.n_worlds
    gaps = mq.query_gaps(bank, [inc, exc])
    np.testing.assert_array_equal(gaps == 0, each)
    np.testing.assert_allclose(gaps[~each[:, 0], 0], np.maximum(expected[~each[:, 0]] - inc.within, 1e-4),
                               atol=1e-5)


def test_any_and_all_over_bodies(bank):
  up = dict(axis="z", within_deg=50)
  one = {b: mwbx.evaluate(bank, [mwbx.OrientationQuery(bodies=b, **up)]) for b in ("crate", "pill", "gem")}
  any_ = mwbx.evaluate(bank, [mwbx.OrientationQuery(bodies="free", mode="any", **up)])
  all_ = mwbx.evaluate(bank, [mwbx.OrientationQuery(bodies="free", mode="all", **up)])
  np.testing.assert_array_equal(any_, one["crate"] | one["pill"] | one["gem"])
  np.testing.assert_array_equal(all_, one["crate"] & one["pill"] & one["gem"])
  assert any_.sum() > all_.sum()
  # The sorter's metric: the most upright worlds first.
  q = mwbx.OrientationQuery(bodies="crate", **up)
  ids, values = mwbx.rank(bank, [mq.Term("orientation_error", query=q)], descending=False, top=3)
  err = mwbx.orientation_error(bank, q)
  np.testing.assert_allclose(values, np.sort(err)[:3])
  assert ids[0] == bank.world_ids[np.argmin(err)]


def test_orientation_query_files_round_trip_and_name_mistakes(bank, tmp_path):
  path = tmp_path / "q.yaml"
  path.write_text(
      "queries:\n"
      "  - {name: up, bodies: crate, upright: z, within_deg: 40}\n"
      "  - {name: facing, bodies: [gem], upright: {axis: -y, up: [0, -1, 0]}, within_deg: 30, window: [0.1, null]}\n"
      "  - {name: kept, bodies: arm, orientation: initial, within_deg: 20, mode: all, sign: exclude}\n"
      "  - {name: turned, bodies: pill, orientation: [0, 1, 0, 0], within_deg: 90}\n"
      "rank:\n  - {metric: orientation_error, query: up}\norder: asc\n")
  qs = mwbx.load_queries(path, bank=bank)
  assert [type(q).__name__ for q in qs.queries] == ["OrientationQuery"] * 4
  assert qs.queries[1].axis == (0.0, -1.0, 0.0) and qs.queries[1].window == (0.1, None)
  assert qs.queries[2].target == "initial" and qs.queries[3].target == (0.0, 1.0, 0.0, 0.0)
  assert qs.rank[0].query is qs.queries[0]
  again = mwbx.load_queries(qs.save(tmp_path / "again.yaml"), bank=bank)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, again), mwbx.evaluate_each(bank, qs))
  assert again.rank[0].query.name == "up"
  for text, message in [
      ("{bodies: crate, upright: z}", "needs 'within_deg'"),
      ("{bodies: crate, upright: z, orientation: initial, within_deg: 5}", "exactly one of 'upright'"),
      ("{bodies: crate, upright: w, within_deg: 5}", "axis must be x, y, z"),
      ("{bodies: crate, upright: z, within_deg: 200}", "within_deg must be an angle in [0, 180]"),
      ("{bodies: crate, orientation: [0, 0, 0, 0], within_deg: 5}", "target must be a finite nonzero"),
      ("{bodies: crate, upright: z, within_deg: 5, radius: 0.1}", "not radius"),
      ("{bodies: nobody, upright: z, within_deg: 5}", "nobody"),
  ]:
    path.write_text(f"queries:\n  - {text}\n")
    with pytest.raises(MwbxError) as err:
      mwbx.load_queries(path, bank=bank)
    assert str(err.value).startswith(f"{path}: queries[0]") and message in str(err.value), str(err.value)
  path.write_text("queries:\n  - {name: up, bodies: crate, upright: z, within_deg: 5}\n"
                  "rank:\n  - {metric: orientation_error, query: down}\n")
  with pytest.raises(MwbxError, match=r"rank\[0\]: no orientation_error query named 'down' \(those queries: up\)"):
    mwbx.load_queries(path, bank=bank)


def test_solve_sees_their_objects_and_deadlines(bank):
  q = mwbx.OrientationQuery(bodies="lower", axis="z", within_deg=10, window=(0.1, 0.2))
  assert involved_objects(bank, q) == ["arm"]
  assert deadline(bank, int(bank.world_ids[0]), q) == pytest.approx(0.1)
  end = (int(bank.frame_count[1]) - 1) / bank.record_fps
  at_end = mwbx.OrientationQuery(bodies="gem", target="initial", within_deg=10, sign="exclude")
  assert involved_objects(bank, at_end) == ["gem"]
  assert deadline(bank, int(bank.world_ids[1]), at_end) == pytest.approx(end)
  geometry = mq.Query.region((-5, -5, -5), (5, 5, 5), bodies="pill", shape="geometry", sign="exclude")
  assert deadline(bank, int(bank.world_ids[1]), geometry) == pytest.approx(0.0)  # inside from the start


def test_cli_query_with_geometry_and_orientation(tiny_native_bank, tmp_path, capsys):
  bank = tiny_native_bank
  saved = tmp_path / "bank"
  bank.save(saved)
  path = tmp_path / "q.yaml"
  path.write_text(
      "queries:\n"
      "  - {name: cube_low, bodies: cube, region: {min: [-1, -1, -0.1], max: [1, 1, 0.06]}, shape: geometry}\n"
      "  - {name: cube_up, bodies: cube, upright: z, within_deg: 20}\n"
      "rank:\n  - {metric: orientation_error, query: cube_up}\norder: asc\n")
  assert cli.main(["query", str(saved), str(path), "--json"]) == 0
  out = json.loads(capsys.readouterr().out)
  qs = mwbx.load_queries(path, bank=bank)
  each = mwbx.evaluate_each(bank, qs)
  assert [q["matches"] for q in out["queries"]] == each.sum(axis=0).tolist()
  com = mwbx.evaluate(bank, [mq.Query.region((-1, -1, -0.1), (1, 1, 0.06), bodies="cube")])
  assert each[:, 0].sum() >= com.sum()  # the cube's faces reach lower than its centre
  match = np.all(each, axis=1)
  if match.any():
    err = mwbx.orientation_error(bank, qs.queries[1])
    best = bank.world_ids[np.flatnonzero(match)[np.argmin(err[match])]]
    assert out["worlds"][0]["world"] == int(best)
  path.write_text("queries:\n  - {bodies: cube, upright: z}\n")
  assert cli.main(["query", str(saved), str(path)]) == 2
  assert "queries[0]: an orientation query needs 'within_deg'" in capsys.readouterr().err


def test_queries_asked_together_answer_as_each_alone():
  """Several orientation queries decode their bodies in one pass over a coded
  bank; each answer and gap is the one it has asked alone, bit for bit."""
  from mwbx.codec import CodecBounds, CompressedQposStore
  from mwbx.queries import orientation

  model = mujoco.MjModel.from_xml_string(ref.SHAPES_XML)
  coded = ref.shapes_bank(n_worlds=9, n_frames=41, seed=3, spin=1.5, store=CompressedQposStore.from_model(
      model, CodecBounds(e_pos=1e-3, e_rot=0.01, e_scalar=0.01)))
  asked = [("crate", None, CASES[0][0]), ("lower", (0.05, 0.2), CASES[1][0]), ("gem", (0.25, None), CASES[2][0]),
           ("free", None, CASES[3][0]), ("upper", None, CASES[0][0])]
  queries = [mwbx.OrientationQuery(bodies=body, window=window, within_deg=45, **goal) for body, window, goal in asked]
  alone_gaps, alone_met = [], []
  for query in queries:
    orientation._CACHE.clear()
    alone_met.append(mwbx.evaluate_each(coded, [query])[:, 0])
    orientation._CACHE.clear()
    alone_gaps.append(mq.query_gaps(coded, [query])[:, 0])
  orientation._CACHE.clear()
  np.testing.assert_array_equal(mwbx.evaluate_each(coded, queries), np.stack(alone_met, axis=1))
  orientation._CACHE.clear()
  together = mq.query_gaps(coded, queries)
  np.testing.assert_array_equal(together, np.stack(alone_gaps, axis=1))
  assert (together > 0).any() and (together == 0).any()
