"""Triangle meshes of the meshcat geometries `mwbx.viewer.geometry` makes.

The browsing page (viser) draws triangles only; this turns each meshcat
primitive into triangles in the primitive's own frame (three.js conventions:
a cylinder runs along +y), so both views draw the same shapes. Plain numpy: no
mesh library is needed.
"""

from __future__ import annotations

import meshcat.geometry as mg
import numpy as np

# Segments around a sphere, an ellipsoid or a cylinder (and latitude rings
# of a sphere: half as many).
AROUND = 24


class UnknownGeometry(TypeError):
  """A meshcat geometry type this module does not triangulate."""


def box(lengths) -> tuple[np.ndarray, np.ndarray]:
  """(f32[8, 3], i32[12, 3]) a box of edge lengths (x, y, z), centred, metres."""
  half = np.asarray(lengths, np.float64).reshape(3) / 2
  signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
  # Corner index = 4·[x>0] + 2·[y>0] + [z>0]; two triangles per face, outward.
  faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5),  # -x, +x
           (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),  # -y, +y
           (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]  # -z, +z
  return (signs * half).astype(np.float32), np.asarray(faces, np.int32)


def sphere(radius: float = 1.0, around: int = AROUND) -> tuple[np.ndarray, np.ndarray]:
  """(f32[V, 3], i32[F, 3]) a UV sphere of `radius` about the origin, with
  vertices on the poles and the equator (its extent is exactly ±radius)."""
  rings = around // 2
  lat = np.linspace(-np.pi / 2, np.pi / 2, rings + 1)[1:-1]
  lon = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
  ring = np.stack([np.cos(lat)[:, None] * np.cos(lon), np.cos(lat)[:, None] * np.sin(lon),
                   np.broadcast_to(np.sin(lat)[:, None], (lat.size, around))], axis=-1).reshape(-1, 3)
  verts = np.concatenate([[[0.0, 0.0, -1.0]], ring, [[0.0, 0.0, 1.0]]]) * radius
  idx = lambda i, j: 1 + i * around + j % around  # noqa: E731
  top = verts.shape[0] - 1
  faces = []
  for j in range(around):
    faces += [(0, idx(0, j + 1), idx(0, j)), (top, idx(lat.size - 1, j), idx(lat.size - 1, j + 1))]
    for i in range(lat.size - 1):
      faces += [(idx(i, j), idx(i, j + 1), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i + 1, j))]
  return verts.astype(np.float32), np.asarray(faces, np.int32)


def cylinder(height: float, radius_top: float, radius_bottom: float,
             around: int = AROUND) -> tuple[np.ndarray, np.ndarray]:
  """(f32[V, 3], i32[F, 3]) a closed (possibly tapered) cylinder along +y,
  centred, as three.js's CylinderGeometry: the top (+y) cap of `radius_top`."""
  lon = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
  circle = np.stack([np.sin(lon), np.zeros(around), np.cos(lon)], axis=-1)
  bottom = circle * radius_bottom + [0.0, -height / 2, 0.0]
  top = circle * radius_top + [0.0, height / 2, 0.0]
  verts = np.concatenate([bottom, top, [[0.0, -height / 2, 0.0], [0.0, height / 2, 0.0]]])
  b_centre, t_centre = 2 * around, 2 * around + 1
  faces = []
  for j in range(around):
    k = (j + 1) % around
    faces += [(j, around + k, around + j), (j, k, around + k),  # side
              (b_centre, k, j), (t_centre, around + j, around + k)]  # caps
  return verts.astype(np.float32), np.asarray(faces, np.int32)


def triangles(geometry: mg.Geometry) -> tuple[np.ndarray, np.ndarray]:
  """(f32[V, 3] metres, i32[F, 3]) triangles of a meshcat geometry in its own frame.

  Raises:
    UnknownGeometry: a geometry type without a triangulation here.
  """
  if isinstance(geometry, mg.Box):
    return box(geometry.lengths)
  if isinstance(geometry, mg.Ellipsoid):  # before Sphere: an Ellipsoid is one
    verts, faces = sphere(1.0)
    return (verts * np.asarray(geometry.radii, np.float32).reshape(1, 3)), faces
  if isinstance(geometry, mg.Sphere):
    return sphere(float(geometry.radius))
  if isinstance(geometry, mg.Cylinder):
    return cylinder(float(geometry.height), float(geometry.radiusTop), float(geometry.radiusBottom))
  if isinstance(geometry, mg.TriangularMeshGeometry):
    return np.asarray(geometry.vertices, np.float32), np.asarray(geometry.faces, np.int32)
  raise UnknownGeometry(f"cannot triangulate geometry {type(geometry).__name__}")
