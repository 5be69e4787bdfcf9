"""Ranking metrics (paper §4.3): per-body tables combined over a selection.

The bank holds `metrics: f32[W, B, M]` computed while sampling, one column
per name in `bank.metric_names` (angular_travel rad, rest_time s, collisions,
orientation_error rad, path_length m, max_height m). A Term picks one metric,
a selection of bodies/objects/groups and a reduction (sum or max over the
selected bodies) and a weight; a score is the weighted sum of terms. The
query-dependent "constraints_satisfied" metric counts how many of the given
queries each world satisfies, so worlds that satisfy most of them surface
when none satisfies all. An orientation query's error (radians, see
:func:`orientation_error`) ranks too: a Term with ``query`` set to an
:class:`~mwbx.OrientationQuery` scores its error instead of a stored metric.
Ranking is a top-k (partition, then a sort of the k best) over the scores of
the eligible worlds; unstable worlds are never ranked.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries import query as query_lib
from mwbx.queries.selection import selection_mask
from mwbx.queries.selection import turning_mask

CONSTRAINTS = "constraints_satisfied"
REDUCTIONS = ("sum", "max")


class Term(NamedTuple):
  """One weighted metric over a selection of bodies.

  metric: a name in bank.metric_names or "constraints_satisfied".
  bodies: body/object/group names, or None for every tracked body.
  reduce: "sum" or "max" over the selected bodies.
  weight: factor in the score.
  query: an OrientationQuery whose error (radians) is the metric (metric
    "orientation_error"; bodies None: the query's own), or None.
  """

  metric: str
  bodies: tuple[str, ...] | None = None
  reduce: str = "sum"
  weight: float = 1.0
  query: object = None


def parse_term(spec: str) -> Term:
  """"METRIC" or "METRIC:sum" / "METRIC:max" -> Term."""
  name, _, reduce = str(spec).partition(":")
  reduce = reduce or "sum"
  if not name or reduce not in REDUCTIONS:
    raise MwbxError(f"rank: expected METRIC[:sum|max], got {spec!r}")
  return Term(name, None, reduce, 1.0)


def as_terms(by) -> tuple[Term, ...]:
  """A metric name, "NAME:max", a Term or a sequence of them -> tuple."""
  if isinstance(by, (str, Term)):
    by = (by,)
  terms = tuple(parse_term(t) if isinstance(t, str) else t for t in by)
  for t in terms:
    if not isinstance(t, Term):
      raise MwbxError(f"rank: expected metric names or Terms, got {type(t).__name__}")
  return terms


# Metrics of a body's turning, which a flex's vertex bodies (slide joints only) never do.
ROTATIONAL = ("angular_travel", "orientation_error")


def metric(bank, name: str, bodies=None, reduce: str = "sum") -> np.ndarray:
  """One precomputed metric combined over a selection: f64[W].

  Args:
    bank: the bank.
    name: one of bank.metric_names.
    bodies: body/object/group names, or None for every tracked body.
    reduce: "sum" or "max" over the selected bodies (an empty selection
      gives 0 for sum and -inf for max).

  A flex's vertex bodies never turn: the rotational metrics (:data:`ROTATIONAL`)
  leave them out and refuse a name that selects only them
  (:func:`~mwbx.queries.selection.turning_mask`), as orientation queries do.
  """
  names = tuple(bank.metric_names)
  if name not in names:
    raise MwbxError(f"metric: unknown metric {name!r} (known: {', '.join(names + (CONSTRAINTS,))})")
  if reduce not in REDUCTIONS:
    raise MwbxError(f"metric {name!r}: reduce must be one of {REDUCTIONS}, got {reduce!r}")
  # A flex's vertices have no orientation: left out, or refused by name.
  mask = turning_mask(bank, bodies, f"metric {name!r}") if name in ROTATIONAL else selection_mask(bank, bodies)
  column = np.asarray(bank.metrics[:, :, names.index(name)], np.float64)[:, mask]  # [W, k]
  if reduce == "sum":
    return np.sum(column, axis=1)
  return np.max(column, axis=1, initial=-np.inf)


def orientation_error(bank, query, bodies=None, reduce: str = "max") -> np.ndarray:
  """An orientation query's error per world, radians: f64[W].

  Per body, the angle to the goal at the world's last frame (no window) or
  the largest over the window; combined over the query's bodies (or
  `bodies`) by "max" or "sum". Rank ascending to list the most upright
  worlds first.

  Example::

    q = mwbx.OrientationQuery(bodies="S", axis="z", within_deg=15)
    ids, err = mwbx.rank(bank, mwbx.orientation_error(bank, q), descending=False)
  """
  if getattr(query, "error_metric", None) != "orientation_error":
    raise MwbxError(f"orientation_error: expected an OrientationQuery, got {type(query).__name__}")
  if reduce not in REDUCTIONS:
    raise MwbxError(f"orientation_error: reduce must be one of {REDUCTIONS}, got {reduce!r}")
  return query.error(bank, reduce, bodies)


def score(bank, terms, queries=()) -> np.ndarray:
  """Weighted sum of terms: f64[W].

  Args:
    bank: the bank.
    terms: metric names ("NAME[:sum|max]"), Terms, or a sequence of them.
    queries: the queries counted by a "constraints_satisfied" term.
  """
  terms = as_terms(terms)
  if not terms:
    raise MwbxError("rank: no metric given")
  total = np.zeros(bank.n_worlds)
  for t in terms:
    if not math.isfinite(float(t.weight)):
      raise MwbxError(f"rank: weight of {t.metric!r} must be finite, got {t.weight!r}")
    if t.metric == CONSTRAINTS:
      value = query_lib.constraints_satisfied(bank, queries).astype(np.float64)
    elif t.query is not None:  # the named query's own error (an orientation query's angle)
      value = t.query.error(bank, t.reduce, t.bodies)
    else:
      value = metric(bank, t.metric, t.bodies, t.reduce)
    total = total + float(t.weight) * value
  return total


def rank(bank, by, *, queries=(), match=None, top: int = 10,
         descending: bool = True) -> tuple[np.ndarray, np.ndarray]:
  """The best worlds by a score, via top-k.

  Args:
    bank: the bank.
    by: metric names ("NAME[:sum|max]"), Terms, or a score array f[W].
    queries: queries for a "constraints_satisfied" term.
    match: bool[W] worlds eligible for ranking (e.g. `evaluate(bank, qs)`);
      None: every world. Unstable worlds and NaN scores are never ranked.
    top: how many worlds to return at most.
    descending: highest score first (False: lowest first).

  Returns:
    (world ids i64[k] from bank.world_ids, scores f64[k]) with k <= top,
    best first; ties go to the lower world index.
  """
  if isinstance(by, np.ndarray) or isinstance(by, jax.Array):
    values = np.asarray(by, np.float64)
    if values.shape != (bank.n_worlds,):
      raise MwbxError(f"rank: a score array must have shape ({bank.n_worlds},), got {values.shape}")
  else:
    values = score(bank, by, queries)
  if int(top) < 0:
    raise MwbxError(f"top: must be >= 0, got {top}")
  eligible = np.asarray(bank.valid, bool) & ~np.isnan(values)
  if match is not None:
    match = np.asarray(match, bool)
    if match.shape != (bank.n_worlds,):
      raise MwbxError(f"rank: match must be bool[{bank.n_worlds}], got shape {match.shape}")
    eligible &= match
  k = min(int(top), bank.n_worlds)
  order = top_k(values, eligible, k, descending)
  order = order[: min(k, int(eligible.sum()))]
  return np.asarray(bank.world_ids)[order].astype(np.int64), values[order]


def top_k(values: np.ndarray, eligible: np.ndarray, k: int,
          descending: bool = True) -> np.ndarray:
  """Indices i64[k] of the k best values, eligible ones first, ties to the
  lower index: a partition to the k-th best key, then a sort of those only.

  Args:
    values: f64[W] scores. eligible: bool[W]. k: 0 <= k <= W.
    descending: highest first (else lowest first).
  """
  key = np.asarray(values, np.float64) if descending else -np.asarray(values, np.float64)
  # Eligible worlds must come before ineligible ones even at -inf.
  key = np.where(eligible, np.maximum(key, np.finfo(np.float64).min), -np.inf)
  n = len(key)
  if k <= 0:
    return np.zeros(0, np.int64)
  if k < n:
    kth = np.partition(key, n - k)[n - k]  # the k-th largest key
    chosen = np.flatnonzero(key >= kth)
  else:
    chosen = np.arange(n)
  order = chosen[np.lexsort((chosen, -key[chosen]))]
  return order[:k].astype(np.int64)
