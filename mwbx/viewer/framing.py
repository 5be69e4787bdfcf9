"""Framing the first view: what is shown, and where meshcat's camera looks from.

The pose itself is :func:`mwbx.viewer.display.camera_pose` (shared with the
page); an MJCF camera is posed by :meth:`mwbx.queries.Camera.from_model`.
meshcat's orbit controls always orbit the display origin, so the caller
shifts the scene by the returned centre; the camera is placed relative to it.
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np

from mwbx.bank import versions
from mwbx.errors import MwbxError
from mwbx.queries import Camera
from mwbx.queries import paths
from mwbx.viewer.display import DEFAULT_VISIBLE_GROUPS, PathClasses, ViewSpec, camera_pose
from mwbx.viewer.errors import ViewerError

# Field of view (degrees) used when the model has no MJCF camera to copy.
DEFAULT_FOVY = 50.0
# Viewing direction (from the scene towards the eye) without an MJCF camera.
DEFAULT_VIEW_DIR = np.array([1.0, -1.4, 0.9])


def scene_bounds(bank, model: mujoco.MjModel, worlds: np.ndarray,
                 path_classes: PathClasses | None, bodies: np.ndarray | None,
                 visible_groups: tuple[int, ...] = DEFAULT_VISIBLE_GROUPS) -> tuple[np.ndarray, np.ndarray]:
  """(lo f64[3], hi f64[3]) box around what is shown: the COM paths of the
  played-back worlds (all bodies, widened by the largest moving geom) and of
  the drawn paths, and the boxes of the visible static geoms other than planes
  and height fields."""
  com = bank.com  # (a lazily opened bank's: only the rows asked for are read)
  pts = [_finite_extent(bank, worlds, np.arange(com.shape[2]))]
  visible = np.isin(model.geom_group, visible_groups) & (model.geom_rgba[:, 3] > 0)
  moving = visible & (model.body_weldid[model.geom_bodyid] != 0)
  if pts[0].size and moving.any():
    margin = float(model.geom_rbound[moving].max())
    pts[0] = pts[0] + np.array([[-margin], [margin]])
  if path_classes is not None and bodies is not None:
    pts.append(_finite_extent(bank, np.concatenate(list(path_classes)), bodies))
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  # Grounds (planes, height fields) can be far larger than where anything goes.
  ground = np.isin(model.geom_type, [int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_HFIELD)])
  static = np.flatnonzero(visible & (model.body_weldid[model.geom_bodyid] == 0) & ~ground)
  signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
  for g in static:
    centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
    local = centre[None] + signs * half[None]  # [8, 3] box corners in the geom frame
    pts.append(data.geom_xpos[g][None] + local @ data.geom_xmat[g].reshape(3, 3).T)
  pts = np.concatenate(pts, axis=0)
  pts = pts[np.all(np.isfinite(pts), axis=1)]
  if pts.shape[0] == 0:
    centre = np.asarray(model.stat.center, np.float64)
    half = max(float(model.stat.extent), 0.5)
    return centre - half, centre + half
  return pts.min(axis=0).astype(np.float64), pts.max(axis=0).astype(np.float64)


def _finite_extent(bank, worlds: np.ndarray, bodies: np.ndarray, chunk: int = 1024) -> np.ndarray:
  """f64[k, 3] (k = 0 or 2) finite min and max over bank.com[worlds][:, :, bodies]
  (objects parked while absent from a world left out), in chunks of worlds so a
  large bank is never copied whole; from the stored path boxes of a lazily
  opened bank, reading only the worlds whose boxes hold a point not finite or
  may hold a parked one."""
  com = bank.com
  worlds, bodies = np.asarray(worlds, np.int64), np.asarray(bodies, np.int64)
  lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
  if worlds.size and bodies.size and paths.has_stored_boxes(bank):
    boxes = paths.stored_boxes(bank)
    box_lo = boxes.lo[worlds][:, bodies].astype(np.float64)  # [k, b, 3]
    box_hi = boxes.hi[worlds][:, bodies].astype(np.float64)
    nearest = np.clip(versions.PARKED_POSITION, box_lo, box_hi)  # the box's point nearest the parking place
    plain = (np.isfinite(box_lo).all(axis=-1) & np.isfinite(box_hi).all(axis=-1)
             & ~versions.is_parked(nearest)).all(axis=1)  # [k]
    if plain.any():
      lo, hi = box_lo[plain].min(axis=(0, 1)), box_hi[plain].max(axis=(0, 1))
    worlds = worlds[~plain]
  for start in range(0, len(worlds), chunk):
    part = com[worlds[start:start + chunk]][:, :, bodies].reshape(-1, 3).astype(np.float64)
    part = part[np.all(np.isfinite(part), axis=1) & ~versions.is_parked(part)]
    if part.size:
      lo, hi = np.minimum(lo, part.min(axis=0)), np.maximum(hi, part.max(axis=0))
  return np.stack([lo, hi]) if np.all(np.isfinite(lo)) else np.zeros((0, 3))


def scene_camera(model: mujoco.MjModel) -> int:
  """Id of the model's first named camera that looks at the scene from a
  fixed place (mode ``fixed``, on the world or a body welded to it), or -1.

  A camera riding on a moving body (an egocentric head camera) or tracking one
  (``track``, ``trackcom``, ``targetbody*``) says where a body is seen from,
  not where the scene is: its direction at the reference pose is arbitrary.
  """
  for cam in range(model.ncam):
    fixed = int(model.cam_mode[cam]) == int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)
    if fixed and int(model.body_weldid[model.cam_bodyid[cam]]) == 0 and model.camera(cam).name:
      return cam
  return -1


def view_spec(model: mujoco.MjModel, camera: str | None = None,
              view_dir: Sequence[float] | None = None) -> ViewSpec:
  """camera: an MJCF camera name to view exactly from; None fits the scene
  into view, looking along `view_dir` (f[3], scene towards eye), else along
  the model's first fixed scene camera (:func:`scene_camera`), else
  obliquely from the front right."""
  if camera is not None:
    try:
      cam = Camera.from_model(model, camera)
    except MwbxError as err:
      raise ViewerError(str(err)) from None
    return ViewSpec(-cam.forward, cam.fovy, cam.eye)
  cam = scene_camera(model)
  fovy = float(model.cam_fovy[cam]) if cam >= 0 else DEFAULT_FOVY
  if view_dir is not None:
    direction = np.asarray(view_dir, np.float64).reshape(-1)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.any(direction):
      raise ViewerError(f"view_dir: must be a finite nonzero 3-vector, got {direction.tolist()}")
  elif cam >= 0:
    direction = -Camera.from_model(model, model.camera(cam).name).forward
  else:
    direction = DEFAULT_VIEW_DIR
  return ViewSpec(direction / np.linalg.norm(direction), fovy, None)


def place_camera(vis, lo: np.ndarray, hi: np.ndarray, spec: ViewSpec) -> tuple[np.ndarray, np.ndarray]:
  """Aims meshcat's camera at the box [lo, hi]. Returns (centre f64[3],
  eye f64[3]) in world coordinates; the caller shifts the scene by -centre."""
  radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.2)
  pose = camera_pose(lo, hi, spec)
  centre, eye = pose.target, pose.eye
  d = eye - centre
  cam = vis["/Cameras/default/rotated/<object>"]
  # The camera's parent is rotated +90 deg about x (three.js is y-up):
  # world (x, y, z) = local (x, -z, y).
  cam.set_property("position", [float(d[0]), float(d[2]), float(-d[1])])
  cam.set_property("fov", pose.fovy)
  cam.set_property("far", float(max(100.0, 20 * (radius + np.linalg.norm(d)))))
  return centre, eye
