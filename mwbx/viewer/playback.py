"""Animated playback of chosen worlds: one meshcat node per moving body, its
pose per recorded frame as an animation track at the recording rate.

Layouts: "overlay" puts every world in the same place, the first opaque in its
MJCF colours and the others as translucent ghosts in the same colours; "grid" lays worlds
out side by side, each with its own copy of the static scene.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import meshcat.animation as manim
import meshcat.geometry as mg
import mujoco
import numpy as np

from mwbx.viewer import flex as flex_lib
from mwbx.viewer.display import Rgba
from mwbx.viewer.errors import ViewerError
from mwbx.viewer.geometry import (PLANE_THICKNESS, GeomVisual, body_node_name, material, moving_body_ids,
                                  pose_matrix)
from mwbx.viewer.kinematics import body_trajectories, pad_frames

LAYOUTS = ("overlay", "grid")
# Ghost worlds in overlay layout keep their MJCF colours (a red crate stays
# red: colour means body, not world) and are told apart by translucency.
GHOST_OPACITY = 0.45


class WorldStyle(NamedTuple):
  """How one world is drawn: opacity (1: opaque, MJCF colours either way)."""

  opacity: float


class WorldTracks(NamedTuple):
  """Recorded body poses of one world, padded to a common length.

  world: index into the bank's world axis.
  body_ids: i32[K] MuJoCo ids of the moving bodies drawn.
  pos: f64[T, K, 3] metres; quat: f64[T, K, 4] wxyz.
  """

  world: int
  body_ids: np.ndarray
  pos: np.ndarray
  quat: np.ndarray


def world_styles(n_worlds: int, layout: str) -> list[WorldStyle]:
  """Style per displayed world for a layout."""
  if layout not in LAYOUTS:
    raise ViewerError(f"layout must be one of {LAYOUTS}, got {layout!r}")
  if layout == "grid" or n_worlds == 1:
    return [WorldStyle(1.0)] * n_worlds
  return [WorldStyle(1.0)] + [WorldStyle(GHOST_OPACITY)] * (n_worlds - 1)


class Grid(NamedTuple):
  """Side-by-side layout of worlds.

  Cells run along `col_axis` (f64[3] unit, the view's right), rows along
  `row_axis` (towards the viewer for floor-like scenes, downwards for tall
  ones), `col_step`/`row_step` metres apart; `n_cols` cells per row.
  centre: f64[3] world point at the middle of a cell (its floor tile is
  centred under it). tile_axes: f64[3, 3] columns (right, away, up) of the
  floor tiles; tile: f64[2] tile size along right and away, metres.
  """

  col_axis: np.ndarray
  col_step: float
  row_axis: np.ndarray
  row_step: float
  n_cols: int
  centre: np.ndarray
  tile_axes: np.ndarray
  tile: np.ndarray


# Cells are this much larger than what moves in them.
GRID_SPACING = 1.25


def make_grid(n_worlds: int, lo: np.ndarray, hi: np.ndarray, direction: np.ndarray) -> Grid:
  """A grid of n_worlds cells around the box [lo, hi] (what one world shows),
  seen along `direction` (f64[3] unit, from the scene towards the eye)."""
  forward = -np.asarray(direction, np.float64)
  right = np.cross(forward, [0.0, 0.0, 1.0])
  if np.linalg.norm(right) < 1e-6:  # looking straight down or up
    right = np.array([1.0, 0.0, 0.0])
  right /= np.linalg.norm(right)
  away = np.cross([0.0, 0.0, 1.0], right)  # horizontal, away from the viewer
  corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
  extent = lambda axis: max(float(np.ptp(corners @ axis)), 0.2)  # noqa: E731
  up = np.array([0.0, 0.0, 1.0])
  if extent(up) > extent(away):
    row_axis, row_step = -up, GRID_SPACING * extent(up)  # tall scenes: rows stack downwards
  else:
    row_axis, row_step = -away, GRID_SPACING * extent(away)  # floors: rows come towards the viewer
  col_step = GRID_SPACING * extent(right)
  tile = 0.97 * GRID_SPACING * np.array([extent(right), extent(away)])
  return Grid(right, col_step, row_axis, row_step, int(np.ceil(np.sqrt(max(n_worlds, 1)))),
              (np.asarray(lo) + np.asarray(hi)) / 2, np.stack([right, away, up], axis=1), tile)


def grid_offsets(n_worlds: int, grid: Grid) -> np.ndarray:
  """f64[n, 3] translations of the grid cells, row-major."""
  k = np.arange(n_worlds)
  return ((k % grid.n_cols)[:, None] * grid.col_step * grid.col_axis[None]
          + (k // grid.n_cols)[:, None] * grid.row_step * grid.row_axis[None])


# Grid labels: height of the text as a fraction of a cell's width, and the
# image it is drawn into (pixels).
LABEL_HEIGHT = 0.08
LABEL_PIXELS = (256, 48)


def label_png(text: str) -> bytes:
  """PNG bytes of ``text`` in dark grey on white (Pillow's default font)."""
  import io
  from PIL import Image, ImageDraw, ImageFont
  width, height = LABEL_PIXELS
  image = Image.new("RGB", (width, height), (255, 255, 255))
  font = ImageFont.load_default(size=int(height * 0.7))
  ImageDraw.Draw(image).text((width / 2, height / 2), text, fill=(40, 40, 40), font=font, anchor="mm")
  out = io.BytesIO()
  image.save(out, format="PNG")
  return out.getvalue()


def draw_label(vis, text: str, grid: Grid) -> None:
  """A world's label in grid layout: a flat card at the far edge of its floor
  tile, facing the viewer, moving with the cell."""
  right, away, up = grid.tile_axes.T
  height = LABEL_HEIGHT * grid.col_step
  width = height * LABEL_PIXELS[0] / LABEL_PIXELS[1]
  card = mg.Box([width, height, 1e-3 * width])
  texture = mg.ImageTexture(image=mg.PngImage(label_png(text)))
  vis.set_object(card, mg.MeshBasicMaterial(map=texture))
  pose = np.eye(4)
  pose[:3, :3] = np.stack([right, up, -away], axis=1)  # card x right, y up, facing the viewer
  pose[:3, 3] = grid.centre + 0.5 * grid.tile[1] * away + (0.5 * height) * up
  vis.set_transform(pose)


def tile_planes(visuals: Sequence[GeomVisual], grid: Grid) -> list[GeomVisual]:
  """Grid layout: horizontal static planes become one floor tile per cell,
  a bit smaller than the cell so neighbouring worlds are visibly apart and
  their floors never overlap."""
  out = []
  for v in visuals:
    normal = v.local[:3, 2]
    is_plane = isinstance(v.geometry, mg.Box) and v.geometry.lengths[2] == PLANE_THICKNESS
    if v.static and is_plane and abs(abs(normal[2]) - 1.0) < 1e-9:
      local = np.eye(4)
      local[:3, :3] = grid.tile_axes
      local[:3, 3] = [grid.centre[0], grid.centre[1], v.local[2, 3]]
      v = v._replace(geometry=mg.Box([float(grid.tile[0]), float(grid.tile[1]), PLANE_THICKNESS]),
                     local=local)
    out.append(v)
  return out


def world_tracks(bank, model: mujoco.MjModel, worlds: Sequence[int],
                 body_ids: np.ndarray) -> list[WorldTracks]:
  """Decodes each world's qpos and runs forward kinematics; all tracks are
  padded to the longest recording (shorter worlds hold their last pose)."""
  decoded = []
  for w in worlds:  # bank rows
    wid = int(bank.world_ids[int(w)])
    qpos = np.asarray(bank.qpos_frames(wid), np.float64)
    if qpos.shape[0] == 0:
      raise ViewerError(f"world {wid} has no recorded frames (frame_count is 0)")
    if not np.all(np.isfinite(qpos)):
      raise ViewerError(f"world {wid} has non-finite recorded coordinates; it cannot be played back")
    decoded.append((int(w), qpos))
  n_frames = max(q.shape[0] for _, q in decoded)
  tracks = []
  for w, qpos in decoded:
    pos, quat = body_trajectories(model, qpos, body_ids)
    tracks.append(WorldTracks(w, body_ids, pad_frames(pos, n_frames), pad_frames(quat, n_frames)))
  return tracks


def draw_static(vis, visuals: Sequence[GeomVisual], style: WorldStyle = WorldStyle(1.0)) -> None:
  """Static geoms at their world poses under `vis`, once."""
  for v in visuals:
    if not v.static:
      continue
    node = vis[v.name]
    node.set_object(v.geometry, material(v.rgba, v.shininess,
                                         opacity=None if style.opacity >= 1.0 else style.opacity))
    node.set_transform(v.local)


def draw_bodies(vis, model: mujoco.MjModel, visuals: Sequence[GeomVisual],
                style: WorldStyle) -> dict[int, object]:
  """Moving bodies under `vis`: one node per body with its geoms as children
  at their body-frame poses. Returns {body id: body node visualizer}."""
  nodes = {}
  for v in visuals:
    if v.static:
      continue
    if v.body_id not in nodes:
      nodes[v.body_id] = vis[body_node_name(model, v.body_id)]
    geom = nodes[v.body_id][v.name]
    geom.set_object(v.geometry, material(v.rgba, v.shininess,
                                         opacity=None if style.opacity >= 1.0 else style.opacity))
    geom.set_transform(v.local)
  return nodes


def add_clip(animation: manim.Animation, node, pos: np.ndarray, quat: np.ndarray, fps: float) -> None:
  """Adds one body's position/orientation tracks to `animation`.

  pos: f64[T, 3] metres, quat: f64[T, 4] wxyz; frame t plays at t / fps s.
  Tracks are filled directly (meshcat wants xyzw quaternions and Python
  floats), which is much faster than per-frame `at_frame(...).set_transform`.
  """
  frames = list(range(pos.shape[0]))
  xyzw = np.asarray(quat, np.float64)[:, [1, 2, 3, 0]]
  animation.clips[node.path] = manim.AnimationClip(
      tracks={
          "position": manim.AnimationTrack("position", "vector3", frames,
                                           np.asarray(pos, np.float64).tolist()),
          "quaternion": manim.AnimationTrack("quaternion", "quaternion", frames, xyzw.tolist()),
      },
      fps=float(fps),
  )


# A flex's surface in meshcat is one mesh per shown frame (meshcat animates
# poses, not vertices), each scaled up only while its frame plays: this many a second.
FLEX_FPS = 30.0
# The scale of a flex frame's mesh before its frame plays (invisibly small).
HIDDEN_SCALE = 1e-6


def draw_flex(vis, animation: manim.Animation, surface, pos: np.ndarray, quat: np.ndarray, fps: float,
              style: WorldStyle) -> None:
  """A flex's surface under ``vis``: a mesh per shown frame (:data:`FLEX_FPS`),
  each with a scale track that shows it for its frames only.

  Args:
    surface: the :class:`mwbx.viewer.flex.FlexSurface`.
    pos, quat: f64[T, V, 3] / f64[T, V, 4] its vertex bodies' poses at every recorded frame.
    fps: the recording rate.
  """
  n_frames = pos.shape[0]
  step = max(1, int(round(fps / FLEX_FPS)))
  colour = Rgba(*(float(c) for c in surface.rgba))
  for f in range(0, n_frames, step):
    node = vis[f"f{f}"]
    node.set_object(mg.TriangularMeshGeometry(surface.vertices(pos[f], quat[f]), surface.faces),
                    material(colour, opacity=None if style.opacity >= 1.0 else style.opacity))
    shown, hidden = [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]
    end = min(f + step, n_frames)
    keys = sorted({max(f - 1, 0), f, end - 1, min(end, n_frames - 1)})
    values = [shown if f <= k < end else hidden for k in keys]
    if end >= n_frames:  # the last mesh stays once the world is at rest
      values[-1] = shown
    animation.clips[node.path] = manim.AnimationClip(
        tracks={"scale": manim.AnimationTrack("scale", "vector3", keys, values)}, fps=float(fps))
    # Hidden until its frame by a tiny scale, not a zero one: meshcat
    # decomposes the matrix, and a zero scale leaves a NaN rotation that keeps
    # the mesh invisible once its scale track shows it.
    hide = HIDDEN_SCALE
    node.set_transform(np.diag([1.0, 1.0, 1.0, 1.0]) if f == 0 else np.diag([hide, hide, hide, 1.0]))


def draw_playback(vis, bank, model: mujoco.MjModel, visuals: Sequence[GeomVisual],
                  worlds: Sequence[int], layout: str, grid: Grid | None = None,
                  play: bool = True) -> np.ndarray:
  """Draws `worlds` of `bank` under `vis` and sets the animation.

  Nodes: `static` (overlay: once), `w{world_id}/static` (grid), and
  `w{world_id}/{body}/{geom}`. grid: the cell layout (grid layout only).
  Returns f64[n, 3] the translation of each world's node (zeros for overlay).
  """
  styles = world_styles(len(worlds), layout)
  body_ids = moving_body_ids(list(visuals))
  offsets = np.zeros((len(worlds), 3))
  if layout == "grid":
    if grid is None:
      raise ViewerError("grid layout needs a Grid (see make_grid)")
    offsets = grid_offsets(len(worlds), grid)
    visuals = tile_planes(visuals, grid)
  else:
    draw_static(vis["static"], visuals)
  if not worlds:
    return offsets
  surfaces = flex_lib.flex_surfaces(model)
  flex_ids = [s.bodies for s in surfaces]
  tracks = world_tracks(bank, model, worlds, np.concatenate([body_ids] + flex_ids).astype(np.int64))
  animation = manim.Animation(default_framerate=float(bank.record_fps))
  world_ids = np.asarray(bank.world_ids)
  for k, (track, style) in enumerate(zip(tracks, styles)):
    node = vis[f"w{int(world_ids[track.world])}"]  # node names carry the world id
    shift = np.eye(4)
    shift[:3, 3] = offsets[k]
    node.set_transform(shift)
    if layout == "grid":
      draw_static(node["static"], visuals)
      draw_label(node["label"], f"world {int(world_ids[track.world])}", grid)
    nodes = draw_bodies(node, model, visuals, style)
    for j, body in enumerate(body_ids):
      body_node = nodes[int(body)]
      body_node.set_transform(pose_matrix(track.pos[0, j], track.quat[0, j]))
      add_clip(animation, body_node, track.pos[:, j], track.quat[:, j], bank.record_fps)
    at = len(body_ids)
    for surface in surfaces:
      n = len(surface.bodies)
      draw_flex(node["flex"][surface.name], animation, surface, track.pos[:, at:at + n], track.quat[:, at:at + n],
                bank.record_fps, style)
      at += n
  if animation.clips:
    vis.set_animation(animation, play=play, repetitions=float("inf") if play else 1)
  return offsets

