"""Which bodies' geometry meets a volume in a window (the culled evaluation
of whole-geometry queries over a :class:`~.geometry.GeometryIndex`).

Stages, each conservative (a stage only drops what provably misses, or
keeps what provably hits):
  1. one jitted pass over every kept frame of a body in every world: its
     bounding sphere (radius reach + margin) apart from some plane -> miss;
     the sphere of radius reach wholly inside the volume -> hit;
  2. per geom, the core's extent along each plane: apart by more than its
     radius plus margin -> miss; a core vertex inside the volume, or a core
     vertex whose projection onto a plane lies in the volume within the
     radius plus margin -> hit; else the nearest core vertex's exact distance
     to the volume within it -> hit (for a point core, beyond it -> miss);
  3. the rest (near an edge or corner of the volume): the exact
     separating-axis test (:mod:`.convex`).
"""

from __future__ import annotations

from functools import partial

import jax
from jax import numpy as jp
import numpy as np

from mwbx.queries import convex
from mwbx.queries.frustum import Frustum
from mwbx.queries.geometry import GeometryIndex
from mwbx.queries.poses import quat_matrix


def frame_margins(index: GeometryIndex, window) -> tuple[np.ndarray, "_Margins"]:
  """The kept frames a window reaches and their margins.

  Args:
    index: the bank's geometry index.
    window: (t0, t1) seconds (None ends open) or None.

  Returns:
    (relevant bool[K]: the ends of every interval between kept frames that
    overlaps the window, or the nearest kept frame when the window lies past
    the end; margin: indexed as f32[B, W, K], the largest margin of a
    relevant interval at each frame, 0 where none).
  """
  relevant, overlap = _relevant(index.times, window)
  return relevant, _Margins(index.sweep, overlap)


def _relevant(times: np.ndarray, window) -> tuple[np.ndarray, np.ndarray]:
  """(relevant bool[K] kept frames, overlap bool[K - 1] intervals) of a window."""
  t0, t1 = (None, None) if window is None else window
  end = float(times[-1])
  t0 = 0.0 if t0 is None else min(max(float(t0), 0.0), end)
  t1 = end if t1 is None else min(max(float(t1), 0.0), end)
  overlap = (times[:-1] <= t1) & (times[1:] >= t0)  # [K - 1]
  relevant = np.zeros(len(times), bool)
  relevant[:-1] |= overlap
  relevant[1:] |= overlap
  if not relevant.any():  # a single kept frame
    relevant[np.argmin(np.abs(times - t0))] = True
  return relevant, overlap


class _Margins:
  """margin[b, w, k]: the largest sweep margin of a relevant interval at kept
  frame k (0 where none), computed for the entries asked for only."""

  def __init__(self, sweep: np.ndarray, overlap: np.ndarray):
    self.sweep, self.overlap = sweep, overlap

  def __getitem__(self, key) -> np.ndarray:
    b, w, k = key
    k = np.asarray(k)
    n_int = len(self.overlap)
    before = np.maximum(k - 1, 0)
    after = np.minimum(k, n_int - 1)
    m0 = np.where((k >= 1) & self.overlap[before], self.sweep[b, w, before], 0.0)
    m1 = np.where((k < n_int) & self.overlap[after], self.sweep[b, w, after], 0.0)
    return np.maximum(m0, m1).astype(np.float32)


@jax.jit
def _sphere_stage(com, sweep, overlap, relevant, valid, body_mask, normals, offsets, grow, reach, tol):
  """Stage 1 for every body at once: (hit bool[B, W] a relevant frame's
  geometry is wholly inside, candidates bool[B, W, K]).

  com f32[B, 3, W, K]; sweep f32[B, W, K - 1]; overlap bool[K - 1]; relevant
  bool[K]; valid bool[W]; body_mask bool[B] (bodies with geoms, selected);
  normals f32[F, 3]; offsets f32[F]; grow f32[B]: reach + codec bound; reach
  f32[B]; tol: metres.
  """
  def one(com, sweep, selected, grow, reach):
    m = jp.where(overlap[None], sweep, 0.0)
    zero = jp.zeros_like(m[:, :1])
    margin = jp.maximum(jp.concatenate([m, zero], axis=1), jp.concatenate([zero, m], axis=1))
    apart = jp.zeros(margin.shape, bool)
    inside = jp.ones(margin.shape, bool)
    for f in range(normals.shape[0]):  # F <= 6, unrolled
      d = (com[0] * normals[f, 0] + com[1] * normals[f, 1]) + com[2] * normals[f, 2] - offsets[f]
      apart |= d > grow + margin + tol
      inside &= d < -(reach + tol)
    ok = relevant[None] & valid[:, None] & selected
    hit = jp.any(inside & ok, axis=1)
    return hit, ok & ~apart & ~hit[:, None]

  def skipped(*_):
    return jp.zeros(com.shape[2], bool), jp.zeros(com.shape[2:4], bool)

  def per_body(i):  # a real branch: unselected bodies cost nothing
    return jax.lax.cond(body_mask[i], one, skipped, com[i], sweep[i], body_mask[i], grow[i], reach[i])

  return jax.lax.map(per_body, jp.arange(com.shape[0]))


def geometry_hits(index: GeometryIndex, frustum: Frustum, body_mask: np.ndarray, window) -> np.ndarray:
  """Whether each selected body's geometry meets the volume in the window.

  Args:
    index: the bank's geometry index.
    frustum: the volume.
    body_mask: bool[B] bodies to test; others report False.
    window: (t0, t1) seconds or None.

  Returns:
    bool[W, B]; False for unselected bodies, bodies without geoms and
    invalid worlds.
  """
  n_bodies, n_worlds = index.com.shape[:2]
  hits = np.zeros((n_worlds, n_bodies), bool)
  relevant, overlap = _relevant(index.times, window)
  normals = frustum.normals.astype(np.float64)
  offsets = frustum.offsets
  volume = None
  tol = 1e-6 * (1.0 + float(np.max(np.abs(index.hi))))
  com_d, sweep_d, valid_d = index.device()
  selected = np.asarray(body_mask, bool) & np.array([bool(c) for c in index.cores])
  hit, cand = _sphere_stage(com_d, sweep_d, jp.asarray(overlap), jp.asarray(relevant), valid_d,
                            jp.asarray(selected), jp.asarray(frustum.normals), jp.asarray(offsets, jp.float32),
                            jp.asarray(index.reach + index.codec, jp.float32),
                            jp.asarray(index.reach, jp.float32), np.float32(tol))
  hits[:] = np.asarray(hit).T
  cand = np.asarray(cand)
  margin = _Margins(index.sweep, overlap)
  for b in np.flatnonzero(selected):
    worlds, frames = np.nonzero(cand[b])
    m = margin[b, worlds, frames]
    # A frame at rest repeats the previous one: skip it if that one is tested
    # with at least its margin.
    prev = np.maximum(frames - 1, 0)
    again = index.repeat[b, worlds, frames] & relevant[prev] & (frames > 0) & (m <= margin[b, worlds, prev])
    worlds, frames, m = worlds[~again], frames[~again], m[~again].astype(np.float64) + index.codec[b]
    if worlds.size == 0:
      continue
    # In rounds of 1, 2, 4, ... candidate frames per world (in time order): a
    # world is done at its first hit, which for most hits comes early.
    rank = np.arange(worlds.size) - np.searchsorted(worlds, worlds)
    lo = 0
    while lo <= rank.max():
      hi = 2 * lo + 1
      take = (rank >= lo) & (rank < hi)
      take &= ~hits[worlds, b]
      if take.any():
        if volume is None:
          volume = convex.clipped(frustum, index.lo, index.hi)
        found = _exact_stage(index, b, worlds[take], frames[take], m[take], normals, offsets, volume, tol)
        hits[worlds[take][found], b] = True
      lo = hi
  return hits & index.valid[:, None]


def _exact_stage(index, b, worlds, frames, m, normals, offsets, volume, tol) -> np.ndarray:
  """Stages 2 and 3 for candidate frames of body b: bool[n] its geometry
  (grown by m f64[n] plus each geom's radius) meets the volume."""
  found = np.zeros(worlds.size, bool)
  com = index.com[b, worlds, frames].astype(np.float64)
  rotation = quat_matrix(index.quat[b, worlds, frames].astype(np.float64))  # [n, 3, 3]
  for core in index.cores[b]:
    todo = np.flatnonzero(~found)
    if todo.size == 0:
      break
    r_, m_ = rotation[todo], m[todo]
    points = com[todo][:, None] + np.einsum("nij,vj->nvi", r_, core.vertices - index.ipos[b])  # [n, V, 3]
    grow = core.radius + m_
    dist = points @ normals.T - offsets  # [n, V, F]
    apart = np.any(dist.min(axis=1) > (grow + tol)[:, None], axis=1)
    near = ~apart & _near_face(points, dist, normals, grow)
    found[todo[near]] = True
    rest = np.flatnonzero(~apart & ~near)
    if rest.size == 0:
      continue
    # The nearest core vertex's exact distance: an upper bound on the core's
    # (its distance, for a point core).
    close = convex.point_distances(points[rest], volume).min(axis=1) <= grow[rest]
    found[todo[rest[close]]] = True
    rest = rest[~close]
    if rest.size == 0 or len(core.vertices) == 1:
      continue
    far = convex.separated(points[rest], r_[rest], core.normals, core.directions, core.edges,
                           grow[rest], volume)
    found[todo[rest[~far]]] = True
  return found


def _near_face(points: np.ndarray, dist: np.ndarray, normals: np.ndarray, grow: np.ndarray) -> np.ndarray:
  """bool[n]: a core vertex lies in the volume, or its projection onto one of
  the volume's planes does and is at most `grow` away (points f64[n, V, 3],
  dist f64[n, V, F] their plane distances): then the shape meets the volume."""
  inside = np.all(dist <= 0.0, axis=2)  # [n, V]
  if inside.any(axis=1).all():
    return np.ones(len(points), bool)
  # Projection of vertex v onto plane i: distances change by -d_vi (n_i·n_j).
  cos = normals @ normals.T  # [F, F]
  d = np.maximum(dist, 0.0)
  moved = dist[:, :, None, :] - d[:, :, :, None] * cos[None, None]  # [n, V, i, j]
  ok = np.all(moved <= 0.0, axis=3) & (d <= grow[:, None, None])  # projection in the volume, close enough
  return inside.any(axis=1) | ok.any(axis=(1, 2))


