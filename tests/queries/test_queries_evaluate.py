"""evaluate / evaluate_each / first_entry on a stand-in bank vs the reference."""

from hypothesis import given, settings, HealthCheck
from hypothesis import strategies as st
import numpy as np
import pytest

from mwbx.errors import MwbxError
from mwbx.queries import Camera, Frustum, Query, ScreenBox
from mwbx.queries import constraints_satisfied, evaluate, evaluate_each, first_entry
from mwbx.queries import paths as query_lib

import queries_bank
import queries_reference as ref

W, P, B = 24, 31, 5
CAMERA = Camera.look_at([0.2, -4, 1.2], [0, 0, 0.8], fovy=50, aspect=4 / 3)
SELECTIONS = [None, (), ("b0",), ("b1", "arm"), ("even",), ("everything",), ("b3",)]


@pytest.fixture(scope="module")
def bank():
  com = queries_bank.ballistic_paths(W, P, B, seed=11)
  flags = np.full(W, queries_bank.FLAG_FINISHED, np.uint8)
  flags[[3, 7]] |= queries_bank.FLAG_UNSTABLE
  com[7] = np.nan  # an unstable world may hold anything
  return queries_bank.make_bank(com, flags=flags)


@st.composite
def queries(draw):
  u = sorted(draw(st.floats(0, 1)) for _ in range(2))
  v = sorted(draw(st.floats(0, 1)) for _ in range(2))
  near = draw(st.one_of(st.none(), st.floats(0, 3.5)))
  # A window starts at 0 or later; no subnormal times (XLA on a CPU flushes them to zero).
  t0 = draw(st.one_of(st.none(), st.floats(0.0, 1.2, allow_subnormal=False)))
  t1 = draw(st.one_of(st.none(), st.floats(0.0, 1.2, allow_subnormal=False)))
  if t0 is not None and t1 is not None and t0 > t1:
    t0, t1 = t1, t0
  return Query.screen(
      CAMERA, ScreenBox(u[0], v[0], u[1], v[1]), near=near,
      bodies=draw(st.sampled_from(SELECTIONS)), sign=draw(st.sampled_from(["include", "exclude"])),
      mode=draw(st.sampled_from(["any", "all"])), window=draw(st.sampled_from([None, (t0, t1)])),
      radius=draw(st.sampled_from([0.0, 0.04, "auto"])))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(qs=st.lists(queries(), min_size=0, max_size=3))
def test_evaluate_matches_reference(bank, qs):
  expected = ref.evaluate_each(bank, qs)
  each = evaluate_each(bank, qs)
  np.testing.assert_array_equal(each, expected)
  np.testing.assert_array_equal(evaluate(bank, qs), expected.all(axis=1) & bank.valid)
  np.testing.assert_array_equal(constraints_satisfied(bank, qs), expected.sum(axis=1))
  assert not evaluate(bank, qs)[[3, 7]].any()


def test_include_and_exclude_partition_valid_worlds(bank):
  q = Query.screen(CAMERA, [0.3, 0.2, 0.7, 0.8], bodies=["b0"])
  inc = evaluate(bank, q)
  exc = evaluate(bank, Query.screen(CAMERA, [0.3, 0.2, 0.7, 0.8], bodies=["b0"], sign="exclude"))
  assert 0 < inc.sum() < bank.valid.sum()
  np.testing.assert_array_equal(inc | exc, bank.valid)
  assert not (inc & exc).any()


def test_all_mode_is_stricter_than_any(bank):
  box = [0.5, 0.1, 0.9, 0.6]
  any_ = evaluate(bank, Query.screen(CAMERA, box, bodies=["everything"], mode="any"))
  all_ = evaluate(bank, Query.screen(CAMERA, box, bodies=["everything"], mode="all"))
  assert np.all(all_ <= any_) and 0 < all_.sum() < any_.sum()


def test_auto_radius_is_each_bodies_bounding_radius(bank):
  radii = query_lib.body_radii(bank.model, bank.body_ids)
  model = bank.model
  np.testing.assert_allclose(radii, [ref.bounding_radius(model, int(i)) for i in bank.body_ids])
  # b1 is a box at 5 cm from its COM plus a sphere: its radius exceeds either geom's.
  assert radii[1] > 0.05 and radii[0] == pytest.approx(0.03)


def test_first_entry_matches_reference(bank):
  frustum = CAMERA.frustum(ScreenBox(0.35, 0.3, 0.65, 0.7))
  found = 0
  for world in range(W):
    for bodies, window, radius in [(None, None, 0.0), (["b1", "b2"], (0.2, None), "auto")]:
      got = first_entry(bank, int(bank.world_ids[world]), bodies, frustum, window=window, radius=radius)
      want = ref.first_entry(bank, world, bodies, frustum, window, radius)
      assert got == want
      found += got is not None
  assert 0 < found < 2 * W


def test_first_entry_is_when_the_path_enters():
  # One body moving along x at 3 m/s; the box starts at x = 1: entry at 1/3 s.
  t = np.arange(31) / 30
  com = np.zeros((1, 31, 2, 3), np.float32)
  com[0, :, 0, 0] = 3 * t
  bank = queries_bank.make_bank(com)
  box = Frustum.box([1, -1, -1], [5, 1, 1])
  assert first_entry(bank, 100, ["b0"], box) == pytest.approx(1 / 3, abs=1e-6)
  assert first_entry(bank, 100, ["b1"], box) is None
  assert first_entry(bank, 100, ["b0"], box, window=(0.5, None)) == pytest.approx(0.5)


def test_unknown_names_and_bad_fields_raise(bank):
  with pytest.raises(MwbxError, match="unknown body, object or group 'nope'"):
    evaluate(bank, Query.region([0, 0, 0], [1, 1, 1], bodies=["nope"]))
  with pytest.raises(MwbxError, match="sign"):
    Query.region([0, 0, 0], [1, 1, 1], sign="maybe")
  with pytest.raises(MwbxError, match="window is empty"):
    Query.region([0, 0, 0], [1, 1, 1], window=(2, 1))
  with pytest.raises(MwbxError, match="radius"):
    Query.region([0, 0, 0], [1, 1, 1], radius=-1)
  with pytest.raises(MwbxError, match=f"world {W}: no world with this id"):
    first_entry(bank, W, None, Frustum.box([0, 0, 0], [1, 1, 1]))  # ids are 100..


def test_index_is_cached_and_rebuilt_when_the_bank_changes(bank):
  first = query_lib.path_index(bank)
  assert query_lib.path_index(bank) is first
  other = queries_bank.make_bank(bank.com.copy(), flags=bank.flags.copy())
  assert query_lib.path_index(other) is not first
  other.flags = other.flags | queries_bank.FLAG_UNSTABLE
  assert not np.asarray(query_lib.path_index(other).valid).any()


@pytest.fixture
def boxed_bank(bank, monkeypatch):
  """The bank read as a lazy bank is: pieces of a few worlds with their path
  boxes stored beside them (packed and unpacked, chunks of 4 segments), and
  one in memory (new worlds: boxed when first asked, in those chunks too);
  answered from the boxes every time."""
  from mwbx.bank.lazy import LazyRows
  from mwbx.queries import path_boxes

  com = np.asarray(bank.com)
  edges = [0, 5, 10, 17, W]
  pieces = [com[a:b] for a, b in zip(edges, edges[1:])]
  stored = lambda piece: path_boxes.unpack(path_boxes.pack(path_boxes.build(piece, 4)), P - 1, 4)
  lazy = LazyRows([lambda piece=piece: piece for piece in pieces[:-1]] + pieces[-1:], [len(x) for x in pieces],
                  com.shape[1:],
                  np.float32, companions=[lambda piece=piece: stored(piece) for piece in pieces[:-1]] + [None])
  monkeypatch.setattr(query_lib, "BOX_ANSWERED_EVALUATIONS", 10**9)
  monkeypatch.setattr(query_lib, "OPEN_FRACTION", 1.0)  # however many worlds the boxes leave open
  return queries_bank.make_bank(com, flags=bank.flags.copy()).__class__(
      lazy, bank.flags.copy(), bank.metrics, bank.com_count)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(qs=st.lists(queries(), min_size=1, max_size=3))
def test_answers_from_stored_boxes_match_reference(boxed_bank, qs):
  assert query_lib.answered_from_boxes(boxed_bank)
  np.testing.assert_array_equal(evaluate_each(boxed_bank, qs), ref.evaluate_each(boxed_bank, qs))


def test_stored_boxes_decide_most_worlds_of_a_small_box(boxed_bank, monkeypatch):
  decoded = []
  rows = boxed_bank.com.rows
  monkeypatch.setattr(boxed_bank.com, "rows", lambda r, **kw: decoded.append(len(r)) or rows(r, **kw))
  q = Query.region([-0.5, -0.5, 0.0], [0.0, 0.0, 0.6], bodies=["b0"])
  got = evaluate_each(boxed_bank, [q])
  assert 0 < sum(decoded) < W // 2  # most worlds' b0 path boxes decide this box
  want = ref.evaluate_each(boxed_bank, [q])
  np.testing.assert_array_equal(got, want)
  assert 0 < want.sum() < W
