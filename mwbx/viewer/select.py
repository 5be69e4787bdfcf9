"""Which worlds to show, from world ids or a ranking (used by `mwbx view`).

World ids are `bank.world_ids` (what rankings print), as everywhere; lists of
them are read by :func:`mwbx.world_ids.parse_world_ids`.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from mwbx import queries as mq
from mwbx.errors import MwbxError
from mwbx.viewer.errors import ViewerError

# Worlds shown by a rank without top (`--rank METRIC` without `--top`).
DEFAULT_TOP = 4


def choose_worlds(bank, *, ids: Sequence[int] | None = None, top: int | None = None,
                  rank: str | None = None, queries=None,
                  flags: Mapping[str, str] | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
  """The world ids to play back and the worlds matching the queries.

  As ``mwbx query`` lists them: the best ``top`` worlds by a metric
  ("NAME[:sum|max]", mwbx.queries.rank) among those matching ``queries``;
  rank None: the query file's ranking, else the first matches in world
  order; and where no valid world matches every query, the worlds meeting
  the most of them (:func:`closest_note` says so).

  ids: explicit world ids. top: how many (default :data:`DEFAULT_TOP` with a
  rank). queries: a mwbx.queries.QuerySet or None. flags: how the caller
  spells ``ids``, ``top`` and ``rank``, for messages (e.g. ``{"ids":
  "--worlds"}``); default: as here.
  Returns (ids i64[n] or None for the viewer's default, match bool[W] or None).
  """
  named = {name: (flags or {}).get(name, name) for name in ("ids", "top", "rank")}
  if ids is not None and (top is not None or rank is not None):
    raise ViewerError(f"{named['ids']} cannot be combined with {named['top']}/{named['rank']}")
  match = None
  if queries is not None and len(queries.queries):
    match = np.asarray(mq.evaluate(bank, queries.queries), bool)
  if ids is not None:
    ids = np.asarray(list(ids), np.int64)
    try:
      bank.row_of(ids)
    except MwbxError as err:
      raise ViewerError(f"{named['ids']}: {err}") from None
    return ids, match
  if top is None and rank is None:
    if match is not None:
      first = np.asarray(bank.world_ids)[np.flatnonzero(match)[:1]]
      return (first if first.size else None), match
    return None, match
  k = DEFAULT_TOP if top is None else int(top)
  if k <= 0:
    raise ViewerError(f"{named['top']}: must be a positive number of worlds, got {k}")
  valid = np.asarray(bank.valid, bool)
  if match is not None and not match.any():  # (match holds valid worlds only)
    if not valid.any():
      raise ViewerError("no valid world in the bank; nothing to show")
    met = mq.constraints_satisfied(bank, queries.queries).astype(np.float64)
    ids, _ = mq.rank(bank, met, match=valid, top=k)
    return np.asarray(ids, np.int64), match
  by = rank if rank is not None else (queries.rank if queries is not None and queries.rank else None)
  if by is None:  # unranked: the first matches (or valid worlds) in world order
    rows = np.flatnonzero(valid if match is None else match)[:k]
    return np.asarray(bank.world_ids, np.int64)[rows], match
  descending = True if queries is None or rank is not None else queries.descending
  qs = () if queries is None else queries.queries
  ids, _ = mq.rank(bank, by, queries=qs, match=match, top=k, descending=descending)
  if len(ids) == 0:
    raise ViewerError(f"{named['rank']}: no valid world has that metric; nothing to show")
  return np.asarray(ids, np.int64), match


def closest_note(match: np.ndarray | None, bank) -> str:
  """What to tell a user whose shown worlds meet not every query: "" when
  some valid world does (or there are no queries)."""
  if match is None or match.any():  # match: valid worlds meeting every query
    return ""
  return "no valid world meets every query; showing the worlds that meet the most"
