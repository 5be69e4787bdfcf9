"""The one Query interface: every query type implements it, every caller uses
it, and a query type the package has never seen works in evaluation, gaps,
the search's view of queries, the page's session and the viewer's classes
without an edit to any of them."""

import ast
import dataclasses
import pathlib

import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.browser import Session
from mwbx.queries import query_file
from mwbx.search.solver import place_queries
from mwbx.viewer import query_adapter

import geometry_reference as ref

PACKAGE = pathlib.Path(mwbx.__file__).parent
QUERY_CLASSES = {"Query", "VolumeQuery", "JointQuery", "OrientationQuery", "TouchQuery", "OrderQuery"}


@pytest.fixture(scope="module")
def bank():
  return ref.shapes_bank(n_worlds=16, n_frames=41, seed=3, spin=1.5)


@dataclasses.dataclass(frozen=True, eq=False)
class HighCrate(mq.Query):
  """A query type defined outside the package: the crate's COM rises above a height."""

  height: float
  name: str = "high_crate"
  sign: str = "include"
  bodies: tuple = ("crate",)

  def _top(self, bank):
    b = list(bank.body_names).index("crate")
    return np.asarray(bank.com, np.float64)[:, :, b, 2].max(axis=1)  # f64[W], m

  def evaluate(self, bank):
    met = self._top(bank) >= self.height
    return (met if self.include else ~met) & np.asarray(bank.valid, bool)

  def gap(self, bank):
    return np.maximum(self.height - self._top(bank), 0.0) if self.include else np.zeros(bank.n_worlds)

  def describe(self):
    return f"{self.sign} crate above {self.height:g} m"

  def to_dict(self):
    return {"name": self.name, "high_crate": self.height}

  @classmethod
  def claims(cls, entry):
    return False

  @classmethod
  def from_entry(cls, entry, index, context):
    raise AssertionError("never claims an entry")


def test_every_shipped_query_type_implements_the_interface():
  assert set(query_file.QUERY_KINDS) == {mq.VolumeQuery, mq.JointQuery, mq.OrientationQuery, mq.TouchQuery,
                                         mq.OrderQuery}
  for kind in query_file.QUERY_KINDS:
    assert issubclass(kind, mq.Query) and not kind.__abstractmethods__, kind
  assert mq.Query is mwbx.Query
  # Query is abstract; Query.screen and Query.region name the paper's volume query.
  with pytest.raises(TypeError):
    mwbx.Query(mwbx.Frustum.box((0, 0, 0), (1, 1, 1)), bodies="crate")
  box = mwbx.VolumeQuery(mwbx.Frustum.box((0, 0, 0), (1, 1, 1)), bodies="crate")
  region = mwbx.Query.region((0, 0, 0), (1, 1, 1), sign="exclude")
  assert type(box) is type(region) is mq.VolumeQuery and isinstance(box, mwbx.Query)
  assert box.describe() == "include crate" and region.describe() == "exclude any body"
  class Unfinished(mq.Query):
    def describe(self):
      return "no answers"

  with pytest.raises(TypeError, match="abstract"):  # a type must implement the whole interface
    Unfinished()


def test_a_new_query_type_works_everywhere_without_edits(bank, tmp_path):
  tops = HighCrate(0.0)._top(bank)
  high = HighCrate(float(np.median(tops)))
  volume = mwbx.Query.region((-5, -5, -5), (5, 5, 0.0), bodies="pill", name="pill_low")
  upright = mwbx.OrientationQuery(bodies="gem", axis="z", within_deg=60, name="gem_up")
  queries = [volume, high, upright]
  each = mwbx.evaluate_each(bank, queries)
  for i, q in enumerate(queries):
    np.testing.assert_array_equal(each[:, i], q.evaluate(bank))
  assert 0 < each[:, 1].sum() < bank.n_worlds
  gaps = mq.query_gaps(bank, queries)
  valid = np.asarray(bank.valid, bool)
  np.testing.assert_array_equal(gaps[valid] == 0, each[valid])
  assert np.all(gaps[~each] >= mq.gaps.MIN_GAP)
  assert place_queries(queries).tolist() == [True, True, False]  # orientations are poses
  assert high.objects(bank) == ["crate"] and high.deadline(bank, int(bank.world_ids[0])) > 0
  session = Session(bank)
  for q in queries:
    session.add(q)
  assert session.counts().per_query == tuple(int(n) for n in each.sum(axis=0))
  assert session.orientation_query() is upright
  match, exclude = query_adapter.evaluate_classes(bank, queries)
  np.testing.assert_array_equal(match, each.all(axis=1) & np.asarray(bank.valid, bool))
  assert not exclude.any()
  assert [q.describe() for q in queries] == ["include pill", f"include crate above {high.height:g} m",
                                             "include gem within 60° of upright"]


def test_every_shipped_type_round_trips_through_a_file(bank, tmp_path):
  cam = mq.Camera.look_at((0, -4, 1), (0, 0, 0.5), fovy=50, aspect=1.0)
  queries = (
      mwbx.Query.screen(cam, [0.2, 0.2, 0.7, 0.8], bodies="crate", window=(0.1, None), name="seen"),
      mwbx.Query.region((-1, -1, -1), (1, 1, 1), sign="exclude", shape="geometry", name="kept_out"),
      mwbx.OrientationQuery(bodies="gem", target="initial", within_deg=30, name="as_placed"),
      mwbx.JointQuery("lid_hinge", turn=(0.5, None), of="max", window=(0.0, 2.0), name="lid"),
  )
  path = mwbx.QuerySet(queries).save(tmp_path / "q.yaml")
  again = mwbx.load_queries(path).queries  # no bank: the joint's name is not checked
  assert [type(q) for q in again] == [type(q) for q in queries]
  assert [q.to_dict() for q in again] == [q.to_dict() for q in queries]
  assert [q.describe() for q in again] == [q.describe() for q in queries]
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, again[:3]), mwbx.evaluate_each(bank, queries[:3]))


def _query_type_switches(path: pathlib.Path) -> list[str]:
  """``isinstance(x, <query class>)`` calls in one module."""
  found = []
  for node in ast.walk(ast.parse(path.read_text())):
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance" and len(node.args) == 2:
      named = {n.attr if isinstance(n, ast.Attribute) else getattr(n, "id", None) for n in ast.walk(node.args[1])}
      hit = named & (QUERY_CLASSES - {"Query"})
      if hit:
        found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} isinstance(..., {', '.join(sorted(hit))})")
  return found


def test_no_caller_switches_on_query_types():
  outside = [p for p in PACKAGE.rglob("*.py") if "queries" not in p.relative_to(PACKAGE).parts[:1]]
  switches = [s for p in outside for s in _query_type_switches(p)]
  assert not switches, "callers must go through the Query interface:\n" + "\n".join(switches)


def test_one_rule_for_matched_and_rejected_worlds():
  # Query 0 includes, query 1 excludes; world 2 is not valid.
  each = np.array([[True, True], [True, False], [False, True], [False, False]])
  k = mq.kept(each, np.array([True, False]), np.array([True, True, False, True]))
  assert k.match.tolist() == [True, False, False, False]
  assert k.rejected.tolist() == [False, True, False, True]  # failed the exclude query (valid worlds only)
  none = mq.kept(np.zeros((3, 0), bool), np.zeros(0, bool), np.array([True, False, True]))
  assert none.match.tolist() == [True, False, True] and not none.rejected.any()
