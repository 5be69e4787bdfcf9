"""Scene geometry for meshcat, read from a compiled `mujoco.MjModel`.

Each visible geom becomes one `GeomVisual`: a meshcat geometry, its MJCF colour
and its pose in the frame of the body that carries it. Geoms on bodies welded
to the world are static (drawn once at their world pose); the rest hang off
moving bodies whose poses come from forward kinematics per recorded frame.
"""

from __future__ import annotations

from typing import NamedTuple

import meshcat.geometry as mg
import mujoco
import numpy as np

from mwbx.viewer.display import DEFAULT_VISIBLE_GROUPS, Rgba  # noqa: F401 (re-exported)
from mwbx.viewer.errors import ViewerError

# Thickness of the slab drawn for a plane (planes are infinite half-spaces).
PLANE_THICKNESS = 0.01
# Vertices a height field is drawn with at most (larger grids: every k-th row
# and column).
HFIELD_MAX_VERTICES = 128 * 128
# MuJoCo's default geom rgba: a geom with a material and this rgba takes the
# material's colour (as in mjv_updateScene).
_DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0], np.float32)


class GeomVisual(NamedTuple):
  """One drawable geom.

  name: unique node name (meshcat path element).
  geom_id: MuJoCo geom id.
  body_id: MuJoCo id of the body carrying it (0 = world).
  static: True when the geom never moves (its body is welded to the world).
  geometry: the meshcat geometry, in the geom's own frame.
  rgba: MJCF colour.
  shininess: MJCF material shininess in [0, 1].
  local: f64[4, 4] pose of the geom in its body frame (static: world frame).
  """

  name: str
  geom_id: int
  body_id: int
  static: bool
  geometry: mg.Geometry
  rgba: Rgba
  shininess: float
  local: np.ndarray


def pose_matrix(pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
  """f64[4, 4] homogeneous transform from a position and a wxyz quaternion."""
  mat = np.zeros(9)
  mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
  out = np.eye(4)
  out[:3, :3] = mat.reshape(3, 3)
  out[:3, 3] = pos
  return out


def capsule_mesh(radius: float, half_length: float, n_around: int = 24,
                 n_cap: int = 6) -> tuple[np.ndarray, np.ndarray]:
  """Triangle mesh of a capsule along z (meshcat has no capsule primitive).

  Returns (vertices f32[N, 3] in metres, faces u32[F, 3] counter-clockwise seen
  from outside), a closed surface: one vertex per pole, `n_cap` rings per
  hemisphere (the two equator rings, shifted by -/+ half_length, bound the
  cylindrical middle), `n_around` vertices per ring.
  """
  # Ring latitudes in (-pi/2, pi/2), bottom to top; the poles are single vertices.
  lat_bottom = np.linspace(-np.pi / 2, 0.0, n_cap + 1)[1:]
  lats = np.concatenate([lat_bottom, -lat_bottom[::-1]])
  shift = np.concatenate([np.full(n_cap, -half_length), np.full(n_cap, half_length)])
  lon = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
  ring_r = radius * np.cos(lats)[:, None]
  ring_z = np.broadcast_to((radius * np.sin(lats) + shift)[:, None], (lats.size, n_around))
  rings = np.stack([ring_r * np.cos(lon)[None, :], ring_r * np.sin(lon)[None, :], ring_z],
                   axis=-1).reshape(-1, 3)
  bottom = np.array([[0.0, 0.0, -half_length - radius]])
  top = np.array([[0.0, 0.0, half_length + radius]])
  verts = np.concatenate([bottom, rings, top])
  n_rings = lats.size
  ring = lambda i, j: 1 + i * n_around + j % n_around  # noqa: E731
  top_id = verts.shape[0] - 1
  faces = []
  for j in range(n_around):
    faces.append((0, ring(0, j + 1), ring(0, j)))
    faces.append((top_id, ring(n_rings - 1, j), ring(n_rings - 1, j + 1)))
    for i in range(n_rings - 1):
      a, b = ring(i, j), ring(i, j + 1)
      c, d = ring(i + 1, j), ring(i + 1, j + 1)
      faces.append((a, b, d))
      faces.append((a, d, c))
  return verts.astype(np.float32), np.asarray(faces, np.uint32)


def geom_rgba(model: mujoco.MjModel, geom_id: int) -> Rgba:
  """The colour MuJoCo draws a geom with: its rgba, or its material's rgba
  when the geom has a material and its rgba was left at the default."""
  rgba = np.asarray(model.geom_rgba[geom_id], np.float32)
  mat = int(model.geom_matid[geom_id])
  if mat >= 0 and np.array_equal(rgba, _DEFAULT_GEOM_RGBA):
    rgba = np.asarray(model.mat_rgba[mat], np.float32)
  return Rgba(*(float(v) for v in rgba))


def geom_shininess(model: mujoco.MjModel, geom_id: int) -> float:
  mat = int(model.geom_matid[geom_id])
  return float(model.mat_shininess[mat]) if mat >= 0 else 0.5


def geom_shape(model: mujoco.MjModel, geom_id: int,
               plane_extent: float) -> tuple[mg.Geometry, np.ndarray] | None:
  """The meshcat geometry of one geom and a f64[4, 4] correction from the
  meshcat primitive's frame to the MuJoCo geom frame; None for geom types
  without a surface to draw (an sdf without a mesh, decor types).

  plane_extent: half-size in metres used for planes declared infinite (size 0).
  """
  gtype = int(model.geom_type[geom_id])
  size = np.asarray(model.geom_size[geom_id], np.float64)
  fix = np.eye(4)
  T = mujoco.mjtGeom
  if gtype == T.mjGEOM_PLANE:
    hx = size[0] if size[0] > 0 else plane_extent
    hy = size[1] if size[1] > 0 else plane_extent
    fix[2, 3] = -PLANE_THICKNESS / 2  # top face at z = 0
    return mg.Box([2 * float(hx), 2 * float(hy), PLANE_THICKNESS]), fix
  if gtype == T.mjGEOM_BOX:
    return mg.Box([float(2 * s) for s in size]), fix
  if gtype == T.mjGEOM_SPHERE:
    return mg.Sphere(float(size[0])), fix
  if gtype == T.mjGEOM_ELLIPSOID:
    return mg.Ellipsoid(np.asarray(size, np.float64)), fix
  if gtype == T.mjGEOM_CYLINDER:
    # three.js cylinders lie along +y; MuJoCo's along +z.
    fix[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    return mg.Cylinder(float(2 * size[1]), float(size[0])), fix
  if gtype == T.mjGEOM_CAPSULE:
    verts, faces = capsule_mesh(float(size[0]), float(size[1]))
    return mg.TriangularMeshGeometry(verts, faces), fix
  if gtype == T.mjGEOM_MESH or (gtype == T.mjGEOM_SDF and int(model.geom_dataid[geom_id]) >= 0):
    # An sdf geom draws the mesh its plugin made (MuJoCo's viewer does too).
    mesh = int(model.geom_dataid[geom_id])
    v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    verts = np.asarray(model.mesh_vert[v0:v0 + nv], np.float32)
    faces = np.asarray(model.mesh_face[f0:f0 + nf], np.uint32)
    return mg.TriangularMeshGeometry(verts, faces), fix
  if gtype == T.mjGEOM_HFIELD:
    return mg.TriangularMeshGeometry(*hfield_mesh(model, int(model.geom_dataid[geom_id]))), fix
  return None


def hfield_mesh(model: mujoco.MjModel, hfield_id: int,
                max_vertices: int = HFIELD_MAX_VERTICES) -> tuple[np.ndarray, np.ndarray]:
  """Triangles of a height field in its geom's frame, as MuJoCo places it.

  Row r, column c of the ``nrow x ncol`` elevation grid (normalized to [0, 1])
  is at ``x = sx·(2c/(ncol-1) - 1)``, ``y = sy·(2r/(nrow-1) - 1)``,
  ``z = sz·elevation`` for ``hfield_size = (sx, sy, sz, base)``; the solid
  below reaches down to ``z = -base``. A grid over ``max_vertices`` is drawn
  every k-th row and column (edges kept).

  Returns:
    (vertices f32[V, 3] metres, faces u32[F, 3] counter-clockwise from outside):
    the top surface, four side walls and the bottom.
  """
  nrow, ncol = int(model.hfield_nrow[hfield_id]), int(model.hfield_ncol[hfield_id])
  sx, sy, sz, base = (float(v) for v in model.hfield_size[hfield_id])
  adr = int(model.hfield_adr[hfield_id])
  height = np.asarray(model.hfield_data[adr:adr + nrow * ncol], np.float64).reshape(nrow, ncol) * sz
  k = max(1, int(np.ceil(np.sqrt(nrow * ncol / max_vertices))))
  rows = np.unique(np.append(np.arange(0, nrow, k), nrow - 1))
  cols = np.unique(np.append(np.arange(0, ncol, k), ncol - 1))
  height = height[np.ix_(rows, cols)]
  x = sx * (2.0 * cols / max(ncol - 1, 1) - 1.0)
  y = sy * (2.0 * rows / max(nrow - 1, 1) - 1.0)
  # A closed grid: the top surface, and the same grid at z = -base below it.
  nr, nc = rows.size, cols.size
  xx, yy = np.meshgrid(x, y)  # [nr, nc]
  top = np.stack([xx, yy, height], axis=-1).reshape(-1, 3)
  bottom = np.stack([xx, yy, np.full_like(height, -base)], axis=-1).reshape(-1, 3)
  verts = np.concatenate([top, bottom])
  at = lambda r, c, lower=0: lower * nr * nc + r * nc + c  # noqa: E731
  r, c = np.meshgrid(np.arange(nr - 1), np.arange(nc - 1), indexing="ij")
  r, c = r.reshape(-1), c.reshape(-1)
  quads = [np.stack([at(r, c), at(r, c + 1), at(r + 1, c + 1)], -1),  # top, facing +z
           np.stack([at(r, c), at(r + 1, c + 1), at(r + 1, c)], -1),
           np.stack([at(r, c, 1), at(r + 1, c + 1, 1), at(r, c + 1, 1)], -1),  # bottom, facing -z
           np.stack([at(r, c, 1), at(r + 1, c, 1), at(r + 1, c + 1, 1)], -1)]
  walls = []
  # Each wall: an edge of the grid walked so that the outside is on its right
  # seen from above, joined to the bottom copy of the same edge.
  for edge in ([at(0, j) for j in range(nc)], [at(i, nc - 1) for i in range(nr)],
               [at(nr - 1, j) for j in range(nc - 1, -1, -1)], [at(i, 0) for i in range(nr - 1, -1, -1)]):
    e = np.asarray(edge)
    a, b = e[:-1], e[1:]
    walls += [np.stack([a, a + nr * nc, b + nr * nc], -1), np.stack([a, b + nr * nc, b], -1)]
  faces = np.concatenate(quads + walls).astype(np.uint32)
  return verts.astype(np.float32), faces


def _node_name(prefix: str, name: str, idx: int) -> str:
  # '/' separates meshcat path elements; keep names readable but unique.
  clean = name.replace("/", "_") if name else ""
  return f"{prefix}{idx}_{clean}" if clean else f"{prefix}{idx}"


def body_node_name(model: mujoco.MjModel, body_id: int) -> str:
  """Meshcat node name of a moving body (its MJCF name where it has one)."""
  name = model.body(body_id).name
  return name.replace("/", "_") if name else f"body{body_id}"


def static_geom_poses(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
  """World poses of all geoms at the model's reference configuration qpos0:
  (pos f64[ngeom, 3] metres, mat f64[ngeom, 3, 3])."""
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  return data.geom_xpos.copy(), data.geom_xmat.reshape(-1, 3, 3).copy()


def scene_visuals(model: mujoco.MjModel,
                  visible_groups: tuple[int, ...] = DEFAULT_VISIBLE_GROUPS,
                  plane_extent: float | None = None) -> list[GeomVisual]:
  """All drawable geoms of `model` (visible groups, nonzero alpha).

  plane_extent: half-size in metres for infinite planes; defaults to the
  model's statistical extent (`model.stat.extent`) times 2.
  """
  if plane_extent is None:
    plane_extent = max(2.0 * float(model.stat.extent), 1.0)
  if plane_extent <= 0:
    raise ViewerError(f"plane_extent must be positive, got {plane_extent}")
  static_pos, static_mat = static_geom_poses(model)
  visuals = []
  for g in range(model.ngeom):
    if int(model.geom_group[g]) not in visible_groups:
      continue
    rgba = geom_rgba(model, g)
    if rgba.a <= 0.0:
      continue
    shape = geom_shape(model, g, plane_extent)
    if shape is None:
      continue
    geometry, fix = shape
    body = int(model.geom_bodyid[g])
    static = int(model.body_weldid[body]) == 0
    if static:
      frame = np.eye(4)
      frame[:3, :3] = static_mat[g]
      frame[:3, 3] = static_pos[g]
    else:
      frame = pose_matrix(model.geom_pos[g], model.geom_quat[g])
    visuals.append(GeomVisual(
        name=_node_name("g", model.geom(g).name, g),
        geom_id=g,
        body_id=body,
        static=static,
        geometry=geometry,
        rgba=rgba,
        shininess=geom_shininess(model, g),
        local=frame @ fix,
    ))
  return visuals


def moving_body_ids(visuals: list[GeomVisual]) -> np.ndarray:
  """i32[K] ids of the bodies that carry at least one moving visual geom."""
  return np.asarray(sorted({v.body_id for v in visuals if not v.static}), np.int32)


def material(rgba: Rgba, shininess: float = 0.5, tint: Rgba | None = None,
             tint_weight: float = 0.5, opacity: float | None = None) -> mg.Material:
  """A lit meshcat material for a geom colour, optionally mixed towards a
  tint colour (weight in [0, 1]) and with an overriding opacity."""
  rgb = np.asarray(rgba[:3], np.float64)
  if tint is not None:
    rgb = (1.0 - tint_weight) * rgb + tint_weight * np.asarray(tint[:3], np.float64)
  alpha = float(rgba.a if opacity is None else opacity * rgba.a)
  color = Rgba(*rgb, alpha)
  translucent = alpha < 1.0
  return mg.MeshPhongMaterial(
      color=color.hex(),
      opacity=alpha,
      transparent=translucent,
      depthWrite=not translucent,
      shininess=float(2.0 + 98.0 * shininess),
  )
