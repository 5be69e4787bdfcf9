"""Cameras, screen boxes and the world-space frustum a box sweeps out.

Screen coordinates are normalised image coordinates (u, v) in [0, 1]^2 with
the origin at the top-left corner, u to the right and v down, as on a screen.
A camera looks along `forward` with `up` and `right` spanning the image, like
an MJCF camera (which looks along its -z axis, y up). A perspective camera has
a vertical field of view `fovy` in degrees; an orthographic one a vertical
view height `fovy` in metres (MuJoCo's convention for both).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries.frustum import Frustum

# Display depth of a frustum without a far plane, metres (viewers clip it).
_DISPLAY_FAR = 100.0
# Largest magnitude of a camera coordinate, near/far depth (metres) or screen
# coordinate: far beyond any scene, and small enough that the view math
# (cross products, norms) never overflows float64.
MAX_COORDINATE = 1e9


@dataclasses.dataclass(frozen=True)
class ScreenBox:
  """A box on the screen in normalised coordinates, origin top-left.

  u0 <= u1 (left, right) and v0 <= v1 (top, bottom); the box may extend past
  [0, 1] (then it reaches beyond the visible image). A box of zero width or
  height is allowed: its frustum is a flat wedge that only crossing paths meet.
  """

  u0: float
  v0: float
  u1: float
  v1: float

  def __post_init__(self):
    values = (self.u0, self.v0, self.u1, self.v1)
    if not all(math.isfinite(float(x)) and abs(float(x)) <= MAX_COORDINATE for x in values):
      raise MwbxError(f"box: coordinates must be finite numbers within ±{MAX_COORDINATE:g}, got {list(values)}")
    if self.u0 > self.u1 or self.v0 > self.v1:
      raise MwbxError(
          f"box: empty, expected [u0, v0, u1, v1] with u0 <= u1 and v0 <= v1, got {list(values)}")

  @classmethod
  def from_corners(cls, a, b) -> ScreenBox:
    """The box spanned by two opposite corners (u, v), in any order."""
    (ua, va), (ub, vb) = a, b
    return cls(min(ua, ub), min(va, vb), max(ua, ub), max(va, vb))

  @classmethod
  def from_pixels(cls, x0, y0, x1, y1, width: int, height: int) -> ScreenBox:
    """A box in pixels of a width x height image (origin top-left)."""
    return cls.from_corners((x0 / width, y0 / height), (x1 / width, y1 / height))


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
  """A pinhole (or orthographic) camera in world coordinates.

  eye: f64[3] position, metres. right, up, forward: f64[3] orthonormal axes.
  fovy: vertical field of view in degrees (orthographic: view height, m).
  aspect: image width / height. name: MJCF camera name or "".
  """

  eye: np.ndarray
  right: np.ndarray
  up: np.ndarray
  forward: np.ndarray
  fovy: float
  aspect: float
  orthographic: bool = False
  name: str = ""

  def __repr__(self) -> str:
    kind = ", orthographic" if self.orthographic else ""
    return (f"Camera({self.name!r}, eye={np.round(self.eye, 3).tolist()}, fovy={self.fovy:g},"
            f" aspect={self.aspect:.4g}{kind})")

  def __post_init__(self):
    for field in ("eye", "right", "up", "forward"):  # checked here, not as a frustum's planes later
      object.__setattr__(self, field, _vec3(getattr(self, field), field))
    if not (math.isfinite(self.aspect) and 0 < self.aspect <= MAX_COORDINATE):
      raise MwbxError(f"camera: aspect must be a positive number up to {MAX_COORDINATE:g}, got {self.aspect}")
    limit = MAX_COORDINATE if self.orthographic else 180.0
    if not (math.isfinite(self.fovy) and 0 < self.fovy <= limit and (self.orthographic or self.fovy < limit)):
      what = "view height (m) > 0" if self.orthographic else "fovy in (0, 180) degrees"
      raise MwbxError(f"camera: {what} expected, got {self.fovy}")

  @classmethod
  def look_at(cls, eye, target, up=(0.0, 0.0, 1.0), fovy: float = 45.0,
              aspect: float = 4.0 / 3.0, orthographic: bool = False) -> Camera:
    """A camera at `eye` looking at `target` with `up` roughly up (metres)."""
    eye = _vec3(eye, "eye")
    forward = _vec3(target, "target") - eye
    if np.linalg.norm(forward) == 0:
      raise MwbxError(f"camera: eye and target coincide at {eye.tolist()}")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, _vec3(up, "up"))
    if np.linalg.norm(right) < 1e-9:
      raise MwbxError(f"camera: up {list(up)} is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    return cls(eye, right, true_up, forward, float(fovy), float(aspect), bool(orthographic))

  @classmethod
  def from_model(cls, model: mujoco.MjModel, name: str,
                 aspect: float | None = None) -> Camera:
    """An MJCF camera, posed at the model's initial configuration (qpos0).

    aspect: None uses the model's offscreen buffer (visual/global offwidth /
      offheight), the image size MuJoCo renders that camera at.
    """
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam_id < 0:
      names = [model.camera(i).name for i in range(model.ncam)]
      raise MwbxError(f"camera: no MJCF camera named {name!r} (cameras: {names})")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    xmat = data.cam_xmat[cam_id].reshape(3, 3)
    if aspect is None:
      aspect = model.vis.global_.offwidth / model.vis.global_.offheight
    ortho = int(model.cam_projection[cam_id]) == int(mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC)
    return cls(
        eye=data.cam_xpos[cam_id].astype(np.float64).copy(),
        right=xmat[:, 0].astype(np.float64).copy(),
        up=xmat[:, 1].astype(np.float64).copy(),
        forward=-xmat[:, 2].astype(np.float64),
        fovy=float(model.cam_fovy[cam_id]),
        aspect=float(aspect),
        orthographic=ortho,
        name=name,
    )

  def to_dict(self) -> dict:
    """Its entry in a query file: an MJCF camera by name; any other as look-at
    (its own axes, exactly)."""
    if self.name:
      return {"mjcf": self.name, "aspect": float(self.aspect)}
    return {"eye": [float(x) for x in self.eye], "target": [float(x) for x in self.eye + self.forward],
            "up": [float(x) for x in self.up], "fovy": float(self.fovy), "aspect": float(self.aspect),
            "orthographic": bool(self.orthographic)}

  @property
  def half_height(self) -> float:
    """Half the image height at depth 1 (perspective) or in metres (ortho)."""
    if self.orthographic:
      return 0.5 * self.fovy
    return math.tan(math.radians(self.fovy) / 2)

  def project(self, points) -> tuple[np.ndarray, np.ndarray]:
    """World points to screen coordinates.

    Args:
      points: f[..., 3] metres.

    Returns:
      (uv: f64[..., 2] normalised screen coordinates, depth: f64[...] distance
      along `forward`, metres; points with depth <= 0 are behind a
      perspective camera and their uv is meaningless).
    """
    rel = np.asarray(points, np.float64) - self.eye
    x, y, depth = rel @ self.right, rel @ self.up, rel @ self.forward
    h = self.half_height
    if self.orthographic:
      sx, sy = x / (h * self.aspect), y / h
    else:
      with np.errstate(divide="ignore", invalid="ignore"):
        sx, sy = x / (depth * h * self.aspect), y / (depth * h)
    return np.stack([(sx + 1) / 2, (1 - sy) / 2], axis=-1), depth

  def unproject(self, uv, depth) -> np.ndarray:
    """Screen coordinates and depth along `forward` to world points.

    Args:
      uv: f[..., 2] normalised screen coordinates. depth: f[...] metres.

    Returns:
      f64[..., 3] metres.
    """
    uv = np.asarray(uv, np.float64)
    depth = np.asarray(depth, np.float64)
    h = self.half_height
    scale = 1.0 if self.orthographic else depth
    x = (2 * uv[..., 0] - 1) * h * self.aspect * scale
    y = (1 - 2 * uv[..., 1]) * h * scale
    return (self.eye + x[..., None] * self.right + y[..., None] * self.up
            + depth[..., None] * self.forward)

  def frustum(self, box: ScreenBox, near: float | None = None,
              far: float | None = None) -> Frustum:
    """The world-space volume a screen box sees.

    Args:
      box: the screen box.
      near: optional near plane, metres along `forward`. None: the eye (a
        perspective box's side planes already meet there; orthographic and
        zero-width boxes get a plane at depth 0).
      far: optional far plane, metres; None: unbounded.

    Returns:
      Frustum with 4 side planes plus the near/far planes given.
    """
    if near is not None and not (math.isfinite(near) and 0 <= near <= MAX_COORDINATE):
      raise MwbxError(f"near: must be a number from 0 to {MAX_COORDINATE:g} (metres), got {near}")
    if far is not None and not (math.isfinite(far) and 0 < far <= MAX_COORDINATE):
      raise MwbxError(f"far: must be a positive number up to {MAX_COORDINATE:g} (metres), got {far}")
    if near is not None and far is not None and near >= far:
      raise MwbxError(f"near/far: empty frustum, near {near} >= far {far}")
    degenerate = box.u0 == box.u1 or box.v0 == box.v1
    if near is None and (self.orthographic or degenerate):
      # Orthographic side planes do not meet, and a flat box's side planes
      # meet in a whole plane through the eye: keep only what is in front.
      near = 0.0
    fwd, right, up = self.forward, self.right, self.up
    h = self.half_height
    w = h * self.aspect
    left_x, right_x = 2 * box.u0 - 1, 2 * box.u1 - 1  # in [-1, 1] units
    top_y, bottom_y = 1 - 2 * box.v0, 1 - 2 * box.v1
    if self.orthographic:
      # Side planes are parallel to `forward`, at signed image offsets.
      dirs = [-right, right, up, -up]
      shifts = [-left_x * w, right_x * w, top_y * h, -bottom_y * h]
    else:
      dirs = [left_x * w * fwd - right, right - right_x * w * fwd,
              up - top_y * h * fwd, bottom_y * h * fwd - up]
      shifts = [0.0] * 4
    normals, offsets = [], []
    for d, shift in zip(dirs, shifts):
      n = (d / np.linalg.norm(d)).astype(np.float32).astype(np.float64)
      normals.append(n)
      offsets.append(float(n @ self.eye) + shift)
    if near is not None:
      n = (-fwd).astype(np.float32).astype(np.float64)
      normals.append(n)
      offsets.append(float(n @ self.eye) - near)
    if far is not None:
      n = fwd.astype(np.float32).astype(np.float64)
      normals.append(n)
      offsets.append(float(n @ self.eye) + far)
    corners = self.box_corners(box, near, far)
    eye = None if self.orthographic else self.eye.copy()
    return Frustum(np.asarray(normals, np.float32), np.asarray(offsets), corners, eye)

  def box_corners(self, box: ScreenBox, near: float | None = None,
                  far: float | None = None) -> np.ndarray:
    """f64[8, 3] corners of the box's frustum for display: near face (top-left,
    top-right, bottom-right, bottom-left), then the far face. Without a far
    plane the far face is drawn 100 m away; without a near plane the near
    face is 1/1000 of the far depth."""
    far_d = _DISPLAY_FAR if far is None else far
    near_d = far_d * 1e-3 if near is None else near
    uv = np.array([[box.u0, box.v0], [box.u1, box.v0], [box.u1, box.v1], [box.u0, box.v1]])
    return np.concatenate([self.unproject(uv, np.full(4, near_d)),
                           self.unproject(uv, np.full(4, far_d))])


def _vec3(value, field: str) -> np.ndarray:
  v = np.asarray(value, np.float64).reshape(-1)
  if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(np.abs(v) > MAX_COORDINATE):
    raise MwbxError(f"camera: {field} must be 3 finite numbers within ±{MAX_COORDINATE:g} m, got {value!r}")
  return v.copy()
