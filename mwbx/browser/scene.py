"""What the page draws in 3-D: the scene, the played worlds' bodies, paths and frustums.

Moving bodies are drawn in *slots*: slot k holds one world being played. A
slot's meshes are uploaded to the clients once, the first time the slot is
used, and reused for every world played in it afterwards: playing a world
only moves the slot's body frames (poses), relabels it and shows it. The
scene's static geometry is drawn once; side by side, slot k > 0 gets its own
copy of it (uploaded once too), and every slot moves to its cell of a grid.
A plane is drawn as a grid of lines over its declared size, not as a filled
slab (software WebGL shades every pixel of a floor that fills half the view).
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from mwbx.browser import glb
from mwbx.errors import MwbxError
from mwbx.viewer import flex as flex_lib
from mwbx.viewer import geometry as vgeom
from mwbx.viewer import triangles

# Worlds played at once (overlaid or side by side), and the opacity of all
# but the first when overlaid.
MAX_SLOTS = 4
GHOST_OPACITY = 0.45
# The scene as a world starts, drawn while no world plays.
START_OPACITY = 0.3
# Grid cells side by side: columns along world x, rows down world z; the gap
# between cells, as a fraction of the scene's extent.
GRID_COLUMNS = 2
GRID_GAP = 0.15
# Meshes neither cast nor receive shadows: shadow passes redraw the scene per
# light for every frame, which software WebGL cannot afford while a world plays.
NO_SHADOWS = {"cast_shadow": False, "receive_shadow": False}
# A plane's grid: about this many cells along its longer side, the spacing
# rounded to 1, 2 or 5 times a power of ten (metres), and the line colour
# the plane's blended this far towards the page's white background.
PLANE_GRID_CELLS = 20
PLANE_GRID_FADE = 0.4


class StaticMesh(NamedTuple):
  """A static geom drawn as a mesh: f32[V, 3] vertices (m), i32[F, 3] faces,
  sRGB 0-255, its world pose, and its opacity (None: opaque)."""

  name: str
  vertices: np.ndarray
  faces: np.ndarray
  rgb: tuple[int, int, int]
  wxyz: np.ndarray
  position: np.ndarray
  opacity: float | None


class StaticLines(NamedTuple):
  """A static plane drawn as a grid of lines: a GLB of :mod:`mwbx.browser.glb`
  in the plane's frame, and the plane's world pose."""

  name: str
  glb_data: bytes
  wxyz: np.ndarray
  position: np.ndarray


def grid_spacing(length: float, cells: int = PLANE_GRID_CELLS) -> float:
  """The round spacing (1, 2 or 5 x 10^k metres) nearest above ``length / cells``."""
  raw = max(float(length) / cells, 1e-6)
  power = 10.0 ** np.floor(np.log10(raw))
  return float(next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw * (1 - 1e-9)))


def plane_grid(half_x: float, half_y: float) -> np.ndarray:
  """f32[N, 2, 3] a plane's grid in its own frame (z = 0, the surface): lines
  at multiples of :func:`grid_spacing` from the centre, and the border, metres."""
  step = grid_spacing(2 * max(half_x, half_y))
  xs = np.unique(np.concatenate([np.arange(0, half_x, step), -np.arange(0, half_x, step), [-half_x, half_x]]))
  ys = np.unique(np.concatenate([np.arange(0, half_y, step), -np.arange(0, half_y, step), [-half_y, half_y]]))
  along_y = [[[x, -half_y, 0.0], [x, half_y, 0.0]] for x in xs]
  along_x = [[[-half_x, y, 0.0], [half_x, y, 0.0]] for y in ys]
  return np.asarray(along_y + along_x, np.float32)


def _mesh(geometry) -> tuple[np.ndarray, np.ndarray]:
  """(f32[V, 3], i32[F, 3]) triangles of a meshcat geometry, in its own frame."""
  try:
    return triangles.triangles(geometry)
  except triangles.UnknownGeometry as err:
    raise MwbxError(f"browse: {err}") from None


def _pose(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(wxyz, position) of a 4x4 transform."""
  quat = np.zeros(4)
  mujoco.mju_mat2Quat(quat, np.ascontiguousarray(matrix[:3, :3]).reshape(-1))
  return quat, np.asarray(matrix[:3, 3], np.float64)


def _rgb(rgba) -> tuple[int, int, int]:
  return tuple(int(round(255 * float(c))) for c in rgba[:3])


class Stage:
  """The scene of one model on a viser server, with MAX_SLOTS reusable slots.

  Args:
    server: the viser server.
    model: the bank's MuJoCo model.
    extent: (lo f64[3], hi f64[3]) metres, the box the worlds move in (the
      grid's cell size side by side).

  Attributes:
    visuals: the model's visuals (:func:`mwbx.viewer.geometry.scene_visuals`).
    static: the geoms that never move (:class:`StaticMesh`, planes :class:`StaticLines`).
    moving: body id -> [(name, vertices, faces, rgb, wxyz, position)] of its geoms.
    body_ids: i64[B] the moving bodies, in slot order.
    flexes: the flexes' surfaces (:func:`mwbx.viewer.flex.flex_surfaces`),
      redrawn from their vertex bodies at every pose.
    pose_ids: i64[B + V] the bodies whose poses :meth:`pose` takes: the
      moving bodies, then every flex's vertex bodies.
    uploads: meshes sent to the clients so far (a replay sends none).
  """

  def __init__(self, server, model, extent):
    self.server = server
    self.model = model
    self.visuals = vgeom.scene_visuals(model)
    self.static: list = []
    self.moving: dict = {}
    for v in self.visuals:
      if v.static and int(model.geom_type[v.geom_id]) == mujoco.mjtGeom.mjGEOM_PLANE:
        self.static.append(self._plane(v))
        continue
      verts, faces = _mesh(v.geometry)
      wxyz, pos = _pose(v.local)
      if v.static:
        self.static.append(StaticMesh(v.name, verts, faces, _rgb(v.rgba), wxyz, pos,
                                      None if v.rgba.a >= 1 else float(v.rgba.a)))
      else:
        self.moving.setdefault(int(v.body_id), []).append((v.name, verts, faces, _rgb(v.rgba), wxyz, pos))
    self.body_ids = np.array(sorted(self.moving), np.int64)
    self.flexes = flex_lib.flex_surfaces(model)
    self.pose_ids = np.concatenate([self.body_ids] + [f.bodies for f in self.flexes]).astype(np.int64)
    lo, hi = (np.asarray(e, np.float64) for e in extent)
    size = np.maximum(hi - lo, 1e-3)
    self.cell = size * (1.0 + GRID_GAP)
    self.side_by_side = False
    self.uploads = 0
    self._slots: list = []  # per slot: (root frame, {body id: frame}, [mesh handles], label)
    self._start = None  # (root frame, {body id: frame}, [meshes]): the scene as it starts (show_start)
    self._copies: dict = {}  # slot -> frame holding a copy of the static scene
    for item in self.static:
      self._add_static(f"/scene/{item.name}", item)

  @staticmethod
  def _plane(v) -> StaticLines:
    """A static plane visual's grid, on its surface (the slab's top face,
    PLANE_THICKNESS above the slab's centre)."""
    half_x, half_y = (float(l) / 2 for l in v.geometry.lengths[:2])
    wxyz, centre = _pose(v.local)
    surface = centre + v.local[:3, 2] * (vgeom.PLANE_THICKNESS / 2)  # along the slab's normal
    rgb = v.rgba._replace(a=1.0 - PLANE_GRID_FADE).over((1.0, 1.0, 1.0))
    return StaticLines(v.name, glb.line_segments(plane_grid(half_x, half_y), rgb), wxyz, surface)

  def _add_static(self, path: str, item: StaticMesh | StaticLines) -> None:
    if isinstance(item, StaticLines):
      self.server.scene.add_glb(path, item.glb_data, wxyz=item.wxyz, position=item.position, **NO_SHADOWS)
    else:
      self.server.scene.add_mesh_simple(path, item.vertices, item.faces, color=item.rgb, wxyz=item.wxyz,
                                        position=item.position, opacity=item.opacity, **NO_SHADOWS)

  def offset(self, slot: int) -> np.ndarray:
    """f64[3] where slot ``slot`` sits: the origin overlaid, its grid cell side by side."""
    if not self.side_by_side:
      return np.zeros(3)
    col, row = slot % GRID_COLUMNS, slot // GRID_COLUMNS
    return np.array([col * self.cell[0], 0.0, -row * self.cell[2]])

  def slot(self, k: int) -> dict:
    """{body id: frame} of slot ``k``, its meshes uploaded the first time only."""
    while len(self._slots) <= k:
      self._slots.append(self._make_slot(len(self._slots)))
    return self._slots[k][1]

  def _make_slot(self, k: int):
    root, frames, meshes = self._make_bodies(f"/play/s{k}", self.offset(k), self._opacity(k))
    label = None
    if self.body_ids.size:  # the label rides on the slot's first body
      label = self.server.scene.add_label(f"/play/s{k}/b{self.body_ids[0]}/label", "")
    return root, frames, meshes, label

  def _make_bodies(self, path: str, position, opacity: float | None):
    """(root frame, {body id: frame}, [meshes]) of every moving body and flex
    under ``path``, hidden, where the model starts."""
    scene = self.server.scene
    root = scene.add_frame(path, show_axes=False, position=position, visible=False)
    frames, meshes = {}, []
    for body in self.body_ids:
      frames[int(body)] = scene.add_frame(f"{path}/b{body}", show_axes=False)
      for name, verts, faces, rgb, wxyz, pos in self.moving[int(body)]:
        meshes.append(scene.add_mesh_simple(f"{path}/b{body}/{name}", verts, faces, color=rgb, wxyz=wxyz,
                                            position=pos, opacity=opacity, **NO_SHADOWS))
        self.uploads += 1
    data = mujoco.MjData(self.model) if self.flexes else None
    if data is not None:
      mujoco.mj_kinematics(self.model, data)
    for f in self.flexes:  # drawn where the model starts; every pose moves its vertices
      vertices = f.vertices(data.xpos[f.bodies], data.xquat[f.bodies])
      rgb = tuple(int(c) for c in np.clip(np.round(f.rgba[:3] * 255), 0, 255))
      meshes.append(scene.add_mesh_simple(f"{path}/flex/{f.name}", vertices, f.faces, color=rgb,
                                          side="double", opacity=opacity, **NO_SHADOWS))
      self.uploads += 1
    return root, frames, meshes

  def show_start(self, pos: np.ndarray, quat: np.ndarray) -> None:
    """Draws every moving body where a world starts (pos f64[N, 3], quat
    f64[N, 4] in pose_ids order), dimmed, while no world plays: the page
    opens on the scene, not on an empty grid."""
    if self._start is None:
      self._start = self._make_bodies("/start", np.zeros(3), START_OPACITY)
    root, frames, meshes = self._start
    for i, b in enumerate(self.body_ids):
      frames[int(b)].position = pos[i]
      frames[int(b)].wxyz = quat[i]
    at = len(self.body_ids)
    for f, mesh in zip(self.flexes, meshes[-len(self.flexes):] if self.flexes else ()):
      n = len(f.bodies)
      mesh.vertices = f.vertices(pos[at:at + n], quat[at:at + n])
      at += n
    self._update_start()

  def _update_start(self) -> None:
    if self._start is not None:
      self._start[0].visible = not any(slot[0].visible for slot in self._slots)

  def _opacity(self, k: int) -> float | None:
    return GHOST_OPACITY if k and not self.side_by_side else None

  def show(self, k: int, world: int | None) -> None:
    """Shows slot ``k`` labelled with world ``world``, or hides it (None)."""
    self.slot(k)
    root, _, _, label = self._slots[k]
    root.visible = world is not None
    if label is not None and world is not None:
      label.text = f"world {world}"
    self._update_start()

  def pose(self, k: int, pos: np.ndarray, quat: np.ndarray) -> None:
    """Moves slot ``k``'s bodies and flexes: pos f64[N, 3] metres, quat f64[N, 4] (w, x, y, z), in
    pose_ids order (the moving bodies first)."""
    frames = self.slot(k)
    for i, b in enumerate(self.body_ids):
      frame = frames[int(b)]
      frame.position = pos[i]
      frame.wxyz = quat[i]
    if self.flexes:
      meshes = self._slots[k][2][-len(self.flexes):]
      at = len(self.body_ids)
      for f, mesh in zip(self.flexes, meshes):
        n = len(f.bodies)
        mesh.vertices = f.vertices(pos[at:at + n], quat[at:at + n])
        at += n

  def set_side_by_side(self, on: bool) -> None:
    """Overlay (every slot at the origin, all but the first translucent) or a
    grid of cells, each with its own copy of the static scene."""
    self.side_by_side = bool(on)
    scene = self.server.scene
    for k, (root, _, meshes, _) in enumerate(self._slots):
      root.position = self.offset(k)
      for mesh in meshes:
        mesh.opacity = self._opacity(k)
    for k in range(1, MAX_SLOTS):
      if on and k not in self._copies and self.static:
        self._copies[k] = scene.add_frame(f"/copies/s{k}", show_axes=False, position=self.offset(k))
        for item in self.static:
          self._add_static(f"/copies/s{k}/{item.name}", item)
          self.uploads += 1
      if k in self._copies:
        self._copies[k].visible = on and k < len(self._slots) and self._slots[k][0].visible

  def refresh_copies(self) -> None:
    """Shows the static copies of the cells whose slot is showing a world."""
    for k, frame in self._copies.items():
      frame.visible = self.side_by_side and k < len(self._slots) and self._slots[k][0].visible

  def remove(self) -> None:
    """Takes everything this stage drew off the page (the model changed)."""
    for path in ("/play", "/copies", "/scene", "/start"):
      self.server.scene.remove_by_name(path)
    self._slots, self._copies, self._start = [], {}, None
