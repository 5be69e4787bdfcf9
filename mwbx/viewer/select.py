"""Which worlds to show, from world ids or a ranking (used by `mwbx view`).

World ids are `bank.world_ids` (what rankings print), as everywhere; lists of
them are read by :func:`mwbx.world_ids.parse_world_ids`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from mwbx import queries as mq
from mwbx.errors import MwbxError
from mwbx.viewer.errors import ViewerError

# Worlds shown by `--rank METRIC` without `--top`.
DEFAULT_TOP = 4


def choose_worlds(bank, *, ids: Sequence[int] | None = None, top: int | None = None,
                  rank: str | None = None, queries=None) -> tuple[np.ndarray | None, np.ndarray | None]:
  """The world ids to play back and the worlds matching the queries.

  ids: explicit world ids. top/rank: the best `top` worlds by a metric
  ("NAME[:sum|max]", mwbx.queries.rank), among those matching `queries` when
  given; rank None with top uses the query file's ranking. queries: a
  mwbx.queries.QuerySet or None.
  Returns (ids i64[n] or None for the viewer's default, match bool[W] or None).
  """
  if ids is not None and (top is not None or rank is not None):
    raise ViewerError("--worlds cannot be combined with --top/--rank")
  match = None
  if queries is not None and len(queries.queries):
    match = np.asarray(mq.evaluate(bank, queries.queries), bool)
  if ids is not None:
    ids = np.asarray(list(ids), np.int64)
    try:
      bank.row_of(ids)
    except MwbxError as err:
      raise ViewerError(f"--worlds: {err}") from None
    return ids, match
  if top is None and rank is None:
    if match is not None:
      first = np.asarray(bank.world_ids)[np.flatnonzero(match)[:1]]
      return (first if first.size else None), match
    return None, match
  by = rank
  if by is None:
    if queries is None or not queries.rank:
      raise ViewerError("--top needs --rank METRIC (or a query file with a 'rank' section)")
    by = queries.rank
  k = DEFAULT_TOP if top is None else int(top)
  if k <= 0:
    raise ViewerError(f"--top: must be a positive number of worlds, got {k}")
  descending = True if queries is None else queries.descending
  qs = () if queries is None else queries.queries
  ids, _ = mq.rank(bank, by, queries=qs, match=match, top=k, descending=descending)
  if len(ids) == 0:
    raise ViewerError("--rank: no valid world matches the queries; nothing to show")
  return np.asarray(ids, np.int64), match
