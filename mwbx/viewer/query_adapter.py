"""Colour classes of worlds from mwbx.queries queries (paper Fig. 5).

match: worlds satisfying every query (green); exclude: valid worlds that a
negative query rejects, i.e. whose path enters a red volume (red). Unstable
worlds are in neither.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from mwbx import queries as mq


def is_query(q: Any) -> bool:
  """A query of any type (:class:`mwbx.Query`), not a plain volume to draw."""
  return isinstance(q, mq.Query)


def is_negative(q: Any) -> bool:
  """An exclude query."""
  return not q.include


def evaluate_classes(bank, queries: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
  """(match bool[W], exclude bool[W]) from the mwbx.queries.Query items of
  `queries` (plain frustums in the list are drawn but not evaluated)."""
  real = [q for q in queries if is_query(q)]
  k = mq.kept(mq.evaluate_each(bank, real), np.array([not is_negative(q) for q in real], bool), bank.valid)
  return k.match, k.rejected
