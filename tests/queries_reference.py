"""Slow, obvious references for mwbx.queries: plain Python loops.

Distances use Python floats (IEEE float64) with the same expression as the
kernels, `((n0*x + n1*y) + n2*z) - off`, on float32 inputs, so the answers
must be identical, including for points exactly on planes.
"""

from __future__ import annotations

import math

import numpy as np


def distances(point, normals, offsets) -> list[float]:
  x, y, z = (float(c) for c in point)
  return [((x * float(n[0]) + y * float(n[1])) + z * float(n[2])) - float(off)
          for n, off in zip(normals, offsets)]


def segment_enter(a, b, normals, offsets, s0: float, s1: float) -> float | None:
  """Smallest parameter in [s0, s1] of segment a->b inside the volume, or None."""
  da, db = distances(a, normals, offsets), distances(b, normals, offsets)
  lo, hi = s0, s1
  for x, y in zip(da, db):
    if x > 0 and y > 0:
      return None
    if x > 0 >= y:
      lo = max(lo, x / (x - y))
    elif x <= 0 < y:
      hi = min(hi, x / (x - y))
  return lo if lo <= hi else None


def path_entry(points, normals, offsets, w0: float, w1: float) -> float | None:
  """Earliest k + s (segment units) at which a path f32[P, 3] is inside the
  volume within the window [w0, w1] (segment units), or None."""
  points = np.asarray(points, np.float32)
  if len(points) == 1:
    points = np.concatenate([points, points])
  best = None
  for k in range(len(points) - 1):
    u0, u1 = w0 - k, w1 - k
    if not (u1 >= 0 and u0 <= 1):
      continue
    s = segment_enter(points[k], points[k + 1], normals, offsets, max(u0, 0.0), min(u1, 1.0))
    if s is not None and (best is None or k + s < best):
      best = k + s
  return best


def window_units(window, fps: float, n_points: int) -> tuple[float, float]:
  n_seg = max(n_points - 1, 1)
  t0, t1 = (None, None) if window is None else window
  w0 = 0.0 if t0 is None else min(max(t0 * fps, 0.0), float(n_seg))
  w1 = float(n_seg) if t1 is None else min(max(t1 * fps, 0.0), float(n_seg))
  return w0, w1


def bounding_radius(model, body_id: int) -> float:
  best = 0.0
  for g in range(model.ngeom):
    if model.geom_bodyid[g] == body_id:
      d = math.dist(model.geom_pos[g], model.body_ipos[body_id])
      best = max(best, d + float(model.geom_rbound[g]))
  return best


def path_hits(bank, query) -> np.ndarray:
  """bool[W, B]: which selected paths meet the query volume (valid worlds)."""
  w_count, p_count, b_count, _ = bank.com.shape
  selected = set(range(b_count)) if query.bodies is None else (
      set(int(i) for i in bank.select_bodies(list(query.bodies))) if query.bodies else set())
  model = bank.model if query.radius == "auto" else None
  w0, w1 = window_units(query.window, bank.query_fps, p_count)
  hits = np.zeros((w_count, b_count), bool)
  for w in range(w_count):
    if bank.flags[w] & 4:
      continue
    for b in sorted(selected):
      r = bounding_radius(model, int(bank.body_ids[b])) if model is not None else float(query.radius)
      offsets = [float(o) + r for o in query.frustum.offsets]
      hits[w, b] = path_entry(bank.com[w, :, b], query.frustum.normals, offsets, w0, w1) is not None
  return hits


def evaluate_each(bank, queries) -> np.ndarray:
  """bool[W, Q] by the definitions in mwbx.queries.query, with loops."""
  out = np.zeros((bank.com.shape[0], len(queries)), bool)
  for q_i, query in enumerate(queries):
    hits = path_hits(bank, query)
    b_count = bank.com.shape[2]
    selected = list(range(b_count)) if query.bodies is None else (
        sorted(set(int(i) for i in bank.select_bodies(list(query.bodies)))) if query.bodies else [])
    for w in range(bank.com.shape[0]):
      if bank.flags[w] & 4:
        continue
      per_body = [bool(hits[w, b]) for b in selected]
      met = any(per_body) if query.mode == "any" else all(per_body)
      out[w, q_i] = met if query.sign == "include" else not met
  return out


def first_entry(bank, world, bodies, frustum, window=None, radius=0.0) -> float | None:
  """Earliest entry time in seconds over the selected bodies, or None."""
  b_count = bank.com.shape[2]
  selected = range(b_count) if bodies is None else sorted(
      set(int(i) for i in bank.select_bodies(list(bodies))))
  w0, w1 = window_units(window, bank.query_fps, bank.com.shape[1])
  model = bank.model
  best = None
  for b in selected:
    r = bounding_radius(model, int(bank.body_ids[b])) if radius == "auto" else float(radius)
    offsets = [float(o) + r for o in frustum.offsets]
    e = path_entry(bank.com[world, :, b], frustum.normals, offsets, w0, w1)
    if e is not None and (best is None or e < best):
      best = e
  return None if best is None else best / bank.query_fps
