"""How far each world is from satisfying each query: a graded twin of
:func:`mwbx.queries.evaluate_each` for searches that need a direction.

A gap is 0 exactly where ``evaluate_each`` says the query is met and positive
elsewhere, so a search that drives gaps to 0 solves the queries as the exact
kernels judge them. Where not met:

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

from mwbx.queries import joint as joint_lib
from mwbx.queries import orientation as orientation_lib
from mwbx.queries.query import Query, as_queries, body_radii, evaluate_each, selection_mask

MIN_GAP = 1e-4  # m (or rad): the gap of a failed query the stored points cannot grade


def _window_points(bank, window) -> np.ndarray:
  """bool[P] stored COM points in a window (seconds; the tail repeats the last point)."""
  n_points = bank.com.shape[1]
  t = np.arange(n_points) / float(bank.query_fps)
  t0, t1 = (None, None) if window is None else window
  inside = np.ones(n_points, bool)
  if t0 is not None:
    inside &= t >= t0 - 1e-9
  if t1 is not None:
    inside &= t <= t1 + 1e-9
  if not inside.any():  # a window between two points: the nearest one
    centre = 0.5 * ((t0 or 0.0) + (t[-1] if t1 is None else t1))
    inside[np.argmin(np.abs(t - centre))] = True
  return inside


def _frustum_gap(bank, query: Query, com: np.ndarray, radii: np.ndarray) -> np.ndarray:
  """f64[W] ungated measure of one volume query (see the module docstring)."""
  mask = selection_mask(bank, query.bodies)
  if not mask.any():
    return np.full(len(com), np.inf if query.include else 0.0)
  if query.radius == "auto" or query.shape == "geometry":
    radius = radii[mask]
  else:
    radius = np.full(int(mask.sum()), float(query.radius))
  points = com[:, _window_points(bank, query.window)][:, :, mask]  # [W, P, b, 3]
  # Outside distance per point: the largest plane distance, sphere pushed out.
  d = query.frustum.distances(points).max(axis=-1) - radius[None, None, :]  # [W, P, b]
  if query.include:
    per_body = np.maximum(d.min(axis=1), 0.0)
    return per_body.min(axis=1) if query.mode == "any" else per_body.max(axis=1)
  depth = np.maximum(-d.min(axis=1), 0.0)  # the deepest point inside
  return depth.max(axis=1) if query.mode == "any" else depth.min(axis=1)


def _joint_gap(bank, query: joint_lib.JointQuery) -> np.ndarray:
  turn = joint_lib.joint_turn(bank, query.joint, query.window, query.of)
  lo, hi = query.turn
  gap = np.zeros_like(turn)
  if lo is not None:
    gap = np.maximum(gap, lo - turn)
  if hi is not None:
    gap = np.maximum(gap, turn - hi)
  return gap


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
  com = radii = None
  for i, query in enumerate(queries):
    if isinstance(query, Query):
      if com is None:
        com = np.asarray(bank.com[np.arange(bank.n_worlds)], np.float32)
        radii = body_radii(bank.model(), bank.body_ids)
      gaps[:, i] = _frustum_gap(bank, query, com, radii)
    elif isinstance(query, orientation_lib.OrientationQuery):
      gaps[:, i] = orientation_lib.orientation_gap(bank, query, selection_mask(bank, query.bodies))
    else:
      gaps[:, i] = _joint_gap(bank, query)
  gaps = np.where(met, 0.0, np.maximum(np.nan_to_num(gaps, nan=np.inf), MIN_GAP))
  gaps[~np.asarray(bank.valid, bool)] = np.inf
  return gaps
