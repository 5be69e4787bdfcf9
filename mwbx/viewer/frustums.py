"""Query frustums drawn as translucent volumes with the camera they came from.

A frustum is given by its 8 world-space corners (metres), near face first,
then the far face in the same corner order, plus whether it includes (green)
or excludes (red). The solid is the convex hull of the corners, its outline
the hull edges between faces that are not coplanar, and the camera is the
point where the four side edges meet (absent for orthographic boxes).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import meshcat.geometry as mg
import numpy as np
import scipy.spatial

from mwbx.viewer.errors import ViewerError
from mwbx.viewer.geometry import Rgba

INCLUDE = Rgba(0.0, 0.85, 0.15, 0.22)
EXCLUDE = Rgba(0.95, 0.1, 0.1, 0.22)
CAMERA_RGBA = Rgba(0.15, 0.15, 0.15, 1.0)


class QueryVolume(NamedTuple):
  """A frustum to draw.

  corners: f64[8, 3] world-space corners in metres, near face then far face
    (far corner i lies on the ray from the camera through near corner i).
  include: True for a positive query (must pass through), False for negative.
  eye: f64[3] camera position, or None to infer it from the side edges.
  """

  corners: np.ndarray
  include: bool
  eye: np.ndarray | None = None


def as_volume(query: Any, index: int = 0) -> QueryVolume:
  """Turns one query description into a QueryVolume.

  Accepted: a QueryVolume; a (corners f[8, 3], include) pair; or an object
  with a `frustum` / `corners` attribute (mwbx.queries), where include comes
  from `include` / `positive` / `negative` and the eye from `camera`.
  """
  if isinstance(query, QueryVolume):
    corners, include, eye = query
  elif isinstance(query, tuple) and len(query) == 2:
    corners, include = query
    eye = None
  else:
    corners, include, eye = _from_query_object(query, index)
  corners = np.asarray(corners, np.float64)
  if corners.shape != (8, 3) or not np.all(np.isfinite(corners)):
    raise ViewerError(f"query {index}: frustum corners must be 8 finite 3-D points "
                      f"(near face then far face), got shape {corners.shape}")
  if eye is not None:
    eye = np.asarray(eye, np.float64).reshape(3)
  return QueryVolume(corners, bool(include), eye)


def _from_query_object(query: Any, index: int):
  frustum = getattr(query, "frustum", query)
  corners = getattr(frustum, "corners", None)
  if corners is None:
    raise ViewerError(f"query {index}: expected a QueryVolume, a (corners, include) pair or a "
                      f"query with frustum corners; got {type(query).__name__}")
  if hasattr(query, "include"):
    include = bool(query.include)
  elif hasattr(query, "positive"):
    include = bool(query.positive)
  elif hasattr(query, "negative"):
    include = not bool(query.negative)
  else:
    include = True
  camera = getattr(query, "camera", None) or getattr(frustum, "camera", None)
  eye = None
  for holder, name in ((camera, "position"), (camera, "pos"), (camera, "eye"), (frustum, "eye")):
    if holder is not None and getattr(holder, name, None) is not None:
      eye = getattr(holder, name)
      break
  return corners, include, eye


def hull_mesh(corners: np.ndarray, index: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """Convex hull of a frustum's corners.

  corners: f[8, 3]. Returns (vertices f32[8, 3], faces u32[F, 3] outward
  counter-clockwise, edges i64[E, 2] between non-coplanar faces).
  """
  try:
    hull = scipy.spatial.ConvexHull(corners)
  except scipy.spatial.QhullError as err:
    raise ViewerError(f"query {index}: frustum is empty or flat (its 8 corners span no volume)") from err
  faces = []
  centre = corners.mean(axis=0)
  for simplex in hull.simplices:
    a, b, c = corners[simplex]
    if np.dot(np.cross(b - a, c - a), a - centre) < 0:
      simplex = simplex[[0, 2, 1]]
    faces.append(simplex)
  normals = hull.equations[:, :3]
  edges = set()
  for i, simplex in enumerate(hull.simplices):
    for k in range(3):
      j = hull.neighbors[i, k]
      # The edge shared with neighbour j is the simplex minus its k-th vertex.
      if np.dot(normals[i], normals[j]) < 1.0 - 1e-9:
        edge = tuple(sorted(int(v) for v in np.delete(simplex, k)))
        edges.add(edge)
  return (corners.astype(np.float32), np.asarray(faces, np.uint32),
          np.asarray(sorted(edges), np.int64).reshape(-1, 2))


def frustum_eye(corners: np.ndarray) -> np.ndarray | None:
  """Least-squares meeting point of the four side edges (near i -> far i),
  behind the near face; None when they are parallel (orthographic)."""
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
  if max_depth is None:
    return corners
  near, far = corners[:4], corners[4:]
  longest = float(np.max(np.linalg.norm(far - near, axis=1)))
  if longest <= max_depth:
    return corners
  scale = max_depth / longest
  return np.concatenate([near, near + scale * (far - near)])


def draw_volume(vis, volume: QueryVolume, index: int = 0,
                max_depth: float | None = None, eye_radius: float = 0.02) -> None:
  """Draws one frustum under `vis`: "volume" (translucent), "outline", and,
  where a camera position is known, "camera" (eye sphere + rays to the near
  corners)."""
  rgba = INCLUDE if volume.include else EXCLUDE
  corners = truncate(volume.corners, max_depth)
  verts, faces, edges = hull_mesh(corners, index)
  vis["volume"].set_object(
      mg.TriangularMeshGeometry(verts, faces),
      mg.MeshBasicMaterial(color=rgba.hex(), opacity=float(rgba.a), transparent=True,
                           depthWrite=False))
  outline = np.ascontiguousarray(verts[edges.reshape(-1)].T)
  vis["outline"].set_object(mg.LineSegments(
      mg.PointsGeometry(outline), mg.LineBasicMaterial(color=rgba.hex())))
  eye = volume.eye if volume.eye is not None else frustum_eye(volume.corners)
  if eye is None:
    vis["camera"].delete()
    return
  rays = np.stack([np.repeat(eye[None], 4, axis=0), volume.corners[:4]], axis=1).reshape(-1, 3)
  vis["camera/rays"].set_object(mg.LineSegments(
      mg.PointsGeometry(np.ascontiguousarray(rays.T, dtype=np.float32)),
      mg.LineBasicMaterial(color=CAMERA_RGBA.hex())))
  vis["camera/eye"].set_object(mg.Sphere(float(eye_radius)),
                               mg.MeshBasicMaterial(color=CAMERA_RGBA.hex()))
  vis["camera/eye"].set_transform(_translation(eye))


def _translation(p: np.ndarray) -> np.ndarray:
  out = np.eye(4)
  out[:3, 3] = np.asarray(p, np.float64)
  return out
