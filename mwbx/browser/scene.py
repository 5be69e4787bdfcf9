"""What the page draws in 3-D: the scene, the played worlds' bodies, paths and frustums.

Moving bodies are drawn in *slots*: slot k holds one world being played. A
slot's meshes are uploaded to the clients once, the first time the slot is
used, and reused for every world played in it afterwards: playing a world
only moves the slot's body frames (poses), relabels it and shows it. The
scene's static geometry is drawn once; side by side, slot k > 0 gets its own
copy of it (uploaded once too), and every slot moves to its cell of a grid.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.viewer import geometry as vgeom
from mwbx.viewer import triangles

# Worlds played at once (overlaid or side by side), and the opacity of all
# but the first when overlaid.
MAX_SLOTS = 4
GHOST_OPACITY = 0.45
# Grid cells side by side: columns along world x, rows down world z; the gap
# between cells, as a fraction of the scene's extent.
GRID_COLUMNS = 2
GRID_GAP = 0.15
# Meshes neither cast nor receive shadows: shadow passes redraw the scene per
# light for every frame, which software WebGL cannot afford while a world plays.
NO_SHADOWS = {"cast_shadow": False, "receive_shadow": False}


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
    moving: body id -> [(name, vertices, faces, rgb, wxyz, position)] of its geoms.
    body_ids: i64[B] the moving bodies, in slot order.
    uploads: meshes sent to the clients so far (a replay sends none).
  """

  def __init__(self, server, model, extent):
    self.server = server
    self.model = model
    self.visuals = vgeom.scene_visuals(model)
    self.static: list = []
    self.moving: dict = {}
    for v in self.visuals:
      verts, faces = _mesh(v.geometry)
      wxyz, pos = _pose(v.local)
      item = (v.name, verts, faces, _rgb(v.rgba), wxyz, pos, None if v.rgba.a >= 1 else float(v.rgba.a))
      if v.static:
        self.static.append(item)
      else:
        self.moving.setdefault(int(v.body_id), []).append(item[:6])
    self.body_ids = np.array(sorted(self.moving), np.int64)
    lo, hi = (np.asarray(e, np.float64) for e in extent)
    size = np.maximum(hi - lo, 1e-3)
    self.cell = size * (1.0 + GRID_GAP)
    self.side_by_side = False
    self.uploads = 0
    self._slots: list = []  # per slot: (root frame, {body id: frame}, [mesh handles], label)
    self._copies: dict = {}  # slot -> frame holding a copy of the static scene
    for name, verts, faces, rgb, wxyz, pos, opacity in self.static:
      server.scene.add_mesh_simple(f"/scene/{name}", verts, faces, color=rgb, wxyz=wxyz, position=pos,
                                   opacity=opacity, **NO_SHADOWS)

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
    scene = self.server.scene
    root = scene.add_frame(f"/play/s{k}", show_axes=False, position=self.offset(k), visible=False)
    frames, meshes = {}, []
    for body in self.body_ids:
      frames[int(body)] = scene.add_frame(f"/play/s{k}/b{body}", show_axes=False)
      for name, verts, faces, rgb, wxyz, position in self.moving[int(body)]:
        meshes.append(scene.add_mesh_simple(f"/play/s{k}/b{body}/{name}", verts, faces, color=rgb, wxyz=wxyz,
                                            position=position, opacity=self._opacity(k), **NO_SHADOWS))
        self.uploads += 1
    label = None
    if self.body_ids.size:  # the label rides on the slot's first body
      label = scene.add_label(f"/play/s{k}/b{self.body_ids[0]}/label", "")
    return root, frames, meshes, label

  def _opacity(self, k: int) -> float | None:
    return GHOST_OPACITY if k and not self.side_by_side else None

  def show(self, k: int, world: int | None) -> None:
    """Shows slot ``k`` labelled with world ``world``, or hides it (None)."""
    self.slot(k)
    root, _, _, label = self._slots[k]
    root.visible = world is not None
    if label is not None and world is not None:
      label.text = f"world {world}"

  def pose(self, k: int, pos: np.ndarray, quat: np.ndarray) -> None:
    """Moves slot ``k``'s bodies: pos f64[B, 3] metres, quat f64[B, 4] (w, x, y, z), in body_ids order."""
    frames = self.slot(k)
    for i, b in enumerate(self.body_ids):
      frame = frames[int(b)]
      frame.position = pos[i]
      frame.wxyz = quat[i]

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
        for name, verts, faces, rgb, wxyz, pos, opacity in self.static:
          scene.add_mesh_simple(f"/copies/s{k}/{name}", verts, faces, color=rgb, wxyz=wxyz, position=pos,
                                opacity=opacity, **NO_SHADOWS)
          self.uploads += 1
      if k in self._copies:
        self._copies[k].visible = on and k < len(self._slots) and self._slots[k][0].visible

  def refresh_copies(self) -> None:
    """Shows the static copies of the cells whose slot is showing a world."""
    for k, frame in self._copies.items():
      frame.visible = self.side_by_side and k < len(self._slots) and self._slots[k][0].visible

  def remove(self) -> None:
    """Takes everything this stage drew off the page (the model changed)."""
    for path in ("/play", "/copies", "/scene"):
      self.server.scene.remove_by_name(path)
    self._slots, self._copies = [], {}
