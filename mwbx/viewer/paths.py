"""Centre-of-mass paths of many worlds as meshcat line segments (paper Fig. 5).

The paths of every chosen world and body go into one vertex buffer per class
(:func:`mwbx.viewer.display.path_layers`), so thousands of paths are three
draw calls: all paths faint, matching worlds green, excluded worlds red, in
the colours of :data:`mwbx.viewer.display.PATH_RGBA` (the page's too).
"""

from __future__ import annotations

import meshcat.geometry as mg
import numpy as np

from mwbx.viewer.display import PathClasses, Rgba, path_layers

# Segments of faint paths drawn at most (an evenly spaced subset of the
# worlds beyond it); matching and excluded paths are always drawn.
MAX_FAINT_SEGMENTS = 1_000_000
BUDGET = {"faint": MAX_FAINT_SEGMENTS, "match": None, "exclude": None}


def line_object(segments: np.ndarray, rgba: Rgba) -> mg.LineSegments:
  """A meshcat LineSegments object for f32[S, 2, 3] segments in one colour."""
  translucent = rgba.a < 1.0
  vertices = np.ascontiguousarray(np.asarray(segments, np.float32).reshape(-1, 3).T)  # meshcat: [3, 2S]
  return mg.LineSegments(
      mg.PointsGeometry(vertices),
      mg.LineBasicMaterial(color=rgba.hex(), opacity=float(rgba.a), transparent=translucent,
                           depthWrite=not translucent),
  )


def draw_paths(vis, com: np.ndarray, count: np.ndarray, bodies: np.ndarray,
               classes: PathClasses, budget: dict = BUDGET) -> dict[str, int]:
  """Draws the COM paths of `bodies` for each class under `vis` ("faint",
  "match", "exclude" children). Returns the number of segments per class.

  com: f32[W, P, B, 3], count: i32[W], bodies: i[K] indices into B.
  """
  counts = {}
  for layer in path_layers(com, count, bodies, classes, budget):
    counts[layer.name] = int(layer.segments.shape[0])
    if counts[layer.name] == 0:
      vis[layer.name].delete()
    else:
      vis[layer.name].set_object(line_object(layer.segments, layer.rgba))
  return counts
