"""`view` (live meshcat server) and `export_html` (one standalone page).

Both draw the same scene with `draw`: under the meshcat path `/mwbx`, shifted
so that the region of interest sits at the origin (meshcat's orbit controls
always orbit the origin):

  /mwbx/worlds   playback of the chosen worlds (animated, recorded rate)
  /mwbx/paths    COM paths: faint / match (green) / exclude (red)
  /mwbx/queries  query frustums q0, q1, ... with their cameras
"""

from __future__ import annotations

import os
import pathlib
from typing import Any, NamedTuple, Sequence

import meshcat
import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries.query import Query
from mwbx.viewer import flex as flex_lib
from mwbx.viewer.errors import ViewerError
from mwbx.viewer.display import DEFAULT_VISIBLE_GROUPS, DrawnVolume, as_volume, classify_worlds
from mwbx.viewer.framing import place_camera, scene_bounds, view_spec
from mwbx.viewer.frustums import draw_volume
from mwbx.viewer.geometry import pose_matrix, scene_visuals
from mwbx.viewer.hull import frustum_eye
from mwbx.viewer.paths import draw_paths
from mwbx.viewer import query_adapter
from mwbx.viewer.playback import LAYOUTS, draw_playback, grid_offsets, make_grid
from mwbx.viewer.recorder import SceneRecorder
from mwbx.viewer.server import LiveView

ROOT = "mwbx"


class DrawInfo(NamedTuple):
  """What `draw` put in the scene.

  centre: f64[3] world point shown at the display origin (metres).
  worlds: i64[n] ids of the played-back worlds.
  offsets: f64[n, 3] grid translation of each played-back world.
  path_segments: {"faint" | "match" | "exclude": number of segments drawn}.
  n_queries: number of frustums drawn.
  eye: f64[3] world position of the initial viewing camera.
  """

  centre: np.ndarray
  worlds: np.ndarray
  offsets: np.ndarray
  path_segments: dict
  n_queries: int
  eye: np.ndarray


def resolve_worlds(bank, worlds: Sequence[int] | None) -> np.ndarray:
  """i64[n] bank rows of world ids, validated; None picks the first valid world."""
  valid = np.asarray(bank.valid, bool)
  if worlds is None:
    first = np.flatnonzero(valid)[:1]
    return first.astype(np.int64)
  ids = np.asarray(list(worlds), np.int64).reshape(-1)
  if len(set(ids.tolist())) != ids.size:
    raise ViewerError(f"worlds: {ids.tolist()} lists a world more than once")
  try:
    rows = bank.row_of(ids)
  except MwbxError as err:
    raise ViewerError(f"worlds: {err}") from None
  for wid, row in zip(ids, rows):
    if not valid[row]:
      raise ViewerError(f"worlds: world {int(wid)} is flagged unstable and cannot be shown")
  return rows


# A query camera's eye marker: this fraction of the scene radius, and never
# wider than this fraction of its distance from the viewing camera (about half
# a degree), so it never fills the view; none when the view is from that eye.
EYE_MARKER_SCENE = 0.015
EYE_MARKER_ANGLE = 0.01


def eye_marker_radius(volume, view_eye: np.ndarray, scene_radius: float) -> float:
  """Radius (m) of a query camera's eye marker seen from ``view_eye``; 0: none."""
  eye = volume.eye if volume.eye is not None else frustum_eye(volume.corners)
  if eye is None:
    return 0.0
  distance = float(np.linalg.norm(np.asarray(eye, np.float64) - np.asarray(view_eye, np.float64)))
  return min(EYE_MARKER_SCENE * scene_radius, EYE_MARKER_ANGLE * distance)


def resolve_bodies(bank, paths: Any) -> np.ndarray | None:
  """Indices into the bank's B axis for `paths` (True: all tracked bodies;
  a body/object/group name or a list of them); None when no paths."""
  if paths is None or paths is False:
    return None
  if paths is True:  # every tracked body; a flex by one path, not one per vertex
    return flex_lib.path_bodies(bank)
  return np.asarray(bank.select_bodies(paths), np.int64).reshape(-1)


def draw(vis, bank, worlds: Sequence[int] | None = None, *, paths: Any = None,
         path_worlds: Sequence[int] | None = None, match: np.ndarray | None = None,
         exclude: np.ndarray | None = None, queries: Sequence[Any] | None = None,
         layout: str = "overlay", camera: str | None = None,
         view_dir: Sequence[float] | None = None, play: bool = True,
         frustum_depth: float | None = None,
         visible_groups: tuple[int, ...] = DEFAULT_VISIBLE_GROUPS) -> DrawInfo:
  """Draws a bank's worlds, paths and queries into a meshcat visualizer.

  bank: a sampled bank (mwbx.bank contract).
  worlds: ids of worlds to play back; None = the first valid world, [] = none.
  paths: COM paths to draw for every valid world (or the ids `path_worlds`): True for
    all tracked bodies, or body/object/group name(s); None = no paths.
  match, exclude: bool[W] worlds whose paths are green / red (others faint);
    when `queries` are mwbx.queries objects and both are None they come from
    evaluating the queries.
  queries: frustums to draw: DrawnVolume, (corners f[8, 3], include) pairs or
    mwbx.queries query objects.
  layout: "overlay" (ghosted, tinted) or "grid" (side by side).
  camera: MJCF camera to view exactly from; None: fit everything into view,
    looking along the model's first camera where it has one.
  view_dir: f[3] direction from the scene towards the eye for the fitted view.
  frustum_depth: longest frustum side edge drawn, metres (None: 3x scene size).
  """
  if layout not in LAYOUTS:
    raise ViewerError(f"layout must be one of {LAYOUTS}, got {layout!r}")
  model = bank.model
  worlds = resolve_worlds(bank, worlds)
  bodies = resolve_bodies(bank, paths)
  queries = as_query_list(queries)
  if queries and match is None and exclude is None:
    match, exclude = query_classes(bank, queries)
  classes = None
  if bodies is not None:
    path_rows = None if path_worlds is None else bank.row_of(np.asarray(list(path_worlds), np.int64))
    classes = classify_worlds(np.asarray(bank.valid), path_rows, match, exclude)
  # Joint queries (no volume) colour the paths but draw nothing.
  volumes = [as_volume(q, i) for i, q in enumerate(queries) if not _volumeless(q)]
  lo, hi = scene_bounds(bank, model, worlds, classes, bodies, visible_groups)
  radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.2)
  visuals = scene_visuals(model, visible_groups, plane_extent=2.0 * radius + float(np.max(np.abs(hi))))
  spec = view_spec(model, camera, view_dir)
  grid = None
  if layout == "grid":
    grid = make_grid(worlds.size, lo, hi, spec.direction)
    # Frame the whole grid, not only the first cell.
    cells = grid_offsets(max(worlds.size, 1), grid)
    lo, hi = lo + cells.min(axis=0), hi + cells.max(axis=0)
  root = vis[ROOT]
  root.delete()
  centre, eye = place_camera(vis, lo, hi, spec)
  root.set_transform(pose_matrix(-centre, np.array([1.0, 0.0, 0.0, 0.0])))
  # meshcat's grid and axes sit at the display origin, no longer the world's.
  vis["/Grid"].set_property("visible", False)
  vis["/Axes"].set_property("visible", False)

  offsets = draw_playback(root["worlds"], bank, model, visuals, list(worlds), layout, grid, play)
  counts = {"faint": 0, "match": 0, "exclude": 0}
  if classes is not None:
    counts = draw_paths(root["paths"], np.asarray(bank.com), np.asarray(bank.com_count), bodies, classes)
  depth = 3.0 * radius if frustum_depth is None else frustum_depth
  for i, volume in enumerate(volumes):
    marker = eye_marker_radius(volume, eye, radius)
    if layout == "grid" and worlds.size:  # every tile shows its world with the queries
      for k, wid in enumerate(np.asarray(bank.world_ids)[worlds]):
        tile = root["queries"][f"q{i}"][f"w{int(wid)}"]
        draw_volume(tile, volume, i, max_depth=depth, eye_radius=marker)
        tile.set_transform(pose_matrix(offsets[k], np.array([1.0, 0.0, 0.0, 0.0])))
    else:
      draw_volume(root["queries"][f"q{i}"], volume, i, max_depth=depth, eye_radius=marker)
  return DrawInfo(centre, np.asarray(bank.world_ids)[worlds], offsets, counts, len(volumes), eye)


def _volumeless(query: Any) -> bool:
  """A query with no volume to draw (a joint or orientation query)."""
  return isinstance(query, Query) and query.frustum is None


def as_query_list(queries: Any) -> list:
  """None, one query, a sequence of them, or a mwbx.queries.QuerySet -> list."""
  if queries is None:
    return []
  if isinstance(queries, DrawnVolume) or hasattr(queries, "frustum"):
    return [queries]
  if isinstance(queries, tuple) and len(queries) == 2 and isinstance(queries[1], (bool, np.bool_)):
    return [queries]  # one (corners, include) pair
  if hasattr(queries, "queries"):  # a QuerySet from mwbx.queries.load_queries
    return list(queries.queries)
  return list(queries)


def query_classes(bank, queries: Sequence[Any]) -> tuple[np.ndarray | None, np.ndarray | None]:
  """(match bool[W], exclude bool[W]) from the mwbx.queries.Query items:
  match = satisfies every query; exclude = rejected by a negative query.
  (None, None) when all are plain frustums (nothing to evaluate)."""
  if not any(query_adapter.is_query(q) for q in queries):
    return None, None
  return query_adapter.evaluate_classes(bank, queries)


def view(bank, worlds: Sequence[int] | None = None, *, paths: Any = None,
         queries: Sequence[Any] | None = None, layout: str = "overlay", open: bool = False,
         vis: meshcat.Visualizer | None = None, zmq_url: str | None = None,
         **draw_kwargs) -> meshcat.Visualizer:
  """Shows a bank in a live meshcat viewer and returns the visualizer.

  A new meshcat server is started unless `vis` or `zmq_url` (of a running
  server) is given; its page is `vis.url()`. open: also open a browser tab.
  The returned :class:`~mwbx.viewer.server.LiveView` stops a server it
  started on `close()`, at the end of a `with` block, at exit, and when this
  process dies. worlds: world ids.
  Other keyword arguments: see `draw` (path_worlds, match, exclude, camera,
  view_dir, play, frustum_depth, visible_groups).
  """
  if vis is None:
    vis = LiveView(zmq_url)
  draw(vis, bank, worlds, paths=paths, queries=queries, layout=layout, **draw_kwargs)
  if open:
    vis.open()
  return vis


def export_html(bank, path: str | os.PathLike, worlds: Sequence[int] | None = None, *,
                paths: Any = None, queries: Sequence[Any] | None = None,
                layout: str = "overlay", title: str = "mwbx", **draw_kwargs) -> pathlib.Path:
  """Writes one self-contained HTML page (meshcat viewer + scene + animation)
  showing a bank; needs no server. Same arguments as `view`/`draw`.
  Returns the path written."""
  path = pathlib.Path(path)
  if path.parent and not path.parent.exists():
    raise ViewerError(f"export_html: directory {str(path.parent)!r} does not exist")
  recorder = SceneRecorder(title=title)
  vis = meshcat.Visualizer(window=recorder)
  draw(vis, bank, worlds, paths=paths, queries=queries, layout=layout, **draw_kwargs)
  path.write_text(vis.static_html(), encoding="utf-8")
  return path
