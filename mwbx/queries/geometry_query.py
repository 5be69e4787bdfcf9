"""Which bodies' geometry meets a volume in a window (the culled evaluation
of whole-geometry queries over a :class:`~.geometry.GeometryIndex`).

Stages, each conservative (a stage only drops what provably misses, or
keeps what provably hits):
  1. chunk boxes of grown bounding spheres against the volume's planes;
  2. each kept frame's bounding sphere (radius reach + margin): apart from
     some plane -> miss; wholly inside the volume (radius reach) -> hit;
  3. per geom, the core's extent along each plane: apart by more than its
     radius plus margin -> miss; a core vertex inside the volume -> hit;
  4. the rest: the exact separating-axis test (:mod:`.convex`).
"""

from __future__ import annotations

import numpy as np

from mwbx.queries import convex
from mwbx.queries.frustum import Frustum
from mwbx.queries.geometry import CHUNK, GeometryIndex
from mwbx.queries.poses import quat_matrix


def frame_margins(index: GeometryIndex, window) -> tuple[np.ndarray, np.ndarray]:
  """The kept frames a window reaches and their margins.

  Args:
    index: the bank's geometry index.
    window: (t0, t1) seconds (None ends open) or None.

  Returns:
    (relevant bool[K]: the ends of every interval between kept frames that
    overlaps the window, or the nearest kept frame when the window lies past
    the end; margin f32[B, W, K]: the largest margin of a relevant interval at
    each frame, 0 where none).
  """
  times = index.times
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
  sweep = np.where(overlap[None, None], index.sweep, 0.0)
  pad = np.zeros(sweep.shape[:2] + (1,), sweep.dtype)
  margin = np.maximum(np.concatenate([sweep, pad], axis=2), np.concatenate([pad, sweep], axis=2))
  return relevant, margin


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
  relevant, margin = frame_margins(index, window)
  normals = frustum.normals.astype(np.float64)
  offsets = frustum.offsets
  n_frames = len(relevant)
  n_chunks = index.box_lo.shape[2]
  rel_pad = np.zeros(n_chunks * CHUNK, bool)
  rel_pad[:n_frames] = relevant
  chunk_relevant = rel_pad.reshape(n_chunks, CHUNK).any(axis=1)
  volume = None
  tol = 1e-6 * (1.0 + float(np.max(np.abs(index.hi))))
  for b in np.flatnonzero(body_mask):
    if not index.cores[b]:
      continue
    worlds, frames = _candidate_frames(index, b, normals, offsets, chunk_relevant, rel_pad, n_frames, tol)
    if worlds.size == 0:
      continue
    com = index.com[b, worlds, frames].astype(np.float64)
    m = margin[b, worlds, frames].astype(np.float64) + index.codec[b]
    d = com @ normals.T - offsets  # [n, F]
    keep = np.all(d <= (index.reach[b] + m + tol)[:, None], axis=1)
    inside = np.all(d <= -index.reach[b], axis=1)
    hits[worlds[inside], b] = True
    keep &= ~hits[worlds, b]
    worlds, frames, com, m = worlds[keep], frames[keep], com[keep], m[keep]
    if worlds.size == 0:
      continue
    rotation = quat_matrix(index.quat[b, worlds, frames].astype(np.float64))  # [n, 3, 3]
    for core in index.cores[b]:
      todo = ~hits[worlds, b]
      if not todo.any():
        break
      w_, r_, c_, m_ = worlds[todo], rotation[todo], com[todo], m[todo]
      points = c_[:, None] + np.einsum("nij,vj->nvi", r_, core.vertices - index.ipos[b])  # [n, V, 3]
      grow = core.radius + m_
      dist = points @ normals.T - offsets  # [n, V, F]
      apart = np.any(dist.min(axis=1) > (grow + tol)[:, None], axis=1)
      vertex_in = np.any(np.all(dist <= 0.0, axis=2), axis=1)
      hits[w_[vertex_in & ~apart], b] = True
      rest = ~apart & ~vertex_in
      rest &= ~hits[w_, b]
      if not rest.any():
        continue
      if volume is None:
        volume = convex.clipped(frustum, index.lo, index.hi)
      far = convex.separated(points[rest], r_[rest], core.normals, core.directions, core.edges,
                             grow[rest], volume)
      hits[w_[rest][~far], b] = True
  return hits & index.valid[:, None]


def _candidate_frames(index, b, normals, offsets, chunk_relevant, rel_pad, n_frames, tol):
  """(worlds i64[n], kept frames i64[n]) of body b whose chunk box may meet the volume."""
  lo, hi = index.box_lo[b], index.box_hi[b]  # [W, NC, 3]
  outside = np.zeros(lo.shape[:2], bool)
  for n, off in zip(normals, offsets):
    near = np.where(n > 0, lo, hi) @ n  # the corner farthest into the half-space
    outside |= near - off > tol
  cand = ~outside & chunk_relevant[None] & index.valid[:, None]
  worlds, chunks = np.nonzero(cand)
  frames = chunks[:, None] * CHUNK + np.arange(CHUNK)[None]  # [n, CHUNK]
  ok = rel_pad[frames]
  worlds = np.repeat(worlds, CHUNK).reshape(-1, CHUNK)[ok]
  return worlds, frames[ok]
