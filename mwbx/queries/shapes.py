"""Geom shapes as convex cores plus a radius, in their body's frame.

Every geom a whole-geometry query tests is written as a convex polytope (the
core: its vertices, face normals, edge directions and edges) grown by a ball
of radius `radius` (the Minkowski sum), which is exactly a sphere (a point
core), a capsule (a segment), a box (its 8 corners, radius 0) or a convex
mesh (the convex hull of its vertices, as MuJoCo collides it). Shapes that
are not of this form get a circumscribing core, a superset whose excess is
`excess` metres at most:

* cylinder: the prism over the regular 16-gon circumscribing its disk
  (excess r (1/cos(pi/16) - 1), about 2 % of the radius);
* ellipsoid, height field and SDF geoms: their bounding box.

Planes are skipped (an infinite plane on a moving body is not a shape a
query can be asked about).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from mwbx.queries.poses import quat_rotate

GEOM_PLANE, GEOM_HFIELD, GEOM_SPHERE, GEOM_CAPSULE, GEOM_ELLIPSOID, GEOM_CYLINDER, GEOM_BOX, GEOM_MESH = range(8)
PRISM_SIDES = 16  # sides of the polygon circumscribing a cylinder's disk


@dataclasses.dataclass(frozen=True)
class Core:
  """One geom as a convex core grown by a ball, in its body's frame.

  vertices: f64[V, 3] core vertices, metres (body frame).
  normals: f64[N, 3] unit face normals of the core (N may be 0).
  directions: f64[D, 3] unit edge directions of the core (D may be 0).
  edges: i64[E, 2] vertex index pairs of the core's edges (E may be 0).
  radius: metres, the ball the core is grown by.
  excess: metres, how far the shape may reach beyond the true geom.
  geom: the MuJoCo geom id.
  """

  vertices: np.ndarray
  normals: np.ndarray
  directions: np.ndarray
  edges: np.ndarray
  radius: float
  excess: float
  geom: int


def _box(half: np.ndarray):
  signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
  vertices = signs * half
  edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(signs[i] != signs[j]) == 1]
  eye = np.eye(3)
  return vertices, eye, eye, np.array(edges, np.int64)


def _prism(radius: float, half_height: float):
  k = PRISM_SIDES
  angles = 2 * np.pi * (np.arange(k) + 0.5) / k
  reach = radius / np.cos(np.pi / k)
  ring = np.stack([reach * np.cos(angles), reach * np.sin(angles)], axis=1)
  vertices = np.concatenate([np.c_[ring, np.full(k, -half_height)], np.c_[ring, np.full(k, half_height)]])
  ring_dirs = np.roll(ring, -1, axis=0) - ring  # counter-clockwise sides
  ring_dirs = np.c_[ring_dirs / np.linalg.norm(ring_dirs, axis=1, keepdims=True), np.zeros(k)]
  sides = np.stack([ring_dirs[:, 1], -ring_dirs[:, 0], np.zeros(k)], axis=1)  # outward
  normals = np.concatenate([sides, [[0.0, 0.0, 1.0]]])
  directions = np.concatenate([ring_dirs, [[0.0, 0.0, 1.0]]])
  nxt = (np.arange(k) + 1) % k
  edges = np.concatenate([np.c_[np.arange(k), nxt], np.c_[np.arange(k) + k, nxt + k],
                          np.c_[np.arange(k), np.arange(k) + k]])
  return vertices, normals, directions, edges.astype(np.int64), reach - radius


def _hull(points: np.ndarray):
  """Vertices, face normals, edge directions and edges of a point set's hull."""
  from scipy.spatial import ConvexHull, QhullError
  try:
    hull = ConvexHull(points)
  except (QhullError, ValueError):  # flat or degenerate: every point, no faces
    return points, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2), np.int64)
  keep = hull.vertices
  index = {int(v): i for i, v in enumerate(keep)}
  normals = _unique_directions(hull.equations[:, :3], signed=True)
  pairs = {tuple(sorted((index[int(s[a])], index[int(s[b])]))) for s in hull.simplices
           for a, b in ((0, 1), (1, 2), (0, 2))}
  edges = np.array(sorted(pairs), np.int64)
  vertices = points[keep]
  directions = _unique_directions(vertices[edges[:, 1]] - vertices[edges[:, 0]], signed=False)
  return vertices, normals, directions, edges


def _unique_directions(vectors: np.ndarray, signed: bool) -> np.ndarray:
  """Unit vectors with near-duplicates (and, unsigned, opposites) removed."""
  v = vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-300)
  if not signed:
    flip = (v[:, 0] < 0) | ((v[:, 0] == 0) & ((v[:, 1] < 0) | ((v[:, 1] == 0) & (v[:, 2] < 0))))
    v = np.where(flip[:, None], -v, v)
  _, first = np.unique(np.round(v, 9), axis=0, return_index=True)
  return v[np.sort(first)]


def geom_core(model: mujoco.MjModel, geom: int) -> Core | None:
  """A geom's core in its body's frame; None for a plane."""
  kind = int(model.geom_type[geom])
  size = np.asarray(model.geom_size[geom], np.float64)
  excess, radius = 0.0, 0.0
  normals = directions = np.zeros((0, 3))
  edges = np.zeros((0, 2), np.int64)
  if kind == GEOM_PLANE:
    return None
  if kind == GEOM_SPHERE:
    vertices, radius = np.zeros((1, 3)), float(size[0])
  elif kind == GEOM_CAPSULE:
    vertices = np.array([[0.0, 0.0, -size[1]], [0.0, 0.0, size[1]]])
    directions, edges, radius = np.array([[0.0, 0.0, 1.0]]), np.array([[0, 1]]), float(size[0])
  elif kind == GEOM_BOX:
    vertices, normals, directions, edges = _box(size)
  elif kind == GEOM_CYLINDER:
    vertices, normals, directions, edges, excess = _prism(float(size[0]), float(size[1]))
  elif kind == GEOM_MESH and int(model.geom_dataid[geom]) >= 0:
    mesh = int(model.geom_dataid[geom])
    start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    vertices, normals, directions, edges = _hull(np.asarray(model.mesh_vert[start:start + count], np.float64))
  else:  # ellipsoid, height field, SDF: the bounding box in the geom frame
    aabb = np.asarray(model.geom_aabb[geom], np.float64)
    vertices, normals, directions, edges = _box(aabb[3:])
    vertices = vertices + aabb[:3]
    excess = float(np.linalg.norm(aabb[3:]))
  q = np.asarray(model.geom_quat[geom], np.float64)
  to_body = lambda v: quat_rotate(q, v)
  return Core(model.geom_pos[geom] + to_body(vertices), to_body(normals), to_body(directions),
              edges, radius, excess, int(geom))


def body_cores(model: mujoco.MjModel, body: int) -> list[Core]:
  """The cores of a body's own geoms (planes left out), and of the flex
  vertices it carries (:func:`flex_vertex_cores`)."""
  cores = [geom_core(model, int(g)) for g in np.flatnonzero(model.geom_bodyid == body)]
  return [c for c in cores if c is not None] + flex_vertex_cores(model, body)


def flex_vertex_cores(model: mujoco.MjModel, body: int) -> list[Core]:
  """A flex vertex on this body as a point grown by its flex's radius (what
  MuJoCo collides there); geom -1. A flex's whole geometry is its vertices
  so grown: the surface between vertices is not tested."""
  empty = np.zeros((0, 3))
  out = []
  for f in range(model.nflex):
    adr, n = int(model.flex_vertadr[f]), int(model.flex_vertnum[f])
    for v in np.flatnonzero(np.asarray(model.flex_vertbodyid[adr:adr + n]) == body):
      point = np.asarray(model.flex_vert[adr + v], np.float64).reshape(1, 3)
      out.append(Core(point, empty, empty, np.zeros((0, 2), np.int64), float(model.flex_radius[f]), 0.0, -1))
  return out


def reach(model: mujoco.MjModel, body: int, cores: list[Core]) -> float:
  """Metres from the body's centre of mass to the farthest point of its cores
  (0 without geoms)."""
  ipos = np.asarray(model.body_ipos[body], np.float64)
  return max([float(np.max(np.linalg.norm(c.vertices - ipos, axis=1))) + c.radius for c in cores],
             default=0.0)
