"""Queries on a real sampled bank and the `mwbx query` command end to end."""

import json
import warnings
import pathlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.queries import Camera, Query, ScreenBox, evaluate, evaluate_each, first_entry
from mwbx.queries import load_queries, rank

import queries_reference as ref

REPO = pathlib.Path(__file__).parents[2]
EXAMPLE = REPO / "configs" / "queries" / "quickstart.yaml"


@pytest.fixture(scope="module")
def quick_bank(quickstart_config):
  return mwbx.sample(quickstart_config, n_worlds=8, key=jax.random.key(0))


@pytest.fixture(scope="module")
def saved_bank(quick_bank, tmp_path_factory):
  path = tmp_path_factory.mktemp("bank") / "quick"
  quick_bank.save(path)
  return path


def test_real_bank_matches_reference(quick_bank):
  cam = Camera.from_model(quick_bank.model, "front")
  queries = list(load_queries(EXAMPLE, quick_bank).queries)
  rng = np.random.default_rng(0)
  for _ in range(6):
    u = np.sort(rng.uniform(0, 1, 2))
    v = np.sort(rng.uniform(0, 1, 2))
    queries.append(Query.screen(
        cam, ScreenBox(u[0], v[0], u[1], v[1]), bodies=[rng.choice(["round", "box_a", "boxes"])],
        sign=rng.choice(["include", "exclude"]), mode=rng.choice(["any", "all"]),
        window=(float(rng.uniform(0, 2)), None), radius=[0.0, "auto"][rng.integers(2)]))
  expected = ref.evaluate_each(quick_bank, queries)
  np.testing.assert_array_equal(evaluate_each(quick_bank, queries), expected)
  assert 0 < expected.sum() < expected.size
  frustum = cam.frustum(ScreenBox(0.3, 0.3, 0.7, 0.7))
  for world in range(quick_bank.n_worlds):
    assert (first_entry(quick_bank, world, ["ball"], frustum)
            == ref.first_entry(quick_bank, world, ["ball"], frustum))


def run(capsys, *argv):
  code = cli.main(["query", *map(str, argv)])
  out = capsys.readouterr()
  return code, out.out, out.err


def test_cli_lists_the_matching_worlds(quick_bank, saved_bank, capsys):
  code, out, _ = run(capsys, saved_bank, EXAMPLE, "--json")
  assert code == 0
  report = json.loads(out)
  qs = load_queries(EXAMPLE, quick_bank)
  match = evaluate(quick_bank, qs.queries)
  assert [q["matches"] for q in report["queries"]] == evaluate_each(quick_bank, qs.queries).sum(0).tolist()
  if match.any():
    assert report["count"] == int(match.sum()) and not report["closest"]
    ids, values = rank(quick_bank, qs.rank, match=match, top=qs.top)
    assert [w["world"] for w in report["worlds"]] == ids.tolist()
    np.testing.assert_allclose([w["value"] for w in report["worlds"]], values)
  else:  # the closest worlds by constraints satisfied
    assert report["closest"] and report["ranked_by"] == "constraints_satisfied"


def test_cli_rank_and_top_override_the_file(quick_bank, saved_bank, tmp_path, capsys):
  path = tmp_path / "wide.yaml"
  path.write_text("camera: {mjcf: front}\nqueries:\n  - {box: [0, 0, 1, 1], bodies: [ball]}\n")
  code, out, _ = run(capsys, saved_bank, path, "--rank", "path_length:max", "--top", "3")
  assert code == 0
  lines = out.strip().splitlines()
  assert "of 8 valid worlds satisfy all 1 queries" in out
  ids, values = rank(quick_bank, "path_length:max", match=quick_bank.valid, top=3)
  listed = [int(line.split()[0]) for line in lines[-3:]]
  assert listed == ids.tolist() and lines[-4].split() == ["world", "path_length:max"]


def test_cli_errors_are_one_line(saved_bank, tmp_path, capsys):
  path = tmp_path / "bad.yaml"
  path.write_text("camera: {mjcf: front}\nqueries:\n  - {box: [0, 0, 1, 1], bodies: [wheel]}\n")
  code, out, err = run(capsys, saved_bank, path)
  assert code == 2 and out == ""
  assert err.count("\n") == 1 and "queries[0].bodies" in err and "wheel" in err and str(path) in err
  code, _, err = run(capsys, saved_bank, EXAMPLE, "--rank", "speed")
  assert code == 2 and "unknown metric 'speed'" in err
  code, _, err = run(capsys, saved_bank, EXAMPLE, "--top", "-1")
  assert code == 2 and err.count("\n") == 1 and "--top: must be >= 0, got -1" in err


def test_run_query_file_from_python_names_its_parameter(quick_bank):
  from mwbx.queries.report import run_query_file
  with pytest.raises(mwbx.MwbxError) as err:  # it named `mwbx query`'s --top
    run_query_file(quick_bank, EXAMPLE, top=-1)
  assert str(err.value) == "top: must be >= 0, got -1"


@pytest.mark.parametrize("camera, query, needle", [
    ("{eye: [1e300, -3, 1], target: [0, 0, 0.4], up: [0, 0, 1], fovy: 60, aspect: 1}",
     "{box: [0, 0, 1, 1], bodies: [ball]}", "eye"),
    ("{eye: [0, -3, 1], target: [0, 0, 0.4], up: [0, 0, 1], fovy: 60, aspect: 1}",
     "{box: [0, 0, 1e300, 1], bodies: [ball]}", "box"),
    ("{eye: [0, -3, 1], target: [0, 0, 0.4], up: [0, 0, 1], fovy: 60, aspect: 1}",
     "{box: [0, 0, 1, 1], bodies: [ball], near: 1, far: 1e300}", "far"),
    ("{eye: [0, -3, 1], target: [0, 0, 0.4], up: [0, 0, 1], fovy: 1e300, aspect: 1e300, orthographic: true}",
     "{box: [0, 0, 1, 1], bodies: [ball]}", "aspect"),
])
def test_huge_finite_numbers_get_one_line_and_no_warnings(saved_bank, tmp_path, capsys, camera, query, needle):
  # Numbers near the float64 limit overflowed the view math: numpy's warnings came before the error.
  path = tmp_path / "huge.yaml"
  path.write_text(f"camera: {camera}\nqueries:\n  - {query}\n")
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    code, _, err = run(capsys, saved_bank, path)
  assert code == 2 and not caught, [str(w.message) for w in caught]
  assert len(err.strip().splitlines()) == 1 and needle in err and "1e+09" in err, err
