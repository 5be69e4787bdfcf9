"""One compiled pass deciding most (world, frame) pairs of a geometry query.

`body_pass` walks one body's kept poses in every world, coarse to fine, and
stops a world at its first hit:
  1. the world's box (its COM at every kept frame) grown by the body's reach,
     the codec's bound and the world's largest sweep margin, apart from some
     plane of the volume -> the world misses;
  2. the same per group of `group` chunks, then per chunk of `chunk` kept
     frames (each with its own largest margin); groups and chunks without a
     frame the window reaches are skipped;
  3. per kept frame the window reaches, in time order: a frame at rest that
     repeats a frame already tested with at least its margin is skipped; the
     bounding sphere (reach + codec + margin) apart -> miss; wholly inside ->
     hit; then per geom core (grown by its radius, the margin and the codec
     bound): its extent along a plane apart -> this core misses; a core vertex
     inside, or a vertex whose projection onto a plane lies in the volume
     within the growth -> hit; the nearest vertex's exact distance within it
     -> hit (for a point core, beyond it -> miss); a polytope core apart
     along one of its face normals or an edge-edge cross product -> miss.
What is left (a polytope core near an edge or corner of the volume) is
marked undecided for the full separating-axis test (:mod:`.convex`).

A hit found with an interval's sweep margin is settled only where the kept
frame lies in the window and meets the volume with no margin but the
codec's bound (then the stored frame itself does); otherwise the world is
borderline and the stored frames between the kept ones decide
(:func:`.geometry_query.geometry_hits`).

Each step drops only what the next would drop and keeps only what the exact
test would keep, so the answers are those of testing every frame exactly
(``tests/queries/test_queries_geometry_cull.py`` compares the two). Float64
throughout.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from mwbx.queries import convex


class ClippedVolume(NamedTuple):
  """The query volume clipped to the index's box, as the compiled tests read it.

  Attributes:
    normals: f64[F, 3] outward unit normals of its planes.
    offsets: f64[F] plane offsets (a point x is inside where normals @ x <= offsets), m.
    tol: metres of float slack on a plane.
    cos: f64[F, F] normals @ normals.T.
    pair_i, pair_j: i64[P] plane pairs whose edge line is solvable.
    pair_inv: f64[P, 2, 2] their inverse Gram matrices.
    vertices: f64[V, 3] its corners, m.
    directions: f64[E, 3] its unique edge directions.
  """

  normals: np.ndarray
  offsets: np.ndarray
  tol: float
  cos: np.ndarray
  pair_i: np.ndarray
  pair_j: np.ndarray
  pair_inv: np.ndarray
  vertices: np.ndarray
  directions: np.ndarray


class Planes(NamedTuple):
  """The query's own planes (unclipped), which decide a hit.

  Attributes:
    normals: f64[F, 3] outward unit normals.
    offsets: f64[F] offsets, m.
    cos: f64[F, F] normals @ normals.T.
    tol: metres of float slack (float32 storage of the poses).
  """

  normals: np.ndarray
  offsets: np.ndarray
  cos: np.ndarray
  tol: float


class BodyShape(NamedTuple):
  """One body's geom cores about its COM (body frame), and its bounds.

  Attributes:
    reach: farthest geom point from the COM, m.
    codec: how far the codec's error can move a point of the body, m.
    verts: f64[V, 3] core vertices about the COM; vstart: i64[cores + 1] each core's first.
    radius: f64[cores] each core's radius (a sphere is a point grown by it), m.
    normals: f64[N, 3] the cores' face normals; nstart: i64[cores + 1].
    dirs: f64[D, 3] the cores' edge directions; dstart: i64[cores + 1].
  """

  reach: float
  codec: float
  verts: np.ndarray
  vstart: np.ndarray
  radius: np.ndarray
  normals: np.ndarray
  nstart: np.ndarray
  dirs: np.ndarray
  dstart: np.ndarray


class KeptPoses(NamedTuple):
  """One body's kept poses in every world.

  Attributes:
    com: f32[W, K, 3] centre of mass at each kept frame, m.
    quat: f32[W, K, 4] orientation (w, x, y, z).
    sweep: f32[W, K - 1] margin of each interval between kept frames, m.
    repeat: bool[W, K] the pose equals the previous kept frame's.
    valid: bool[W] worlds to test.
  """

  com: np.ndarray
  quat: np.ndarray
  sweep: np.ndarray
  repeat: np.ndarray
  valid: np.ndarray


class CullBoxes(NamedTuple):
  """One body's boxes of steps 1 and 2 (:func:`chunk_bounds`).

  Attributes:
    world_lo, world_hi: f32[W, 1, 3] the COM's box over the world, m;
      world_sweep: f32[W] its largest margin, m.
    group_lo, group_hi: f32[W, NG, 3]; group_sweep: f32[W, NG] per group of
      `group` chunks.
    chunk_lo, chunk_hi: f32[W, NC, 3]; chunk_sweep: f32[W, NC] per chunk of
      `chunk` kept frames.
    group: chunks per group; chunk: kept frames per chunk.
  """

  world_lo: np.ndarray
  world_hi: np.ndarray
  world_sweep: np.ndarray
  group_lo: np.ndarray
  group_hi: np.ndarray
  group_sweep: np.ndarray
  chunk_lo: np.ndarray
  chunk_hi: np.ndarray
  chunk_sweep: np.ndarray
  group: int
  chunk: int


class WindowFrames(NamedTuple):
  """Which kept frames and intervals a query window reaches.

  Attributes:
    relevant: bool[K] the ends of every interval that overlaps the window.
    overlap: bool[K - 1] the intervals that overlap it.
    inside: bool[K] kept frames whose time lies in the window (stored
      frames the settled answer tests with no sweep margin).
    chunk_relevant: bool[NC] chunks holding a relevant frame.
    settle: True where a hit found only with an interval's margin is to be
      settled on the stored frames (the index keeps every `stride`-th);
      False: every hit is final.
  """

  relevant: np.ndarray
  overlap: np.ndarray
  inside: np.ndarray
  chunk_relevant: np.ndarray
  settle: bool

class Scratch(NamedTuple):
  """Per-thread scratch of :func:`_frame_verdict` (no allocation per frame).

  Attributes:
    r: f64[3, 3] rotation; pts: f64[V, 3] a core's vertices in the world;
    dist: f64[V, F] their plane distances; point_dist: f64[F'] one point's
    distances to the clipped volume's planes; axis: f64[3].
  """

  r: np.ndarray
  pts: np.ndarray
  dist: np.ndarray
  point_dist: np.ndarray
  axis: np.ndarray


def scratch_for(shape: BodyShape, planes: Planes, vol: ClippedVolume) -> Scratch:
  """Scratch arrays sized for one body and one volume."""
  n_verts = shape.verts.shape[0]
  return Scratch(np.empty((3, 3)), np.empty((n_verts, 3)), np.empty((n_verts, planes.normals.shape[0])),
                 np.empty(vol.normals.shape[0]), np.empty(3))


@numba.njit(cache=True, nogil=True, inline="always")
def _margin(sweep, overlap, w, k):
  """The largest sweep margin of a window interval next to kept frame k of
  world w (indices, not slices: a slice costs reference counting)."""
  n_int = overlap.shape[0]
  m = 0.0
  if k >= 1 and overlap[k - 1]:
    m = max(m, float(sweep[w, k - 1]))
  if k < n_int and overlap[k]:
    m = max(m, float(sweep[w, k]))
  return m


@numba.njit(cache=True, nogil=True, inline="always")
def _box_apart(lo, hi, w, h, normals, offsets, grow):
  """Whether the box [lo[w, h], hi[w, h]] grown by `grow` lies beyond some
  plane (lo, hi: f32[W, H, 3])."""
  for f in range(normals.shape[0]):
    near = 0.0
    for a in range(3):
      n = normals[f, a]
      near += n * (lo[w, h, a] if n > 0 else hi[w, h, a])
    if near - offsets[f] > grow:
      return True
  return False


@numba.njit(cache=True, nogil=True)
def within(points, row, grow, vol, dist):
  """Whether the point points[row] (f64[n, 3]) lies within `grow` metres of
  the clipped volume `vol` (:class:`ClippedVolume`): the exact distance of
  :func:`.convex.point_distances` (inside, else the nearest projection onto a
  face or an edge line that lies in the volume, or the nearest vertex) at
  most `grow`, found with early exits. dist: f64[F] scratch."""
  vol_n, vol_off, vol_tol = vol.normals, vol.offsets, vol.tol
  n_planes = vol_n.shape[0]
  inside = True
  for f in range(n_planes):
    dist[f] = points[row, 0] * vol_n[f, 0] + points[row, 1] * vol_n[f, 1] + points[row, 2] * vol_n[f, 2] - vol_off[f]
    inside &= dist[f] <= vol_tol
  if inside:
    return True
  for i in range(n_planes):  # faces
    d = max(dist[i], 0.0)
    if d > grow:
      continue
    ok = True
    for j in range(n_planes):
      ok &= dist[j] - d * vol.cos[i, j] <= vol_tol
    if ok:
      return True
  for e in range(vol.pair_i.shape[0]):  # edge lines
    i, j = vol.pair_i[e], vol.pair_j[e]
    # The line lies in both planes: never nearer than either plane (with a
    # tolerance, so that rounding cannot skip a line within reach).
    if max(dist[i], dist[j], -dist[i], -dist[j]) > grow + vol_tol:
      continue
    c0 = dist[i] * vol.pair_inv[e, 0, 0] + dist[j] * vol.pair_inv[e, 0, 1]
    c1 = dist[i] * vol.pair_inv[e, 1, 0] + dist[j] * vol.pair_inv[e, 1, 1]
    q0 = points[row, 0] - c0 * vol_n[i, 0] - c1 * vol_n[j, 0]
    q1 = points[row, 1] - c0 * vol_n[i, 1] - c1 * vol_n[j, 1]
    q2 = points[row, 2] - c0 * vol_n[i, 2] - c1 * vol_n[j, 2]
    if math.sqrt((points[row, 0] - q0)**2 + (points[row, 1] - q1)**2 + (points[row, 2] - q2)**2) > grow:
      continue
    ok = True
    for f in range(n_planes):
      ok &= q0 * vol_n[f, 0] + q1 * vol_n[f, 1] + q2 * vol_n[f, 2] - vol_off[f] <= vol_tol
    if ok:
      return True
  verts = vol.vertices
  for v in range(verts.shape[0]):  # vertices
    if math.sqrt((points[row, 0] - verts[v, 0])**2 + (points[row, 1] - verts[v, 1])**2
                 + (points[row, 2] - verts[v, 2])**2) <= grow:
      return True
  return False


@numba.njit(cache=True, nogil=True)
def _apart_along(axis, pts, n_pts, vol_verts, grow, vol_tol):
  """Whether the core pts[:n_pts] and the volume's vertices lie apart by more
  than grow + vol_tol along axis (made unit; a zero axis separates nothing),
  as :func:`.convex._gap_exceeds` tests one axis."""
  norm = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
  if not norm > 1e-12:
    return False
  u0, u1, u2 = axis[0] / norm, axis[1] / norm, axis[2] / norm
  core_lo, core_hi = math.inf, -math.inf
  for v in range(n_pts):
    x = u0 * pts[v, 0] + u1 * pts[v, 1] + u2 * pts[v, 2]
    core_lo, core_hi = min(core_lo, x), max(core_hi, x)
  vol_lo, vol_hi = math.inf, -math.inf
  for v in range(vol_verts.shape[0]):
    x = u0 * vol_verts[v, 0] + u1 * vol_verts[v, 1] + u2 * vol_verts[v, 2]
    vol_lo, vol_hi = min(vol_lo, x), max(vol_hi, x)
  return max(core_lo - vol_hi, vol_lo - core_hi) > grow + vol_tol


@numba.njit(cache=True, nogil=True)
def _separated_cheaply(pts, n_pts, r, shape, core, vol, grow, axis):
  """Whether core `core`'s face normals or the cross products of its edge
  directions with the volume's separate it from the volume by more than
  grow (some of the separating-axis test's axes: True only where that test
  finds the core apart). pts: the core's vertices in the world; r f64[3, 3]
  body-to-world; axis f64[3] scratch."""
  core_normals, core_dirs, vol_dirs = shape.normals, shape.dirs, vol.directions
  for k in range(shape.nstart[core], shape.nstart[core + 1]):
    for a in range(3):
      axis[a] = r[a, 0] * core_normals[k, 0] + r[a, 1] * core_normals[k, 1] + r[a, 2] * core_normals[k, 2]
    if _apart_along(axis, pts, n_pts, vol.vertices, grow, vol.tol):
      return True
  for k in range(shape.dstart[core], shape.dstart[core + 1]):
    e0 = r[0, 0] * core_dirs[k, 0] + r[0, 1] * core_dirs[k, 1] + r[0, 2] * core_dirs[k, 2]
    e1 = r[1, 0] * core_dirs[k, 0] + r[1, 1] * core_dirs[k, 1] + r[1, 2] * core_dirs[k, 2]
    e2 = r[2, 0] * core_dirs[k, 0] + r[2, 1] * core_dirs[k, 1] + r[2, 2] * core_dirs[k, 2]
    for e in range(vol_dirs.shape[0]):
      axis[0] = e1 * vol_dirs[e, 2] - e2 * vol_dirs[e, 1]
      axis[1] = e2 * vol_dirs[e, 0] - e0 * vol_dirs[e, 2]
      axis[2] = e0 * vol_dirs[e, 1] - e1 * vol_dirs[e, 0]
      if _apart_along(axis, pts, n_pts, vol.vertices, grow, vol.tol):
        return True
  return False


@numba.njit(cache=True, nogil=True)
def _frame_verdict(c, q, m, shape, planes, vol, scratch):
  """One pose (c f64[3] COM, q f64[4] orientation) grown by margin m (plus
  the codec's bound): 1 hit, 0 miss, -1 undecided (a polytope core for the
  separating-axis test)."""
  normals, offsets, tol = planes.normals, planes.offsets, planes.tol
  r, pts, dist = scratch.r, scratch.pts, scratch.dist
  n_planes = normals.shape[0]
  inside = True
  for f in range(n_planes):
    d = c[0] * normals[f, 0] + c[1] * normals[f, 1] + c[2] * normals[f, 2] - offsets[f]
    if d > shape.reach + shape.codec + m + tol:
      return 0
    inside &= d < -(shape.reach + tol)
  if inside:
    return 1
  w, x, y, z = q[0], q[1], q[2], q[3]
  r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
  r[1, 0], r[1, 1], r[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
  r[2, 0], r[2, 1], r[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
  verts = shape.verts
  verdict = 0
  for core in range(shape.radius.shape[0]):
    grow = shape.radius[core] + m + shape.codec
    v0, v1 = shape.vstart[core], shape.vstart[core + 1]
    for v in range(v1 - v0):
      for a in range(3):
        pts[v, a] = c[a] + r[a, 0] * verts[v0 + v, 0] + r[a, 1] * verts[v0 + v, 1] + r[a, 2] * verts[v0 + v, 2]
      for f in range(n_planes):
        dist[v, f] = pts[v, 0] * normals[f, 0] + pts[v, 1] * normals[f, 1] + pts[v, 2] * normals[f, 2] - offsets[f]
    apart = False
    for f in range(n_planes):
      low = math.inf
      for v in range(v1 - v0):
        low = min(low, dist[v, f])
      apart |= low > grow + tol
    if apart:
      continue
    for v in range(v1 - v0):  # a vertex inside, or projected onto a face within reach
      for i in range(n_planes):
        d = max(dist[v, i], 0.0)
        if d > grow:
          continue
        ok = True
        for j in range(n_planes):
          ok &= dist[v, j] - d * planes.cos[i, j] <= 0.0
        if ok:
          return 1
    for v in range(v1 - v0):  # the nearest vertex's exact distance within reach
      if within(pts, v, grow, vol, scratch.point_dist):
        return 1
    if v1 - v0 > 1 and not _separated_cheaply(pts, v1 - v0, r, shape, core, vol, grow, scratch.axis):
      verdict = -1
  return verdict


@numba.njit(cache=True, nogil=True)
def body_pass(poses, boxes, window, shape, planes, vol, scratch, hits, borderline, undecided):
  """Steps 1-3 of the module docstring for one body in every world.

  Args:
    poses: :class:`KeptPoses`; boxes: :class:`CullBoxes`; window:
      :class:`WindowFrames`; shape: :class:`BodyShape`; planes:
      :class:`Planes`; vol: :class:`ClippedVolume`; scratch: :class:`Scratch`.
    hits: bool[W] out: the body meets the volume (settled).
    borderline: bool[W] out, only where ``window.settle``: no settled hit,
      but a hit with some interval's margin (to be settled on the stored
      frames).
    undecided: bool[W, K] out: kept frames for the separating-axis test,
      set only in worlds with neither a hit nor a borderline one.
  """
  n_worlds, n_frames = poses.com.shape[0], poses.com.shape[1]
  big = shape.reach + shape.codec + planes.tol
  normals, offsets = planes.normals, planes.offsets
  c = np.empty(3)
  q = np.empty(4)
  n_chunks = window.chunk_relevant.shape[0]
  group = boxes.group
  group_relevant = np.zeros(boxes.group_lo.shape[1], np.bool_)
  for h in range(n_chunks):
    group_relevant[h // group] |= window.chunk_relevant[h]
  for w in range(n_worlds):
    if not poses.valid[w] or _box_apart(boxes.world_lo, boxes.world_hi, w, 0, normals, offsets,
                                        big + boxes.world_sweep[w]):
      continue
    found = False
    near = False
    pending = False
    skip_group = False
    for h in range(n_chunks):
      if h % group == 0:
        g = h // group
        skip_group = not group_relevant[g] or _box_apart(boxes.group_lo, boxes.group_hi, w, g, normals, offsets,
                                                         big + boxes.group_sweep[w, g])
      if skip_group or not window.chunk_relevant[h] or _box_apart(boxes.chunk_lo, boxes.chunk_hi, w, h, normals,
                                                                  offsets, big + boxes.chunk_sweep[w, h]):
        continue
      for k in range(h * boxes.chunk, min(n_frames, (h + 1) * boxes.chunk)):
        if not window.relevant[k]:
          continue
        m = _margin(poses.sweep, window.overlap, w, k)
        if k > 0 and poses.repeat[w, k] and window.relevant[k - 1] and m <= _margin(poses.sweep, window.overlap, w, k - 1):
          continue
        for a in range(3):
          c[a] = poses.com[w, k, a]
        for a in range(4):
          q[a] = poses.quat[w, k, a]
        verdict = _frame_verdict(c, q, m, shape, planes, vol, scratch)
        if verdict == 1 and window.settle:
          # Settled only if the stored frame itself meets the volume (the
          # codec's bound is its only margin); else the stored frames decide.
          if not (window.inside[k] and (m == 0.0 or _frame_verdict(c, q, 0.0, shape, planes, vol, scratch) == 1)):
            near = True
            continue
        if verdict == 1:
          found = True
          break
        if verdict == -1 and not near:
          undecided[w, k] = True
          pending = True
      if found:
        break
    if found:
      hits[w] = True
    elif near:
      borderline[w] = True
    if pending and (found or near):
      undecided[w] = False


def volume_arrays(volume: convex.Polytope) -> ClippedVolume:
  """The clipped volume as the compiled tests take it."""
  n = np.ascontiguousarray(volume.normals, np.float64)
  cos = n @ n.T
  pair_i, pair_j, inv = [], [], []
  for i in range(len(n)):
    for j in range(i + 1, len(n)):
      g = np.array([[1.0, cos[i, j]], [cos[i, j], 1.0]])
      if abs(np.linalg.det(g)) < 1e-9:
        continue
      pair_i.append(i)
      pair_j.append(j)
      inv.append(np.linalg.inv(g))
  return ClippedVolume(n, np.ascontiguousarray(volume.offsets, np.float64), float(volume.tol), cos,
                       np.array(pair_i, np.int64), np.array(pair_j, np.int64),
                       np.array(inv, np.float64).reshape(-1, 2, 2),
                       np.ascontiguousarray(volume.vertices, np.float64).reshape(-1, 3),
                       np.ascontiguousarray(volume.directions, np.float64).reshape(-1, 3))


def planes_of(normals: np.ndarray, offsets: np.ndarray, tol: float) -> Planes:
  """A query's planes as the compiled pass takes them."""
  n = np.ascontiguousarray(normals, np.float64)
  return Planes(n, np.ascontiguousarray(offsets, np.float64), n @ n.T, float(tol))


def body_boxes(bounds: tuple, b: int, group: int, chunk: int) -> CullBoxes:
  """Body b's :class:`CullBoxes` from the boxes of every body (:func:`chunk_bounds`)."""
  world_lo, world_hi, world_sweep, group_lo, group_hi, group_sweep, chunk_lo, chunk_hi, chunk_sweep = bounds
  return CullBoxes(world_lo[b][:, None], world_hi[b][:, None], world_sweep[b], group_lo[b], group_hi[b],
                   group_sweep[b], chunk_lo[b], chunk_hi[b], chunk_sweep[b], int(group), int(chunk))


def chunk_bounds(com: np.ndarray, sweep: np.ndarray, chunk: int, group: int) -> tuple:
  """The boxes of steps 1 and 2.

  Args:
    com: f32[B, W, K, 3] kept COM positions; sweep: f32[B, W, K - 1].
    chunk: kept frames per chunk; group: chunks per group.

  Returns:
    (world_lo, world_hi f32[B, W, 3], world_sweep f32[B, W], group_lo,
    group_hi f32[B, W, NG, 3], group_sweep f32[B, W, NG], chunk_lo,
    chunk_hi f32[B, W, NC, 3], chunk_sweep f32[B, W, NC]): boxes of the COM
    and the largest margin of any interval next to a frame inside (so at
    least any frame's margin in any window).
  """
  n_frames = com.shape[2]
  n_chunks = -(-n_frames // chunk)
  n_int = sweep.shape[2]
  shape = com.shape[:2]
  lo = np.empty(shape + (n_chunks, 3), np.float32)
  hi = np.empty(shape + (n_chunks, 3), np.float32)
  margin = np.zeros(shape + (n_chunks,), np.float32)
  for h in range(n_chunks):
    part = com[:, :, h * chunk:(h + 1) * chunk]
    lo[:, :, h] = part.min(axis=2)
    hi[:, :, h] = part.max(axis=2)
    first, last = max(h * chunk - 1, 0), min((h + 1) * chunk, n_frames) - 1  # intervals first..last
    if n_int and first < min(last + 1, n_int):
      margin[:, :, h] = sweep[:, :, first:min(last + 1, n_int)].max(axis=2)
  n_groups = -(-n_chunks // group)
  parts = [slice(g * group, (g + 1) * group) for g in range(n_groups)]
  return (lo.min(axis=2), hi.max(axis=2), margin.max(axis=2),
          np.stack([lo[:, :, p].min(axis=2) for p in parts], axis=2),
          np.stack([hi[:, :, p].max(axis=2) for p in parts], axis=2),
          np.stack([margin[:, :, p].max(axis=2) for p in parts], axis=2), lo, hi, margin)
