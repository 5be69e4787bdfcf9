"""Metrics combined over selections, weighted scores and top-k ranking."""

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from mwbx.errors import MwbxError
from mwbx.queries import Query, Term, metric, rank, score
from mwbx.queries import metrics as metrics_lib

import queries_bank

W, B = 12, 5


def make(seed=0, metrics=None, flags=None):
  com = queries_bank.ballistic_paths(W, 10, B, seed=seed)
  return queries_bank.make_bank(com, metrics=metrics, flags=flags, seed=seed)


def reference_metric(bank, name, bodies, reduce):
  m = bank.metric_names.index(name)
  chosen = range(B) if bodies is None else sorted(set(bank.select_bodies(list(bodies)).tolist()))
  out = []
  for w in range(W):
    values = [float(bank.metrics[w, b, m]) for b in chosen]
    if reduce == "sum":
      out.append(sum(values))
    else:
      out.append(max(values) if values else -np.inf)
  return np.array(out)


def reference_rank(bank, values, eligible, top, descending):
  order = sorted((i for i in range(W) if eligible[i] and not np.isnan(values[i])),
                 key=lambda i: ((-values[i] if descending else values[i]), i))
  order = order[:top]
  return bank.world_ids[order], values[order]


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(queries_bank.METRIC_NAMES),
       bodies=st.sampled_from([None, ("b0",), ("arm",), ("even", "b1"), ()]),
       reduce=st.sampled_from(["sum", "max"]), seed=st.integers(0, 1000))
def test_metric_matches_reference(name, bodies, reduce, seed):
  bank = make(seed)
  np.testing.assert_array_equal(metric(bank, name, bodies, reduce),
                                reference_metric(bank, name, bodies, reduce))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 1000), top=st.integers(0, W + 2), descending=st.booleans(),
       ties=st.booleans(), data=st.data())
def test_rank_matches_sorted_reference(seed, top, descending, ties, data):
  rng = np.random.default_rng(seed)
  metrics = rng.uniform(0, 3, size=(W, B, 6)).astype(np.float32)
  if ties:
    metrics = np.round(metrics)  # many equal scores: ties go to the lower index
  flags = np.where(rng.random(W) < 0.2, queries_bank.FLAG_UNSTABLE, 1).astype(np.uint8)
  bank = make(seed, metrics=metrics, flags=flags)
  match = np.asarray(data.draw(st.lists(st.booleans(), min_size=W, max_size=W)))
  terms = [Term("path_length", ("b0", "b1"), "sum", 2.0), Term("collisions", None, "max", -0.5)]
  values = score(bank, terms)
  expected = (2.0 * reference_metric(bank, "path_length", ("b0", "b1"), "sum")
              - 0.5 * reference_metric(bank, "collisions", None, "max"))
  np.testing.assert_allclose(values, expected, rtol=1e-12)
  ids, vals = rank(bank, terms, match=match, top=top, descending=descending)
  want_ids, want_vals = reference_rank(bank, values, match & bank.valid, top, descending)
  np.testing.assert_array_equal(ids, want_ids)
  np.testing.assert_array_equal(vals, want_vals)


def test_rank_by_name_and_reduction_string():
  bank = make(3)
  ids, vals = rank(bank, "max_height:max", top=3)
  expected = reference_metric(bank, "max_height", None, "max")
  assert list(ids) == list(bank.world_ids[np.argsort(-expected, kind="stable")[:3]])
  np.testing.assert_array_equal(vals, np.sort(expected)[::-1][:3])


def test_constraints_satisfied_ranks_partial_matches_first():
  bank = make(5)
  # World i satisfies query "x" iff its b0 path reaches x <= -0.5, etc.
  qs = [Query.region([-9, -9, -9], [-0.5, 9, 9], bodies="b0"),
        Query.region([-9, -9, -9], [9, 9, 0.2], bodies="b0"),
        Query.region([0.5, -9, -9], [9, 9, 9], bodies="b2")]
  from mwbx.queries import constraints_satisfied
  counts = constraints_satisfied(bank, qs)
  ids, vals = rank(bank, "constraints_satisfied", queries=qs, top=W)
  assert list(vals) == sorted(counts.tolist(), reverse=True)
  assert vals[0] == counts.max() and len(set(counts.tolist())) > 1


def test_unstable_and_nan_worlds_are_never_ranked():
  metrics = np.ones((W, B, 6), np.float32)
  metrics[2] = 100.0
  metrics[4] = np.nan
  flags = np.ones(W, np.uint8)
  flags[2] |= queries_bank.FLAG_UNSTABLE
  bank = make(0, metrics=metrics, flags=flags)
  ids, _ = rank(bank, "rest_time", top=W)
  assert bank.world_ids[2] not in ids and bank.world_ids[4] not in ids and len(ids) == W - 2


def test_metric_errors_are_clear():
  bank = make(0)
  with pytest.raises(MwbxError, match="unknown metric 'speed'"):
    metric(bank, "speed")
  with pytest.raises(MwbxError, match="METRIC"):
    metrics_lib.parse_term("rest_time:median")
  with pytest.raises(MwbxError, match="shape"):
    rank(bank, np.zeros(W + 1))


@settings(max_examples=80, deadline=None)
@given(values=st.lists(st.sampled_from([-np.inf, -1.0, 0.0, 0.5, 2.0, np.inf]), min_size=1, max_size=30),
       data=st.data(), descending=st.booleans())
def test_top_k_orders_like_a_stable_sort(values, data, descending):
  values = np.asarray(values)
  n = len(values)
  eligible = np.asarray(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)))
  k = data.draw(st.integers(0, n))
  got = metrics_lib.top_k(values, eligible, k, descending)
  # Eligible worlds by value, then the ineligible ones in index order.
  best_first = sorted(range(n), key=lambda i: (not eligible[i], (
      -values[i] if descending else values[i]) if eligible[i] else 0.0, i))
  assert got.tolist() == best_first[:k]
