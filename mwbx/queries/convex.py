"""Exact tests of convex shapes against a query volume, by separating axes.

A shape here is a convex core (vertices) grown by a ball of radius `grow`;
the volume is a frustum clipped to a box holding every shape (so it has
vertices and edges; the clip box lies beyond every shape and changes no
answer). The shape meets the volume iff the distance between the core and
the volume is at most `grow`. A distance is at least the gap between the
two projections onto any axis, and equals it for the axis through the two
closest points, which joins a pair of features: a face and a vertex (a face
normal), two edges (their cross product), two vertices (their difference),
or a vertex and an edge (the perpendicular from one to the other). Every
such axis is tried, so the test is exact, not only conservative; a shape is
declared apart only for an axis whose gap exceeds `grow` by more than a
rounding tolerance, so rounding can only add hits.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from mwbx.queries.frustum import Frustum

CHUNK = 256  # candidates tested at once by `separated` (memory ~ CHUNK * axes * vertices)


class Polytope(NamedTuple):
  """A frustum clipped to a box, as the separating-axis test needs it.

  normals: f64[F, 3], offsets: f64[F] the frustum's own planes (n·p <= off).
  vertices: f64[V, 3] (V = 0: the volume is empty inside the box).
  edge_starts: f64[E, 3], edge_dirs: f64[E, 3] unit; directions: f64[D, 3]
  the unique edge directions. tol: metres, the rounding tolerance.
  """

  normals: np.ndarray
  offsets: np.ndarray
  vertices: np.ndarray
  edge_starts: np.ndarray
  edge_dirs: np.ndarray
  directions: np.ndarray
  tol: float


def clipped(frustum: Frustum, lo, hi) -> Polytope:
  """The frustum cut by the box [lo, hi] (metres), with vertices and edges."""
  lo = np.asarray(lo, np.float64)
  hi = np.asarray(hi, np.float64)
  eye = np.eye(3)
  normals = np.concatenate([frustum.normals.astype(np.float64), eye, -eye])
  offsets = np.concatenate([frustum.offsets, hi, -lo])
  scale = 1.0 + float(np.max(np.abs(np.concatenate([lo, hi]))))
  tol = 1e-9 * scale
  vertices, planes = [], []
  for tri in itertools.combinations(range(len(normals)), 3):
    m = normals[list(tri)]
    if abs(np.linalg.det(m)) < 1e-9:
      continue
    v = np.linalg.solve(m, offsets[list(tri)])
    if np.all(normals @ v - offsets <= tol):
      vertices.append(v)
      planes.append(set(tri))
  if not vertices:
    empty = np.zeros((0, 3))
    return Polytope(normals[:-6], offsets[:-6], empty, empty, empty, empty, tol)
  vertices = np.array(vertices)
  on = np.abs(vertices @ normals.T - offsets) <= 1e3 * tol  # [V, F'] vertex lies on plane
  starts, dirs = [], []
  for i, j in itertools.combinations(range(len(normals)), 2):
    d = np.cross(normals[i], normals[j])
    if np.linalg.norm(d) < 1e-9:
      continue
    d /= np.linalg.norm(d)
    ends = vertices[on[:, i] & on[:, j]]
    if len(ends) < 2:
      continue
    t = ends @ d
    if t.max() - t.min() <= tol:
      continue
    starts.append(ends[np.argmin(t)])
    dirs.append(d)
  starts = np.array(starts).reshape(-1, 3)
  dirs = np.array(dirs).reshape(-1, 3)
  unique = _unsigned_unique(dirs)
  return Polytope(normals[:-6], offsets[:-6], _dedupe(vertices), starts, dirs, unique, tol)


def point_distances(points: np.ndarray, volume: Polytope) -> np.ndarray:
  """Exact distance of points f64[..., 3] to the volume, metres: 0 inside,
  else the nearest of their projections onto the volume's faces, edge lines
  and vertices that lies in the volume (the closest point of a convex
  polytope is one of these). inf for an empty volume."""
  n = volume.normals
  dist = points @ n.T - volume.offsets  # [..., F]
  inside = np.all(dist <= volume.tol, axis=-1)
  best = np.where(inside, 0.0, np.inf)
  cos = n @ n.T
  d = np.maximum(dist, 0.0)
  # Faces: moving onto plane i changes distance j by -d_i cos_ij.
  on_face = dist[..., None, :] - d[..., :, None] * cos  # [..., i, j]
  ok = np.all(on_face <= volume.tol, axis=-1)
  best = np.minimum(best, np.min(np.where(ok, d, np.inf), axis=-1))
  # Edge lines: the nearest point q = p - a d_i n_i... solved for planes i, j.
  for i, j in itertools.combinations(range(len(n)), 2):
    g = np.array([[1.0, cos[i, j]], [cos[i, j], 1.0]])
    if abs(np.linalg.det(g)) < 1e-9:
      continue
    coef = np.stack([dist[..., i], dist[..., j]], axis=-1) @ np.linalg.inv(g).T  # [..., 2]
    q = points - coef[..., :1] * n[i] - coef[..., 1:] * n[j]
    ok = np.all(q @ n.T - volume.offsets <= volume.tol, axis=-1)
    best = np.minimum(best, np.where(ok, np.linalg.norm(points - q, axis=-1), np.inf))
  if len(volume.vertices):
    gap = np.linalg.norm(points[..., None, :] - volume.vertices, axis=-1).min(axis=-1)
    best = np.minimum(best, gap)
  return best


def _dedupe(points: np.ndarray) -> np.ndarray:
  _, first = np.unique(np.round(points, 9), axis=0, return_index=True)
  return points[np.sort(first)]


def _unsigned_unique(dirs: np.ndarray) -> np.ndarray:
  if len(dirs) == 0:
    return dirs
  flip = np.sum(dirs * np.array([1.0, 1e-3, 1e-6]), axis=1) < 0
  d = np.where(flip[:, None], -dirs, dirs)
  return _dedupe(d)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(unit vectors, usable bool[...]) of f64[..., 3]; zero ones unusable."""
  norm = np.linalg.norm(v, axis=-1, keepdims=True)
  ok = norm[..., 0] > 1e-12
  return v / np.where(norm > 1e-12, norm, 1.0), ok


def _perpendicular(w: np.ndarray, d: np.ndarray) -> np.ndarray:
  """Component of w f64[..., 3] orthogonal to unit d f64[..., 3]."""
  return w - np.sum(w * d, axis=-1, keepdims=True) * d


def separated(points: np.ndarray, rotation: np.ndarray, normals: np.ndarray, directions: np.ndarray,
              edges: np.ndarray, grow: np.ndarray, volume: Polytope) -> np.ndarray:
  """Which cores are farther than `grow` from the volume.

  Args:
    points: f64[n, V, 3] the core's vertices in the world, metres.
    rotation: f64[n, 3, 3] body-to-world rotations (for the core's normals and
      edge directions).
    normals: f64[N, 3] the core's face normals, body frame.
    directions: f64[D, 3] the core's edge directions, body frame.
    edges: i64[E, 2] the core's edges (vertex index pairs).
    grow: f64[n] radius plus margin, metres.
    volume: the clipped frustum.

  Returns:
    bool[n]: True where some axis separates core and volume by more than
    `grow` (the shape misses the volume); every candidate with no separating
    axis is False.
  """
  n = len(points)
  out = np.zeros(n, bool)
  if len(volume.vertices) == 0:
    out[:] = True
    return out
  for s in range(0, n, CHUNK):
    part = slice(s, min(n, s + CHUNK))
    # The face, edge-pair and vertex-pair axes first; the vertex-edge ones only
    # for what they leave undecided.
    found = _separated(points[part], rotation[part], normals, directions, edges, grow[part], volume, False)
    rest = np.flatnonzero(~found)
    if rest.size:
      found[rest] = _separated(points[part][rest], rotation[part][rest], normals, directions, edges,
                               grow[part][rest], volume, True)
    out[part] = found
  return out


def _separated(x, rot, normals, directions, edges, grow, volume, vertex_edge: bool) -> np.ndarray:
  n = len(x)
  pv = volume.vertices
  axes = [np.broadcast_to(volume.normals, (n,) + volume.normals.shape)]
  if vertex_edge:
    return _gap_exceeds(_vertex_edge_axes(x, edges, volume), x, pv, grow, volume.tol)
  if len(normals):
    axes.append(np.einsum("nij,kj->nki", rot, normals))
  if len(directions) and len(volume.directions):
    d = np.einsum("nij,kj->nki", rot, directions)  # [n, D, 3]
    axes.append(np.cross(d[:, :, None], volume.directions[None, None]).reshape(n, -1, 3))
  axes.append((x[:, :, None] - pv[None, None]).reshape(n, -1, 3))  # vertex-vertex
  return _gap_exceeds(np.concatenate(axes, axis=1), x, pv, grow, volume.tol)


def _vertex_edge_axes(x, edges, volume) -> np.ndarray:
  """f64[n, A, 3] perpendiculars between core vertices and volume edges and
  between volume vertices and core edges."""
  n = len(x)
  axes = [np.zeros((n, 0, 3))]
  if len(volume.edge_starts):  # core vertex - volume edge
    w = x[:, :, None] - volume.edge_starts[None, None]
    axes.append(_perpendicular(w, volume.edge_dirs[None, None]).reshape(n, -1, 3))
  if len(edges):  # volume vertex - core edge
    a = x[:, edges[:, 0]]
    e, _ = _unit(x[:, edges[:, 1]] - a)  # [n, E, 3]
    w = volume.vertices[None, None] - a[:, :, None]  # [n, E, V, 3]
    axes.append(_perpendicular(w, e[:, :, None]).reshape(n, -1, 3))
  return np.concatenate(axes, axis=1)


def _gap_exceeds(axes, x, pv, grow, tol) -> np.ndarray:
  """bool[n]: along some axis f64[n, A, 3], core x f64[n, V, 3] and volume
  vertices pv f64[Vp, 3] lie apart by more than grow f64[n] (+ tol)."""
  if axes.shape[1] == 0:
    return np.zeros(len(x), bool)
  u, ok = _unit(axes)  # [n, A, 3]
  core = np.einsum("nav,nkv->nak", u, x)  # [n, A, Vc]
  vol = np.einsum("nav,kv->nak", u, pv)  # [n, A, Vp]
  gap = np.maximum(core.min(axis=2) - vol.max(axis=2), vol.min(axis=2) - core.max(axis=2))
  gap = np.where(ok, gap, -np.inf)
  return np.any(gap > grow[:, None] + tol, axis=1)
