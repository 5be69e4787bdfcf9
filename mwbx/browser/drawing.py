"""The page's paths and query volumes: :mod:`mwbx.viewer.display` as viser line segments.

Paths: the selected bodies' COM polylines of every valid world in the three
classes and colours of :data:`mwbx.viewer.display.PATH_RGBA` (the meshcat
viewer's too), each thinned to MAX_PATH_SEGMENTS. A class a pixel wide (the
faint one, most of the paths) goes to the page as native WebGL lines
(:mod:`mwbx.browser.glb`), the others as viser's wider lines. Volumes: the
outline of every enabled box query, its far face cut to the scene's size,
and the rays from the camera it was drawn through.
"""

from __future__ import annotations

import numpy as np

from mwbx.browser import glb
from mwbx.viewer import display

# Each class of paths (faint, matching, excluded) draws at most this many
# segments: an evenly spaced subset of its worlds beyond it, with a count shown.
# Software WebGL redraws them every frame, and a click waits for a frame: on
# 100,000 quickstart worlds a sorter click played in ~125 ms median in
# headless Chromium at 20,000 (17 frames/s idle) against ~210 ms at 60,000 (11).
MAX_PATH_SEGMENTS = 20_000
BUDGET = {name: MAX_PATH_SEGMENTS for name in display.PATH_CLASSES}
THICKNESS = {"faint": 1.0, "match": 2.0, "exclude": 2.0}
# Classes this thin are drawn as native lines (one draw call, always a pixel
# wide): viser's lines are one instanced quad a segment, which software WebGL
# pays per segment every frame (20-body play bench: 6.9 frames/s playing with
# them, 11.2 with the faint class as native lines, 12.8 with no paths).
NATIVE_THICKNESS = 1.0
# Paths are drawn within this fraction of the scene's diagonal of every
# recorded point (display.simplify_polylines): well under a pixel at the
# first view, and a body flying straight or lying still costs a segment, not
# one per frame. Software WebGL redraws every segment whenever a played world
# moves (20 bodies, 8 worlds: 6 frames/s with every segment, 16 without paths).
PATH_TOLERANCE = 1e-3


def most_moving(bank, bodies: np.ndarray, budget: int = MAX_PATH_SEGMENTS) -> np.ndarray:
  """i64[k] of ``bodies``: as many as fit ``budget`` segments in every
  valid world (each path counted at its stored points), those that travel
  furthest on average first, so a scene of many bodies (a tower of blocks)
  opens on the paths of what moves (the rock) in every world rather than on
  every body of a few worlds."""
  bodies = np.asarray(bodies, np.int64)
  valid = np.flatnonzero(np.asarray(bank.valid, bool))
  if not valid.size or "path_length" not in bank.metric_names:
    return bodies
  per_path = max(1.0, float(np.asarray(bank.com_count)[valid].mean()) - 1.0)
  fit = int(budget // (len(valid) * per_path))
  if fit >= len(bodies):
    return bodies
  # One metric of the valid worlds (not every metric of them copied): this runs at every redraw.
  metric = list(bank.metric_names).index("path_length")
  length = np.asarray(bank.metrics)[valid, :, metric][:, bodies].mean(axis=0)
  return np.sort(bodies[np.argsort(-length, kind="stable")[:max(1, fit)]])


def path_rgb(rgba: display.Rgba) -> tuple[int, int, int]:
  """The opaque colour the page draws a path class in: viser's lines have no
  opacity, so a translucent class is blended over the page's white background."""
  return rgba.over((1.0, 1.0, 1.0))


def draw_paths(server, handles: dict, bank, bodies: np.ndarray, match: np.ndarray,
               exclude: np.ndarray, only_matches: bool = False,
               simplify: display.PathSimplifier | None = None) -> dict:
  """Draws the paths of tracked bodies ``bodies`` (i64[k]) for the worlds in
  ``match`` / ``exclude`` (bool[W]) and the other valid ones (faint, unless
  ``only_matches``), joining the points ``simplify`` keeps (None: every
  one); ``handles`` keeps what was drawn (replaced next time).
  Returns {class: worlds left out by the segment budget}."""
  valid = np.asarray(bank.valid, bool)
  classes = display.classify_worlds(valid, None, match, exclude)
  if only_matches:
    empty = np.zeros(0, np.int64)
    classes = classes._replace(faint=empty, exclude=empty)
  left_out = {}
  for layer in display.path_layers(bank.com, np.asarray(bank.com_count), bodies, classes, BUDGET, simplify):
    left_out[layer.name] = layer.left_out
    key = f"paths/{layer.name}"
    old = handles.pop(key, None)
    data = None
    if THICKNESS[layer.name] <= NATIVE_THICKNESS and layer.segments.shape[0]:
      data = glb.line_segments(layer.segments, path_rgb(layer.rgba))
    # The page frees a replaced GLB's meshes but not its lines: an unchanged class is kept.
    if data is not None and old is not None and getattr(old, "glb_data", None) == data:
      handles[key] = old
      continue
    if old is not None:  # before adding: a node's removal goes by its name
      old.remove()
    if data is not None:
      handles[key] = server.scene.add_glb(f"/{key}", data, cast_shadow=False, receive_shadow=False)
    elif layer.segments.shape[0]:
      handles[key] = server.scene.add_line_segments(
          f"/{key}", layer.segments, path_rgb(layer.rgba),
          thickness=THICKNESS[layer.name], thickness_units="screen")
  return left_out


def segments_drawn(handle) -> int:
  """Segments a path handle of :func:`draw_paths` draws (native lines or viser's)."""
  data = getattr(handle, "glb_data", None)
  return glb.segment_count(data) if data is not None else int(handle.points.shape[0])


def draw_frustums(server, handles: dict, entries, max_depth: float | None = None) -> None:
  """Draws the outline of every enabled query that has a frustum (green
  include, red exclude, :data:`mwbx.viewer.display.QUERY_RGBA`) with the
  rays from its camera; orientation and joint queries draw nothing."""
  for key in [k for k in handles if k.startswith("queries/")]:
    handles.pop(key).remove()
  for i, entry in enumerate(entries):
    q = entry.query
    if q.frustum is None or getattr(q.frustum, "corners", None) is None or not entry.enabled:
      continue
    shape = display.volume_shape(display.as_volume(q, i), i, max_depth)
    handles[f"queries/q{i}"] = server.scene.add_line_segments(
        f"/queries/q{i}", shape.edges, shape.rgba.u8(), thickness=2.0, thickness_units="screen")
    if shape.rays.size:
      handles[f"queries/q{i}-rays"] = server.scene.add_line_segments(
          f"/queries/q{i}-rays", shape.rays, display.CAMERA_RGBA.u8(), thickness=1.0, thickness_units="screen")
