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

Each step drops only what the next would drop and keeps only what the exact
test would keep, so the answers are those of testing every frame exactly
(``tests/queries/test_queries_geometry.py`` compares the two). Float64 throughout.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mwbx.queries import convex


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
def within(points, row, grow, vol_n, vol_off, vol_tol, cos, pair_i, pair_j, pair_inv, vol_verts, dist):
  """Whether the point points[row] (f64[n, 3]) lies within `grow` metres of
  the clipped volume: the exact distance of :func:`.convex.point_distances` (inside, else the
  nearest projection onto a face or an edge line that lies in the volume, or
  the nearest vertex) at most `grow`, found with early exits. dist: f64[F]
  scratch."""
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
      ok &= dist[j] - d * cos[i, j] <= vol_tol
    if ok:
      return True
  for e in range(pair_i.shape[0]):  # edge lines
    i, j = pair_i[e], pair_j[e]
    # The line lies in both planes: never nearer than either plane (with a
    # tolerance, so that rounding cannot skip a line within reach).
    if max(dist[i], dist[j], -dist[i], -dist[j]) > grow + vol_tol:
      continue
    c0 = dist[i] * pair_inv[e, 0, 0] + dist[j] * pair_inv[e, 0, 1]
    c1 = dist[i] * pair_inv[e, 1, 0] + dist[j] * pair_inv[e, 1, 1]
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
  for v in range(vol_verts.shape[0]):  # vertices
    if math.sqrt((points[row, 0] - vol_verts[v, 0])**2 + (points[row, 1] - vol_verts[v, 1])**2
                 + (points[row, 2] - vol_verts[v, 2])**2) <= grow:
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
def _separated_cheaply(pts, n_pts, r, core_normals, n0, n1, core_dirs, d0, d1, vol_verts, vol_dirs, grow, vol_tol,
                       axis):
  """Whether a core's face normals or the cross products of its edge
  directions with the volume's separate it from the volume by more than
  grow (some of the separating-axis test's axes: True only where that test
  finds the core apart). core_normals[n0:n1], core_dirs[d0:d1]: the core's;
  r f64[3, 3] body-to-world; axis f64[3] scratch."""
  for k in range(n0, n1):
    for a in range(3):
      axis[a] = r[a, 0] * core_normals[k, 0] + r[a, 1] * core_normals[k, 1] + r[a, 2] * core_normals[k, 2]
    if _apart_along(axis, pts, n_pts, vol_verts, grow, vol_tol):
      return True
  for k in range(d0, d1):
    e0 = r[0, 0] * core_dirs[k, 0] + r[0, 1] * core_dirs[k, 1] + r[0, 2] * core_dirs[k, 2]
    e1 = r[1, 0] * core_dirs[k, 0] + r[1, 1] * core_dirs[k, 1] + r[1, 2] * core_dirs[k, 2]
    e2 = r[2, 0] * core_dirs[k, 0] + r[2, 1] * core_dirs[k, 1] + r[2, 2] * core_dirs[k, 2]
    for e in range(vol_dirs.shape[0]):
      axis[0] = e1 * vol_dirs[e, 2] - e2 * vol_dirs[e, 1]
      axis[1] = e2 * vol_dirs[e, 0] - e0 * vol_dirs[e, 2]
      axis[2] = e0 * vol_dirs[e, 1] - e1 * vol_dirs[e, 0]
      if _apart_along(axis, pts, n_pts, vol_verts, grow, vol_tol):
        return True
  return False


@numba.njit(cache=True, nogil=True, inline="always")
def _frame_verdict(c, q, m, reach, codec, verts, vstart, radius, core_normals, nstart, core_dirs, dstart,
                   normals, offsets, cos, tol, vol_n, vol_off, vol_tol, vol_cos, pair_i, pair_j, pair_inv,
                   vol_verts, vol_dirs, r, pts, dist, scratch, axis):
  """One kept pose (c f64[3] COM, q f64[4] orientation, m margin): 1 hit,
  0 miss, -1 undecided (a polytope core for the separating-axis test).
  r f64[3, 3], pts f64[V, 3], dist f64[V, F], scratch f64[F']: scratch."""
  n_planes = normals.shape[0]
  inside = True
  for f in range(n_planes):
    d = c[0] * normals[f, 0] + c[1] * normals[f, 1] + c[2] * normals[f, 2] - offsets[f]
    if d > reach + codec + m + tol:
      return 0
    inside &= d < -(reach + tol)
  if inside:
    return 1
  w, x, y, z = q[0], q[1], q[2], q[3]
  r[0, 0], r[0, 1], r[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
  r[1, 0], r[1, 1], r[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
  r[2, 0], r[2, 1], r[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
  verdict = 0
  for core in range(radius.shape[0]):
    grow = radius[core] + m + codec
    v0, v1 = vstart[core], vstart[core + 1]
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
          ok &= dist[v, j] - d * cos[i, j] <= 0.0
        if ok:
          return 1
    for v in range(v1 - v0):  # the nearest vertex's exact distance within reach
      if within(pts, v, grow, vol_n, vol_off, vol_tol, vol_cos, pair_i, pair_j, pair_inv, vol_verts, scratch):
        return 1
    if v1 - v0 > 1 and not _separated_cheaply(pts, v1 - v0, r, core_normals, nstart[core], nstart[core + 1],
                                              core_dirs, dstart[core], dstart[core + 1], vol_verts, vol_dirs,
                                              grow, vol_tol, axis):
      verdict = -1
  return verdict


@numba.njit(cache=True, nogil=True)
def body_pass(com, quat, sweep, repeat, valid, relevant, overlap, world_lo, world_hi, world_sweep,
              group_lo, group_hi, group_sweep, group, chunk_lo, chunk_hi, chunk_sweep, chunk, chunk_relevant, reach, codec, verts, vstart, radius,
              core_normals, nstart, core_dirs, dstart, vol_dirs,
              normals, offsets, tol, vol_n, vol_off, vol_tol, vol_cos, pair_i, pair_j, pair_inv, vol_verts,
              hits, undecided):
  """Steps 1-3 of the module docstring for one body in every world.

  Args:
    com: f32[W, K, 3], quat: f32[W, K, 4] kept poses; sweep: f32[W, K - 1]
      interval margins; repeat: bool[W, K]; valid: bool[W].
    relevant: bool[K], overlap: bool[K - 1] the window's kept frames and
      intervals; chunk_relevant: bool[NC].
    world_lo, world_hi: f32[W, 1, 3], world_sweep: f32[W]; group_lo, group_hi:
      f32[W, NG, 3], group_sweep: f32[W, NG] (groups of `group` chunks);
      chunk_lo, chunk_hi: f32[W, NC, 3], chunk_sweep: f32[W, NC] the bounds
      of steps 1 and 2.
    reach, codec: metres; verts: f64[V, 3] core vertices about the COM,
      vstart: i64[cores + 1], radius: f64[cores]; core_normals f64[N, 3],
      nstart i64[cores + 1], core_dirs f64[D, 3], dstart i64[cores + 1]:
      the cores' face normals and edge directions (body frame).
    vol_dirs: f64[E, 3] the volume's unique edge directions.
    normals: f64[F, 3], offsets: f64[F] the volume's planes; tol: metres.
    vol_*: the clipped volume (:func:`volume_arrays`).
    hits: bool[W] out; undecided: bool[W, K] out, set only in worlds
      without a hit.
  """
  n_worlds, n_frames = com.shape[0], com.shape[1]
  n_planes = normals.shape[0]
  cos = np.empty((n_planes, n_planes))
  for i in range(n_planes):
    for j in range(n_planes):
      cos[i, j] = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
  big = reach + codec + tol
  c = np.empty(3)
  q = np.empty(4)
  r = np.empty((3, 3))
  n_verts = verts.shape[0]
  pts = np.empty((n_verts, 3))
  dist = np.empty((n_verts, n_planes))
  scratch = np.empty(vol_n.shape[0])
  axis = np.empty(3)
  n_chunks = chunk_relevant.shape[0]
  group_relevant = np.zeros(group_lo.shape[1], np.bool_)
  for h in range(n_chunks):
    group_relevant[h // group] |= chunk_relevant[h]
  for w in range(n_worlds):
    if not valid[w] or _box_apart(world_lo, world_hi, w, 0, normals, offsets, big + world_sweep[w]):
      continue
    found = False
    pending = False
    skip_group = False
    for h in range(n_chunks):
      if h % group == 0:
        g = h // group
        skip_group = not group_relevant[g] or _box_apart(group_lo, group_hi, w, g, normals, offsets,
                                                         big + group_sweep[w, g])
      if skip_group or not chunk_relevant[h] or _box_apart(chunk_lo, chunk_hi, w, h, normals, offsets,
                                                           big + chunk_sweep[w, h]):
        continue
      for k in range(h * chunk, min(n_frames, (h + 1) * chunk)):
        if not relevant[k]:
          continue
        m = _margin(sweep, overlap, w, k)
        if k > 0 and repeat[w, k] and relevant[k - 1] and m <= _margin(sweep, overlap, w, k - 1):
          continue
        for a in range(3):
          c[a] = com[w, k, a]
        for a in range(4):
          q[a] = quat[w, k, a]
        verdict = _frame_verdict(c, q, m, reach, codec, verts, vstart, radius, core_normals, nstart, core_dirs,
                                 dstart, normals, offsets, cos, tol, vol_n, vol_off, vol_tol, vol_cos, pair_i,
                                 pair_j, pair_inv, vol_verts, vol_dirs, r, pts, dist, scratch, axis)
        if verdict == 1:
          found = True
          break
        if verdict == -1:
          undecided[w, k] = True
          pending = True
      if found:
        break
    if found:
      hits[w] = True
      if pending:
        undecided[w] = False


def volume_arrays(volume: convex.Polytope) -> tuple:
  """The clipped volume as `within` takes it: (normals, offsets, tol,
  cos f64[F, F], pair_i, pair_j i64[P] plane pairs whose edge line is
  solvable, pair_inv f64[P, 2, 2] their inverse Gram matrices, vertices)."""
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
  return (n, np.ascontiguousarray(volume.offsets, np.float64), float(volume.tol), cos,
          np.array(pair_i, np.int64), np.array(pair_j, np.int64), np.array(inv, np.float64).reshape(-1, 2, 2),
          np.ascontiguousarray(volume.vertices, np.float64).reshape(-1, 3))


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
