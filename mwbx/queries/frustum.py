"""World-space query volumes: convex intersections of half-spaces.

A Frustum is F closed half-spaces `n·p - off <= 0` (points with distance
<= 0 are inside; a point on a plane is inside). Normals are stored as float32
unit vectors and offsets as float64 metres: every product of a float32
normal with a float32 position is then exact in float64, which makes the
tests in `segments.py` reproducible bit for bit (see there).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mwbx.errors import MwbxError


@dataclasses.dataclass(frozen=True, eq=False)
class Frustum:
  """A convex query volume.

  normals: f32[F, 3] unit outward normals, 1 <= F <= 6.
  offsets: f64[F] plane offsets, metres (`n·p - off <= 0` inside).
  corners: f64[8, 3] corners for display (near face, then the far face with
    far corner i on the ray through near corner i), metres, or None.
  eye: f64[3] camera position for display, or None (orthographic, box).
  """

  normals: np.ndarray
  offsets: np.ndarray
  corners: np.ndarray | None = None
  eye: np.ndarray | None = None

  def __post_init__(self):
    normals = np.asarray(self.normals, np.float32)
    offsets = np.asarray(self.offsets, np.float64)
    if normals.ndim != 2 or normals.shape[1] != 3 or not 1 <= len(normals) <= 6:
      raise MwbxError(f"frustum: normals must be f32[F, 3] with 1 <= F <= 6, got shape {normals.shape}")
    if offsets.shape != (len(normals),):
      raise MwbxError(f"frustum: offsets must have shape ({len(normals)},), got {offsets.shape}")
    if not (np.all(np.isfinite(normals)) and np.all(np.isfinite(offsets))):
      raise MwbxError("frustum: plane normals and offsets must be finite")
    if np.any(np.linalg.norm(normals, axis=1) == 0):
      raise MwbxError("frustum: a plane normal is zero")
    normals.flags.writeable = False
    offsets.flags.writeable = False
    object.__setattr__(self, "normals", normals)
    object.__setattr__(self, "offsets", offsets)

  def __repr__(self) -> str:
    eye = "" if self.eye is None else f", eye={np.round(np.asarray(self.eye, float), 3).tolist()}"
    return f"Frustum({self.n_planes} planes{eye})"

  @property
  def n_planes(self) -> int:
    return len(self.normals)

  @classmethod
  def from_planes(cls, normals, offsets, corners=None, eye=None) -> Frustum:
    """Half-spaces `n·p <= off` from any nonzero normals (normalised here).

    Args:
      normals: f[F, 3] outward normals.
      offsets: f[F] offsets in the units of the given normals.
    """
    n = np.asarray(normals, np.float64)
    off = np.asarray(offsets, np.float64)
    if n.ndim != 2 or n.shape[1:] != (3,) or off.shape != n.shape[:1]:
      raise MwbxError(f"frustum: normals f[F, 3] and offsets f[F] expected, got {n.shape} and {off.shape}")
    length = np.linalg.norm(n, axis=1)
    if np.any(~np.isfinite(length)) or np.any(length == 0):
      raise MwbxError("frustum: plane normals must be finite and nonzero")
    return plane_frustum(n / length[:, None], off / length, corners, eye)

  @classmethod
  def box(cls, lo, hi) -> Frustum:
    """An axis-aligned world box [lo, hi] (metres), e.g. a bin of the scene."""
    lo = np.asarray(lo, np.float64).reshape(-1)
    hi = np.asarray(hi, np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,):
      raise MwbxError(f"box: min and max must be 3 numbers each, got {lo.tolist()} and {hi.tolist()}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
      raise MwbxError(f"box: corners must be finite, got min {lo.tolist()} max {hi.tolist()}")
    if np.any(lo > hi):
      raise MwbxError(f"box: empty, min {lo.tolist()} exceeds max {hi.tolist()}")
    eye3 = np.eye(3)
    normals = np.concatenate([eye3, -eye3])
    offsets = np.concatenate([hi, -lo])
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    corners = np.array([
        [x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
        [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1],
    ])
    return cls(normals.astype(np.float32), offsets, corners, None)

  def distances(self, points, radius: float = 0.0) -> np.ndarray:
    """Signed distances to the planes, positive outside, with the same
    float64 arithmetic as the query kernels.

    Args:
      points: f32[..., 3] positions (cast to float32 first), metres.
      radius: sphere radius pushing every plane outward, metres.

    Returns:
      f64[..., F].
    """
    p = np.asarray(points, np.float32).astype(np.float64)[..., None, :]
    n = self.normals.astype(np.float64)
    off = self.offsets + np.float64(radius)
    return ((p[..., 0] * n[:, 0] + p[..., 1] * n[:, 1]) + p[..., 2] * n[:, 2]) - off

  def contains(self, points, radius: float = 0.0) -> np.ndarray:
    """Whether points lie in the closed volume: bool[...]."""
    return np.all(self.distances(points, radius) <= 0, axis=-1)


def plane_frustum(normals, offsets, corners=None, eye=None) -> Frustum:
  """Frustum from unit normals f64[F, 3] through points with offsets f64[F].

  The normals are rounded to float32 and the offsets are kept for the planes
  as given (no re-normalisation after rounding: the error is ~1e-7 relative).
  """
  normals32 = np.asarray(normals, np.float64).astype(np.float32)
  return Frustum(normals32, np.asarray(offsets, np.float64), corners, eye)
