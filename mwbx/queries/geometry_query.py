"""Which bodies' geometry meets a volume in a window (the culled evaluation
of whole-geometry queries over a :class:`~.geometry.GeometryIndex`).

Per selected body, one compiled pass (:mod:`.geometry_cull`) culls worlds
and chunks of kept frames by their boxes, then decides each kept frame the
window reaches by its bounding sphere, each geom's extent along the planes,
a vertex in or projected into the volume, and the exact distance of the
nearest vertex, stopping a world at its first settled hit. Only frames that
leave undecided (a polytope core near an edge or corner of the volume) reach
the exact separating-axis test (:mod:`.convex`) here, a few per world at a
time. A world that meets the volume only within an interval's sweep margin
is borderline: the same evaluation on its stored frames (a stride-1 index
of just those worlds, :class:`~.geometry.StoredFrames`) settles it. Every
stage is conservative (it drops only what provably misses and keeps only
what provably hits), so the answer is that of the exact test on every
stored frame.
"""

from __future__ import annotations

import threading

import numpy as np

from mwbx.queries import convex
from mwbx.queries import geometry_cull
from mwbx.queries.frustum import Frustum
from mwbx.queries.geometry import GeometryIndex
from mwbx.queries.poses import quat_matrix
from mwbx.host_pool import LazyPool


ANSWERS_KEPT = 32  # latest answers kept per index
_ANSWERS_LOCK = threading.Lock()


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
  relevant, overlap = window_frames(index, window)
  return relevant, _Margins(index.sweep, overlap)


def _clamped(times: np.ndarray, window) -> tuple[float, float]:
  """The window's (t0, t1) within [0, the last kept frame's time], open ends closed."""
  t0, t1 = (None, None) if window is None else window
  end = float(times[-1])
  return (0.0 if t0 is None else min(max(float(t0), 0.0), end),
          end if t1 is None else min(max(float(t1), 0.0), end))


def window_frames(index: GeometryIndex, window) -> tuple[np.ndarray, np.ndarray]:
  """(relevant bool[K] kept frames, overlap bool[K - 1] intervals) a window
  reaches. Where every stored frame is kept (stride 1: a bank recorded at
  the query rate, or the stored frames a borderline world is settled on),
  the answer is that of the stored frames in the window, each on its own (the
  nearest one where none lies in it): no interval's motion is added, only
  the codec's bound."""
  if index.stride > 1:
    return _relevant(index.times, window)
  relevant = _inside(index.times, window)
  if not relevant.any():
    relevant[np.argmin(np.abs(index.times - _clamped(index.times, window)[0]))] = True
  return relevant, np.zeros(max(len(index.times) - 1, 0), bool)


def _relevant(times: np.ndarray, window) -> tuple[np.ndarray, np.ndarray]:
  """(relevant bool[K] kept frames, overlap bool[K - 1] intervals) of a window."""
  t0, t1 = _clamped(times, window)
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
  key = (np.asarray(frustum.normals, np.float64).tobytes(), np.asarray(frustum.offsets, np.float64).tobytes(),
         np.asarray(body_mask, bool).tobytes(), None if window is None else tuple(window))
  answer = index.answers.get(key)
  if answer is None:
    answer = _hits(index, frustum, body_mask, window)
    with _ANSWERS_LOCK:  # a page may evaluate from several threads
      while len(index.answers) >= ANSWERS_KEPT:
        index.answers.pop(next(iter(index.answers)))
      index.answers[key] = answer
  return answer.copy()


def _hits(index: GeometryIndex, frustum: Frustum, body_mask: np.ndarray, window,
          worlds: np.ndarray | None = None) -> np.ndarray:
  """`geometry_hits` computed afresh (for the worlds marked in bool[W] `worlds`, default the valid ones)."""
  n_bodies, n_worlds, n_frames = index.com.shape[:3]
  hits = np.zeros((n_worlds, n_bodies), bool)
  selected = np.asarray(body_mask, bool) & np.array([bool(c) for c in index.cores])
  if not selected.any():
    return hits
  volume = convex.clipped(frustum, index.lo, index.hi)
  if len(volume.vertices) == 0:  # empty inside the box that holds every shape
    return hits
  valid = index.valid if worlds is None else index.valid & worlds
  relevant, overlap = window_frames(index, window)
  n_chunks = index.bounds[6].shape[2]
  chunk_relevant = np.array([relevant[h * index.chunk:(h + 1) * index.chunk].any() for h in range(n_chunks)])
  settle = index.stored is not None
  frames = geometry_cull.WindowFrames(relevant, overlap, _inside(index.times, window), chunk_relevant, settle)
  planes = geometry_cull.planes_of(frustum.normals, frustum.offsets, index.tol)
  vol = geometry_cull.volume_arrays(volume)
  margin = _Margins(index.sweep, overlap)

  def compiled_pass(b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shape = _body_shape(index, b)
    poses = geometry_cull.KeptPoses(index.com[b], index.quat[b], index.sweep[b], index.repeat[b], valid)
    boxes = geometry_cull.body_boxes(index.bounds, b, index.group, index.chunk)
    found = np.zeros(n_worlds, bool)
    near = np.zeros(n_worlds, bool)
    undecided = np.zeros((n_worlds, n_frames), bool)
    geometry_cull.body_pass(poses, boxes, frames, shape, planes, vol, geometry_cull.scratch_for(shape, planes, vol),
                            found, near, undecided)
    return found, near, undecided

  bodies = np.flatnonzero(selected)
  borderline = np.zeros_like(hits)
  # The pass holds no GIL: bodies run on all cores while this thread does the
  # exact stage of the bodies already passed.
  for b, (found, near, undecided) in zip(bodies, _POOL.get().map(compiled_pass, bodies)):
    hits[:, b] = found
    borderline[:, b] = near
    pending = np.flatnonzero(undecided.any(axis=1))
    if pending.size == 0:
      continue
    rows, kept = np.nonzero(undecided[pending])
    rows = pending[rows]
    m = margin[b, rows, kept].astype(np.float64) + index.codec[b]
    # In rounds of 1, 2, 4, ... undecided frames per world (in time order): a
    # world is done at its first settled hit.
    rank = np.arange(rows.size) - np.searchsorted(rows, rows)
    lo = 0
    while lo <= rank.max():
      hi = 2 * lo + 1
      take = np.flatnonzero((rank >= lo) & (rank < hi) & ~hits[rows, b] & ~borderline[rows, b])
      if take.size:
        hit = take[_exact_stage(index, b, rows[take], kept[take], m[take], volume, planes.tol)]
        if settle:  # settled only by the stored frame itself (margin: the codec's bound)
          inside = hit[frames.inside[kept[hit]]]
          sure = inside[_exact_stage(index, b, rows[inside], kept[inside], np.full(inside.size, index.codec[b]),
                                     volume, planes.tol)]
          borderline[rows[hit], b] = True
          hit = sure
        hits[rows[hit], b] = True
      lo = hi
  borderline &= ~hits
  if borderline.any():
    rows = np.flatnonzero(borderline.any(axis=1))
    fine, places = index.stored.index(index, rows)
    worlds = np.zeros(fine.com.shape[1], bool)
    worlds[places] = True
    hits[rows] |= _hits(fine, frustum, borderline[rows].any(axis=0), window, worlds)[places] & borderline[rows]
  return hits & index.valid[:, None]


def _inside(times: np.ndarray, window) -> np.ndarray:
  """bool[K] kept frames whose time lies in the (clamped) window."""
  t0, t1 = _clamped(times, window)
  return (times >= t0) & (times <= t1)


_POOL = LazyPool("mwbx-geometry")  # the body passes, a thread per core


def _body_shape(index: GeometryIndex, b: int) -> geometry_cull.BodyShape:
  """Body b's cores for the compiled pass."""
  cores = index.cores[b]

  def stacked(arrays):
    starts = np.concatenate([[0], np.cumsum([len(a) for a in arrays])]).astype(np.int64)
    return np.ascontiguousarray(np.concatenate(arrays).reshape(-1, 3), np.float64), starts

  verts, vstart = stacked([c.vertices - index.ipos[b] for c in cores])
  normals, nstart = stacked([c.normals.reshape(-1, 3) for c in cores])
  dirs, dstart = stacked([c.directions.reshape(-1, 3) for c in cores])
  return geometry_cull.BodyShape(float(index.reach[b]), float(index.codec[b]), verts, vstart,
                                 np.array([c.radius for c in cores], np.float64), normals, nstart, dirs, dstart)


def _exact_stage(index, b, worlds, frames, m, volume, tol) -> np.ndarray:
  """Stages 2 and 3 for candidate kept frames of body b: bool[n] its geometry
  (grown by m f64[n] plus each geom's radius) meets the volume (the
  frustum's planes clipped to the index's box)."""
  normals, offsets = volume.normals, volume.offsets  # the frustum's own planes
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


