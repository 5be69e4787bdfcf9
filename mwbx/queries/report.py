"""A query file applied to a bank: matching worlds, optionally ranked.

This is what `mwbx query BANK QUERIES.yaml` prints. When no world satisfies
every query, the worlds satisfying the most of them are listed instead
(paper §4.3), so there is always something to refine.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Mapping

import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries import metrics as metrics_lib
from mwbx.queries import query as query_lib
from mwbx.queries.query_file import load_queries


@dataclasses.dataclass(frozen=True)
class QueryReport:
  """Result of a query file on a bank.

  queries: per query (name, sign, number of worlds satisfying it).
  count: worlds satisfying all queries. valid: worlds that can match.
  ranked_by: the score's description ("" if unranked).
  world_ids: i64[k] listed worlds, best first. values: f64[k] their scores
    (NaN if unranked). closest: True when no world satisfies all queries and
    the list holds the worlds satisfying the most (values = that count).
  """

  queries: tuple[tuple[str, str, int], ...]
  count: int
  valid: int
  ranked_by: str
  world_ids: np.ndarray
  values: np.ndarray
  closest: bool

  def to_dict(self) -> dict:
    return {
        "queries": [dict(name=n, sign=s, matches=m) for n, s, m in self.queries],
        "count": self.count,
        "valid_worlds": self.valid,
        "ranked_by": self.ranked_by or None,
        "closest": self.closest,
        "worlds": [dict(world=int(w), value=None if np.isnan(v) else float(v))
                   for w, v in zip(self.world_ids, self.values)],
    }

  def format(self) -> str:
    width = max([5] + [len(n) for n, _, _ in self.queries])
    lines = [f"{'query':<{width}}  {'sign':<8} {'worlds':>6}"]
    lines += [f"{n:<{width}}  {s:<8} {m:>6}" for n, s, m in self.queries]
    n_queries = len(self.queries)
    lines.append(f"{self.count} of {self.valid} valid worlds satisfy all {n_queries} queries")
    if self.closest:
      lines.append(f"closest worlds (constraints satisfied out of {n_queries}):")
    if len(self.world_ids):
      label = self.ranked_by or ""
      lines.append(f"{'world':>8}  {label}".rstrip())
      for w, v in zip(self.world_ids, self.values):
        lines.append(f"{int(w):>8}" + ("" if np.isnan(v) else f"  {v:.6g}"))
    return "\n".join(lines)


def _describe(terms) -> str:
  parts = []
  for t in terms:
    name = t.metric if t.metric == metrics_lib.CONSTRAINTS else f"{t.metric}:{t.reduce}"
    if t.bodies:
      name += f"[{','.join(t.bodies)}]"
    parts.append(name if t.weight == 1 else f"{t.weight:g}*{name}")
  return " + ".join(parts)


def run_query_file(bank, path: str | os.PathLike, rank: str | None = None,
                   top: int | None = None, descending: bool | None = None,
                   under: int | None = None, flags: Mapping[str, str] | None = None) -> QueryReport:
  """Loads a query file, evaluates it on the bank and ranks the matches.

  Args:
    bank: the bank.
    path: the query YAML (see `query_file`).
    rank: "METRIC[:sum|max]" overriding the file's ranking (highest first
      unless `descending` says otherwise); None: the file's ranking and order
      (or unranked, in world order).
    top: worlds to list at most (None: the file's `top`, else all matches).
    descending: overrides the order.
    under: a world id: only it and the worlds refined from it (directly or
      not) are counted and listed.
    flags: how the caller spells ``top``, for messages (e.g. ``{"top":
      "--top"}``); default: as here.
  """
  if top is not None and top < 0:
    raise MwbxError(f"{(flags or {}).get('top', 'top')}: must be >= 0, got {top}")
  qs = load_queries(path, bank)
  each = query_lib.evaluate_each(bank, qs.queries)
  valid = np.asarray(bank.valid, bool)
  if under is not None:
    valid = valid & bank.under(under)
    each = each & valid[:, None]
  match = np.all(each, axis=1) & valid
  terms = metrics_lib.as_terms(rank) if rank else qs.rank
  top = qs.top if top is None else top
  if descending is None:
    descending = True if rank else qs.descending
  summary = tuple((q.name, q.sign, int(each[:, i].sum())) for i, q in enumerate(qs.queries))
  closest = bool(qs.queries) and not match.any() and valid.any()
  if closest:
    counts = np.sum(each, axis=1).astype(np.float64)
    ids, values = metrics_lib.rank(bank, counts, match=valid, top=10 if top is None else top)
    return QueryReport(summary, 0, int(valid.sum()), metrics_lib.CONSTRAINTS, ids, values, True)
  if terms:
    k = int(match.sum()) if top is None else top
    ids, values = metrics_lib.rank(bank, terms, queries=qs.queries, match=match, top=k,
                                   descending=descending)
    ranked_by = _describe(terms)
  else:
    rows = np.flatnonzero(match)[:top]
    ids, values, ranked_by = np.asarray(bank.world_ids)[rows], np.full(len(rows), np.nan), ""
  return QueryReport(summary, int(match.sum()), int(valid.sum()), ranked_by,
                     np.asarray(ids, np.int64), np.asarray(values, np.float64), False)
