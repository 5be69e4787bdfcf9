"""Query frustums drawn as translucent volumes with the camera they came from.

A frustum is given by its 8 world-space corners (metres), near face first,
then the far face in the same corner order, plus whether it includes (green)
or excludes (red). The solid is the convex hull of the corners, its outline
the hull edges between faces that are not coplanar, and the camera is the
point where the four side edges meet (absent for orthographic boxes).
"""

from __future__ import annotations

import meshcat.geometry as mg
import numpy as np

from mwbx.viewer.display import CAMERA_RGBA, QUERY_RGBA, DrawnVolume, as_volume, volume_shape

INCLUDE, EXCLUDE = QUERY_RGBA["include"], QUERY_RGBA["exclude"]
__all__ = ["DrawnVolume", "as_volume", "draw_volume", "INCLUDE", "EXCLUDE", "CAMERA_RGBA"]


def _segments(segments: np.ndarray) -> mg.PointsGeometry:
  """meshcat's vertex layout f32[3, 2S] of f32[S, 2, 3] segments."""
  return mg.PointsGeometry(np.ascontiguousarray(np.asarray(segments, np.float32).reshape(-1, 3).T))


def draw_volume(vis, volume: DrawnVolume, index: int = 0,
                max_depth: float | None = None, eye_radius: float = 0.02) -> None:
  """Draws one frustum (:func:`mwbx.viewer.display.volume_shape`) under `vis`:
  "volume" (translucent), "outline", and, where a camera position is known,
  "camera" (eye sphere of `eye_radius` metres, none when 0, + rays to the
  near corners)."""
  shape = volume_shape(volume, index, max_depth)
  vis["volume"].set_object(
      mg.TriangularMeshGeometry(shape.vertices, shape.faces),
      mg.MeshBasicMaterial(color=shape.rgba.hex(), opacity=float(shape.rgba.a), transparent=True,
                           depthWrite=False))
  vis["outline"].set_object(mg.LineSegments(_segments(shape.edges), mg.LineBasicMaterial(color=shape.rgba.hex())))
  if shape.eye is None:
    vis["camera"].delete()
    return
  if shape.rays.size:
    vis["camera/rays"].set_object(mg.LineSegments(_segments(shape.rays),
                                                  mg.LineBasicMaterial(color=CAMERA_RGBA.hex())))
  if eye_radius <= 0:
    vis["camera/eye"].delete()
    return
  vis["camera/eye"].set_object(mg.Sphere(float(eye_radius)),
                               mg.MeshBasicMaterial(color=CAMERA_RGBA.hex()))
  vis["camera/eye"].set_transform(_translation(shape.eye))


def _translation(p: np.ndarray) -> np.ndarray:
  out = np.eye(4)
  out[:3, 3] = np.asarray(p, np.float64)
  return out
