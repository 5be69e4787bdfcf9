"""Convex hulls of a few points: the solid and outline of a query volume.

Pure numpy (no front end): :mod:`mwbx.viewer.display` builds what both
viewers draw from these.
"""

from __future__ import annotations

import numpy as np

from mwbx.viewer.errors import ViewerError


def hull_mesh(points: np.ndarray, index: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """Convex hull of a few points (a frustum's 8 corners, or the vertices of
  a convex volume), by testing every plane through three of them.

  points: f[N, 3], N small (<= ~30). Returns (vertices f32[N, 3], faces
  u32[F, 3] counter-clockwise seen from outside, edges i64[E, 2] along the
  boundary of each flat face, i.e. between faces that are not coplanar).
  """
  pts = np.asarray(points, np.float64)
  scale = max(float(np.ptp(pts, axis=0).max()) if pts.size else 0.0, 1e-12)
  eps = 1e-9 * scale
  _, sing, basis = np.linalg.svd(pts - pts.mean(axis=0))
  if sing.size < 3 or sing[2] <= 1e-9 * max(sing[0], 1e-300):
    return _flat_polygon(pts, basis, eps, index)
  planes: list[tuple[np.ndarray, float]] = []
  n_pts = pts.shape[0]
  for i in range(n_pts):
    for j in range(i + 1, n_pts):
      for k in range(j + 1, n_pts):
        normal = np.cross(pts[j] - pts[i], pts[k] - pts[i])
        length = np.linalg.norm(normal)
        if length <= eps * scale:
          continue
        normal /= length
        dist = pts @ normal - normal @ pts[i]
        if np.all(dist <= eps):
          plane = (normal, float(normal @ pts[i]))
        elif np.all(dist >= -eps):
          plane = (-normal, float(-normal @ pts[i]))
        else:
          continue
        if not any(np.allclose(plane[0], n, atol=1e-9) and abs(plane[1] - o) <= eps for n, o in planes):
          planes.append(plane)
  if len(planes) < 4:
    raise ViewerError(f"query {index}: frustum is empty or flat (its corners span no volume)")
  faces, edges = [], set()
  for normal, offset in planes:
    on = np.flatnonzero(np.abs(pts @ normal - offset) <= eps)
    # The face is the 2-D hull of its points, counter-clockwise about the
    # outward normal (points inside the face or repeated are dropped).
    u = pts[on[1:]] - pts[on[0]]
    u = u[np.argmax(np.linalg.norm(u, axis=1))]
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    ring = on[_hull_2d(np.stack([pts[on] @ u, pts[on] @ v], axis=1), eps)]
    for a in range(1, ring.size - 1):
      faces.append((ring[0], ring[a], ring[a + 1]))
    for a in range(ring.size):
      edges.add(tuple(sorted((int(ring[a]), int(ring[(a + 1) % ring.size])))))
  return (pts.astype(np.float32), np.asarray(faces, np.uint32),
          np.asarray(sorted(edges), np.int64).reshape(-1, 2))


def _flat_polygon(pts: np.ndarray, basis: np.ndarray, eps: float, index: int):
  """hull_mesh for points in one plane (e.g. the wedge of a zero-width screen
  box): the polygon they span, drawn from both sides."""
  xy = np.stack([pts @ basis[0], pts @ basis[1]], axis=1)
  ring = _hull_2d(xy, eps)
  if ring.size < 3:
    raise ViewerError(f"query {index}: frustum is empty (its corners lie on one line or point)")
  faces = [(ring[0], ring[a], ring[a + 1]) for a in range(1, ring.size - 1)]
  edges = sorted(tuple(sorted((int(ring[a]), int(ring[(a + 1) % ring.size])))) for a in range(ring.size))
  return pts.astype(np.float32), np.asarray(faces, np.uint32), np.asarray(edges, np.int64).reshape(-1, 2)


def _hull_2d(xy: np.ndarray, eps: float) -> np.ndarray:
  """Indices of the convex hull of f[N, 2] points, counter-clockwise, without
  collinear or repeated points (Andrew's monotone chain)."""
  order = np.lexsort((xy[:, 1], xy[:, 0]))

  def cross(o, a, b):
    return (xy[a, 0] - xy[o, 0]) * (xy[b, 1] - xy[o, 1]) - (xy[a, 1] - xy[o, 1]) * (xy[b, 0] - xy[o, 0])

  def chain(idx):
    out: list[int] = []
    for i in idx:
      while len(out) >= 2 and cross(out[-2], out[-1], i) <= eps * eps:
        out.pop()
      out.append(int(i))
    return out

  lower, upper = chain(order), chain(order[::-1])
  return np.asarray(lower[:-1] + upper[:-1], np.int64)


def plane_vertices(normals: np.ndarray, offsets: np.ndarray, index: int = 0) -> np.ndarray:
  """f64[N, 3] vertices of the convex volume {p : normals @ p <= offsets},
  from every three planes that meet in a point inside all the others."""
  normals = np.asarray(normals, np.float64)
  offsets = np.asarray(offsets, np.float64)
  scale = max(float(np.abs(offsets).max()), 1.0)
  found: list[np.ndarray] = []
  n = normals.shape[0]
  for i in range(n):
    for j in range(i + 1, n):
      for k in range(j + 1, n):
        a = normals[[i, j, k]]
        if abs(np.linalg.det(a)) < 1e-9:
          continue
        p = np.linalg.solve(a, offsets[[i, j, k]])
        if np.all(normals @ p - offsets <= 1e-9 * scale) and not any(np.allclose(p, q) for q in found):
          found.append(p)
  if len(found) < 4:
    raise ViewerError(f"query {index}: frustum is unbounded or flat and has no display corners")
  return np.asarray(found)


def frustum_eye(corners: np.ndarray) -> np.ndarray | None:
  """Least-squares meeting point of the four side edges (near i -> far i),
  behind the near face; None when they are parallel (orthographic)."""
  if corners.shape[0] != 8:
    return None
  near, far = corners[:4], corners[4:]
  dirs = far - near
  norms = np.linalg.norm(dirs, axis=1)
  if np.any(norms <= 0):
    return None
  dirs = dirs / norms[:, None]
  proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]  # [4, 3, 3]
  lhs = proj.sum(axis=0)
  rhs = np.einsum("kij,kj->i", proj, near)
  if np.linalg.cond(lhs) > 1e8:
    return None
  eye = np.linalg.solve(lhs, rhs)
  # A real apex lies on the near side, backwards along every edge.
  if np.any(np.einsum("ki,ki->k", near - eye[None], dirs) <= 0):
    return None
  return eye


def truncate(corners: np.ndarray, max_depth: float | None) -> np.ndarray:
  """Moves the far face towards the near face so no side edge is longer than
  max_depth metres (one common factor keeps the far face planar)."""
  if max_depth is None or corners.shape[0] != 8:
    return corners
  near, far = corners[:4], corners[4:]
  longest = float(np.max(np.linalg.norm(far - near, axis=1)))
  if longest <= max_depth:
    return corners
  scale = max_depth / longest
  return np.concatenate([near, near + scale * (far - near)])
