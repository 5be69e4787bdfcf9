"""How far each world is from satisfying each query: a graded twin of
:func:`mwbx.queries.evaluate_each` for searches that need a direction.

A gap is 0 exactly where ``evaluate_each`` says the query is met and positive
elsewhere, so a search that drives gaps to 0 solves the queries as the exact
kernels judge them. Each query type grades itself (:meth:`Query.gap`); where
not met:

* an include query: how far the selected bodies' stored COM points in the
  window stay outside the volume (for a point, the largest signed distance to
  the volume's planes, swept radius included; over the window the closest
  point; over the bodies the closest (``any``) or the farthest (``all``)),
  metres;
* an exclude query: how deep the offending bodies go inside (the deepest
  point; ``any``: the deepest body, ``all``: the shallowest), metres;
* a joint query: how far the joint's turn lies outside its range, radians
  or metres;
* a whole-geometry query: as an include or exclude query on the COM points
  swept by each body's bounding sphere (``radius="auto"``): the geometry lies
  in that sphere, so the measure points the same way;
* an orientation query: how far the angle error exceeds the allowed angle
  (include) or lies inside it (exclude), radians.

A failed query whose measure is 0 (e.g. a segment crosses a corner between
two stored points) gets :data:`MIN_GAP`. Unstable worlds get ``inf``.
"""

from __future__ import annotations

import numpy as np

from mwbx.queries.query import as_queries, columns_by_type, evaluate_each

MIN_GAP = 1e-4  # m (or rad): the gap of a failed query the stored points cannot grade


def query_gaps(bank, queries) -> np.ndarray:
  """How far each world is from meeting each query.

  Args:
    bank: a bank (its stored COM polylines are read whole, so for a big
      lazily opened bank pass the part to grade, e.g. refined worlds).
    queries: a query, a list of them or a :class:`~mwbx.QuerySet`.

  Returns:
    f64[W, Q] gaps, metres for volume queries, radians or metres for joint
    queries and radians for orientation queries: 0 where ``evaluate_each`` is True, at least :data:`MIN_GAP`
    where it is False, ``inf`` for unstable worlds.

  Example::

    gaps = mwbx.queries.query_gaps(bank, mwbx.load_queries("q.yaml", bank=bank))
    nearest = bank.world_ids[np.argmin(gaps.sum(axis=1))]
  """
  queries = as_queries(queries)
  met = evaluate_each(bank, queries)
  gaps = np.zeros((bank.n_worlds, len(queries)))
  if bank.n_worlds == 0 or not queries:
    return gaps
  for kind, columns in columns_by_type(queries).items():  # one type shares its reads (Query.gap_many)
    gaps[:, columns] = kind.gap_many(bank, [queries[i] for i in columns])
  gaps = np.where(met, 0.0, np.maximum(np.nan_to_num(gaps, nan=np.inf), MIN_GAP))
  gaps[~np.asarray(bank.valid, bool)] = np.inf
  return gaps
