"""Centre-of-mass paths of many worlds as meshcat line segments (paper Fig. 5).

Every polyline of every chosen world and body goes into one vertex buffer per
colour class, so thousands of paths are three draw calls: all paths faint,
matching worlds green, excluded worlds red.
"""

from __future__ import annotations

from typing import NamedTuple

import meshcat.geometry as mg
import numpy as np

from mwbx.viewer.errors import ViewerError
from mwbx.viewer.geometry import Rgba

# Colour classes, drawn in this order (later ones on top).
FAINT = Rgba(0.55, 0.55, 0.6, 0.35)
MATCH = Rgba(0.0, 0.9, 0.1, 1.0)
EXCLUDE = Rgba(0.95, 0.05, 0.05, 1.0)

# Cap on the number of faint polylines (world x body) drawn; beyond it an
# evenly spaced subset is shown. Matching and excluded paths are always drawn.
MAX_FAINT_POLYLINES = 20_000


class PathClasses(NamedTuple):
  """Which worlds' paths are drawn and how.

  faint: i64[n] world indices drawn faint (neither matching nor excluded).
  match: i64[m] world indices drawn green.
  exclude: i64[e] world indices drawn red.
  """

  faint: np.ndarray
  match: np.ndarray
  exclude: np.ndarray


def polyline_segments(com: np.ndarray, count: np.ndarray) -> np.ndarray:
  """Line-segment vertex pairs of COM polylines, zero-length tails dropped.

  com: f[N, P, K, 3] points (metres) of N worlds and K bodies, point p at time
    p / query_fps; points at index >= count[n] repeat the last valid point.
  count: i[N] valid points per world.
  Returns f32[3, 2 * S]: columns (2s, 2s + 1) are the ends of segment s, the
  layout `meshcat.geometry.PointsGeometry` takes for `LineSegments`.
  """
  com = np.asarray(com, np.float32)
  count = np.asarray(count)
  if com.ndim != 4 or com.shape[-1] != 3 or count.shape != com.shape[:1]:
    raise ViewerError(f"com must be f32[N, P, K, 3] with count i32[N]; got {com.shape} "
                      f"and {count.shape}")
  n_points = com.shape[1]
  starts = com[:, :-1]  # [N, P-1, K, 3]
  ends = com[:, 1:]
  # Segment p joins points p and p + 1; it exists while p + 1 < count.
  keep = np.arange(n_points - 1)[None, :] < (count[:, None] - 1)  # [N, P-1]
  keep = np.broadcast_to(keep[:, :, None], starts.shape[:3])
  keep = keep & np.all(np.isfinite(starts) & np.isfinite(ends), axis=-1)
  pairs = np.stack([starts[keep], ends[keep]], axis=1)  # [S, 2, 3]
  return np.ascontiguousarray(pairs.reshape(-1, 3).T)


def classify_worlds(valid: np.ndarray, worlds: np.ndarray | None,
                    match: np.ndarray | None, exclude: np.ndarray | None) -> PathClasses:
  """Split the worlds whose paths are drawn into faint / match / exclude.

  valid: bool[W]; invalid (unstable) worlds are never drawn.
  worlds: i[n] indices to draw, or None for every valid world.
  match, exclude: bool[W] or None; a world in both is drawn as excluded.
  """
  n_worlds = valid.shape[0]
  chosen = np.zeros(n_worlds, bool)
  if worlds is None:
    chosen[:] = True
  else:
    worlds = np.asarray(worlds, np.int64).reshape(-1)
    bad = worlds[(worlds < 0) | (worlds >= n_worlds)]
    if bad.size:
      raise ViewerError(f"path world index {int(bad[0])} out of range for a bank of {n_worlds} worlds")
    chosen[worlds] = True
  chosen &= np.asarray(valid, bool)
  is_match = np.zeros(n_worlds, bool) if match is None else _mask(match, n_worlds, "match")
  is_excl = np.zeros(n_worlds, bool) if exclude is None else _mask(exclude, n_worlds, "exclude")
  excl = chosen & is_excl
  good = chosen & is_match & ~is_excl
  faint = chosen & ~good & ~excl
  return PathClasses(np.flatnonzero(faint), np.flatnonzero(good), np.flatnonzero(excl))


def _mask(mask, n_worlds: int, name: str) -> np.ndarray:
  mask = np.asarray(mask)
  if mask.shape != (n_worlds,):
    raise ViewerError(f"{name} must be bool[{n_worlds}] (one entry per world), got shape {mask.shape}")
  return mask.astype(bool)


def thin_out(worlds: np.ndarray, n_bodies: int, cap: int) -> np.ndarray:
  """At most cap // n_bodies worlds, evenly spaced, so at most `cap` polylines."""
  keep = max(cap // max(n_bodies, 1), 1)
  if worlds.size <= keep:
    return worlds
  return worlds[np.linspace(0, worlds.size - 1, keep).round().astype(np.int64)]


def line_object(segments: np.ndarray, rgba: Rgba) -> mg.LineSegments:
  """A meshcat LineSegments object for f32[3, 2S] vertex pairs in one colour."""
  translucent = rgba.a < 1.0
  return mg.LineSegments(
      mg.PointsGeometry(np.asarray(segments, np.float32)),
      mg.LineBasicMaterial(color=rgba.hex(), opacity=float(rgba.a), transparent=translucent,
                           depthWrite=not translucent),
  )


def draw_paths(vis, com: np.ndarray, count: np.ndarray, bodies: np.ndarray,
               classes: PathClasses, max_faint: int = MAX_FAINT_POLYLINES) -> dict[str, int]:
  """Draws the COM paths of `bodies` for each class under `vis` ("faint",
  "match", "exclude" children). Returns the number of segments per class.

  com: f32[W, P, B, 3], count: i32[W], bodies: i[K] indices into B.
  """
  counts = {}
  for name, worlds, rgba in (("faint", thin_out(classes.faint, bodies.size, max_faint), FAINT),
                             ("match", classes.match, MATCH),
                             ("exclude", classes.exclude, EXCLUDE)):
    node = vis[name]
    if worlds.size == 0 or bodies.size == 0:
      node.delete()
      counts[name] = 0
      continue
    segments = polyline_segments(com[worlds][:, :, bodies], count[worlds])
    counts[name] = segments.shape[1] // 2
    if counts[name] == 0:
      node.delete()
      continue
    node.set_object(line_object(segments, rgba))
  return counts
