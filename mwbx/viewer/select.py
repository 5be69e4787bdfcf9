"""Which worlds to show, from world ids or a ranking (used by `mwbx view`).

World ids are `bank.world_ids` (what rankings print), as everywhere.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from mwbx import queries as mq
from mwbx.errors import MwbxError
from mwbx.yaml_input import short_repr
from mwbx.viewer.errors import ViewerError

# Worlds shown by `--rank METRIC` without `--top`.
DEFAULT_TOP = 4
# Ids one range may name when it is not bounded by a bank's ids.
MAX_RANGE_IDS = 1_000_000


def parse_world_ids(text: str, flag: str = "--worlds", known=None) -> list[int]:
  """'3,17, 20..22' -> [3, 17, 20, 21, 22] (``a..b`` includes both ends); the
  message names the flag and the bad item.

  Args:
    text: ids and ranges, comma separated.
    flag: the flag or argument, for messages.
    known: optional i64[W] ids of the bank: a range then stands for the
      bank's ids within it (``0..1000000000`` is every world, not a billion
      ids); single ids are kept as given (an unknown one is an error later).
      Without it a range may hold at most :data:`MAX_RANGE_IDS` ids.
  """
  known = None if known is None else np.unique(np.asarray(known, np.int64))
  out: list[int] = []
  for item in text.split(","):
    item = item.strip()
    if not item:
      continue
    lo, dots, hi = item.partition("..")
    try:
      lo, hi = (int(lo), int(hi)) if dots else (int(item), int(item))
    except ValueError:
      raise ViewerError(f"{flag}: {short_repr(item)} is not a world id or range (expected e.g. 3,17,20..29)") from None
    if not dots:
      out.append(lo)
    elif known is not None:
      inside = known[(known >= lo) & (known <= hi)]
      if not inside.size:
        raise ViewerError(f"{flag}: the bank has no world in {lo}..{hi}")
      out.extend(int(i) for i in inside)
    elif hi - lo + 1 > MAX_RANGE_IDS:
      raise ViewerError(f"{flag}: {lo}..{hi} spans {hi - lo + 1:,} ids; at most {MAX_RANGE_IDS:,}")
    else:
      out.extend(range(lo, hi + 1))
  if not out:
    raise ViewerError(f"{flag}: no world ids in {short_repr(text)}")
  return out


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
