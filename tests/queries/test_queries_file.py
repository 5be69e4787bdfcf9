"""Query files: the YAML format and its error messages."""

import textwrap

import numpy as np
import pytest

from mwbx.errors import MwbxError
from mwbx.queries import Query, Term, VolumeQuery, evaluate, load_queries

import queries_bank

GOOD = """
camera: {mjcf: front}
queries:
  - name: high_left
    box: [0.0, 0.0, 0.5, 0.5]
    near: 0.5
    bodies: [b0, arm]
    mode: all
    window: [0.1, null]
    radius: auto
  - region: {min: [-9, -9, -9], max: [9, 9, 0.1]}
    sign: exclude
    bodies: even
  - box: [0.4, 0.4, 0.6, 0.6]
    camera: {eye: [0, -3, 1], target: [0, 0, 1], fovy: 30, aspect: 1.0}
rank:
  - {metric: path_length, bodies: [b0], reduce: max, weight: 2}
  - collisions
order: asc
top: 5
"""


@pytest.fixture(scope="module")
def bank():
  return queries_bank.make_bank(queries_bank.ballistic_paths(10, 20, 4, seed=2))


def write(tmp_path, text, name="q.yaml"):
  path = tmp_path / name
  path.write_text(textwrap.dedent(text))
  return path


def test_good_file_loads(tmp_path, bank):
  qs = load_queries(write(tmp_path, GOOD), bank)
  assert len(qs.queries) == 3 and qs.top == 5 and not qs.descending
  a, b, c = qs.queries
  assert (a.name, a.mode, a.window, a.radius, a.bodies) == ("high_left", "all", (0.1, None), "auto",
                                                           ("b0", "arm"))
  assert a.camera.name == "front" and a.frustum.n_planes == 5
  assert b.sign == "exclude" and b.bodies == ("even",) and b.frustum.n_planes == 6 and b.name == "q1"
  assert c.camera.fovy == 30 and c.frustum.n_planes == 4
  assert qs.rank == (Term("path_length", ("b0",), "max", 2.0), Term("collisions", None, "sum", 1.0))
  # The loaded query is the one built in code.
  same = Query.screen(a.camera, [0.0, 0.0, 0.5, 0.5], near=0.5, bodies=["b0", "arm"], mode="all",
                      window=(0.1, None), radius="auto")
  np.testing.assert_array_equal(evaluate(bank, [same]), evaluate(bank, qs.queries[:1]))


@pytest.mark.parametrize("text, message", [
    ("queries: [{box: [0, 0, 1]}]", r"queries\[0\]\.box"),
    ("camera: {mjcf: front}\nqueries: [{box: [0.5, 0, 0.2, 1]}]", r"queries\[0\]: box: empty"),
    ("queries: [{box: [0, 0, 1, 1]}]", r"queries\[0\]: a screen box needs a camera"),
    ("queries: [{region: {min: [0, 0, 0], max: [1, 1, 1]}, colour: red}]", r"queries\[0\]\.colour"),
    ("queries: [{region: {min: [0, 0, 0], max: [1, 1, 1]}, bodies: [ghost]}]",
     r"queries\[0\]\.bodies: .*'ghost'"),
    ("queries: [{region: {min: [0, 0, 0], max: [1, 1, 1]}, sign: maybe}]", r"queries\[0\]\.sign"),
    ("queries: [{region: {min: [0, 0, 0], max: [1, 1, 1]}, window: [3, 1]}]", r"window is empty"),
    ("camera: {mjcf: top}\nqueries: []", r"camera: camera: no MJCF camera named 'top'"),
    ("camera: {eye: [0, 0, 0], target: [0, 0, 0]}\nqueries: []", r"camera: .*coincide"),
    ("queries: []\nrank: [speed]", r"rank\[0\]: unknown metric 'speed'"),
    ("queries: [{}]", r"queries\[0\]: give exactly one of 'box'"),
    ("queries: [a, b", r"not valid YAML: line 1, column 15: while parsing a flow sequence; expected ',' or ']'"),
    ("- 1\n- 2", r"expected a mapping"),
])
def test_errors_name_file_and_field(tmp_path, bank, text, message):
  path = write(tmp_path, text)
  with pytest.raises(MwbxError, match=message) as info:
    load_queries(path, bank)
  assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_mjcf_camera_needs_the_scene(tmp_path):
  with pytest.raises(MwbxError, match="needs the scene"):
    load_queries(write(tmp_path, "camera: {mjcf: front}\nqueries: []"))


def test_missing_file(tmp_path):
  with pytest.raises(MwbxError, match="cannot read query file"):
    load_queries(tmp_path / "absent.yaml")


def test_query_set_saves_a_file_that_loads_to_the_same_queries(tmp_path, bank):
  from mwbx.queries import Camera, Frustum, QuerySet, evaluate_each
  qs = load_queries(write(tmp_path, GOOD), bank)
  free = Camera.look_at([0.3, -3.5, 1.4], [0.1, 0.2, 0.7], fovy=52, aspect=1.6)
  extra = (Query.screen(free, [0.2, 0.1, 0.7, 0.9], far=6.0, bodies="b1", sign="exclude", name="drawn"),
           Query.region([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0], window=(None, 0.4)))
  everything = qs._replace(queries=qs.queries + extra)
  path = everything.save(tmp_path / "saved.yaml")
  again = load_queries(path, bank)
  assert [q.name for q in again.queries] == [q.name or f"q{i}" for i, q in enumerate(everything.queries)]
  assert again.rank == everything.rank and again.top == 5 and not again.descending
  np.testing.assert_array_equal(evaluate_each(bank, again.queries), evaluate_each(bank, everything.queries))
  for a, b in zip(again.queries, everything.queries):
    np.testing.assert_allclose(a.frustum.normals, b.frustum.normals, atol=1e-6)
    np.testing.assert_allclose(a.frustum.offsets, b.frustum.offsets, atol=1e-6)
  with pytest.raises(MwbxError, match=r"queries\[0\]: a query built from raw planes cannot be saved"):
    QuerySet((VolumeQuery(Frustum.box([0, 0, 0], [1, 1, 1])),)).save(tmp_path / "raw.yaml")
