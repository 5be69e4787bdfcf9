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
import mujoco
import numpy as np

from mwbx.viewer.errors import ViewerError
from mwbx.viewer.frustums import QueryVolume, as_volume, draw_volume
from mwbx.viewer.geometry import DEFAULT_VISIBLE_GROUPS, pose_matrix, scene_visuals
from mwbx.viewer.paths import PathClasses, classify_worlds, draw_paths
from mwbx.viewer.playback import LAYOUTS, draw_playback, grid_offsets, make_grid
from mwbx.viewer.recorder import SceneRecorder

ROOT = "mwbx"
# Field of view (degrees) used when the model has no MJCF camera to copy.
DEFAULT_FOVY = 50.0
# Viewing direction (from the scene towards the eye) without an MJCF camera.
DEFAULT_VIEW_DIR = np.array([1.0, -1.4, 0.9])


class DrawInfo(NamedTuple):
  """What `draw` put in the scene.

  centre: f64[3] world point shown at the display origin (metres).
  worlds: i64[n] bank indices of the played-back worlds.
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
  """i64[n] validated world indices; None picks the first valid world."""
  valid = np.asarray(bank.valid, bool)
  if worlds is None:
    first = np.flatnonzero(valid)[:1]
    return first.astype(np.int64)
  out = np.asarray(list(worlds), np.int64).reshape(-1)
  for w in out:
    if not 0 <= w < bank.n_worlds:
      raise ViewerError(f"worlds: index {int(w)} is out of range for a bank of {bank.n_worlds} worlds")
    if not valid[w]:
      raise ViewerError(f"worlds: world {int(w)} is flagged unstable and cannot be shown")
  if len(set(out.tolist())) != out.size:
    raise ViewerError(f"worlds: {out.tolist()} lists a world more than once")
  return out


def resolve_bodies(bank, paths: Any) -> np.ndarray | None:
  """Indices into the bank's B axis for `paths` (True: all tracked bodies;
  a body/object/group name or a list of them); None when no paths."""
  if paths is None or paths is False:
    return None
  if paths is True:
    return np.arange(len(bank.body_names), dtype=np.int64)
  return np.asarray(bank.select_bodies(paths), np.int64).reshape(-1)


def scene_bounds(bank, model: mujoco.MjModel, worlds: np.ndarray,
                 path_classes: PathClasses | None, bodies: np.ndarray | None,
                 visible_groups: tuple[int, ...] = DEFAULT_VISIBLE_GROUPS) -> tuple[np.ndarray, np.ndarray]:
  """(lo f64[3], hi f64[3]) box around what is shown: the COM paths of the
  played-back worlds (all bodies, widened by the largest moving geom) and of
  the drawn paths, and the boxes of the visible static geoms other than planes."""
  com = np.asarray(bank.com)
  pts = [_finite_extent(com, worlds, np.arange(com.shape[2]))]
  visible = np.isin(model.geom_group, visible_groups) & (model.geom_rgba[:, 3] > 0)
  moving = visible & (model.body_weldid[model.geom_bodyid] != 0)
  if pts[0].size and moving.any():
    margin = float(model.geom_rbound[moving].max())
    pts[0] = pts[0] + np.array([[-margin], [margin]])
  if path_classes is not None and bodies is not None:
    pts.append(_finite_extent(com, np.concatenate(list(path_classes)), bodies))
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  static = np.flatnonzero(visible & (model.body_weldid[model.geom_bodyid] == 0)
                          & (model.geom_type != mujoco.mjtGeom.mjGEOM_PLANE))
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


def fit_distance(lo: np.ndarray, hi: np.ndarray, centre: np.ndarray, direction: np.ndarray,
                 fovy: float, aspect: float = 4 / 3, margin: float = 0.9) -> float:
  """Smallest distance from `centre` along unit `direction` (towards the eye)
  at which all 8 corners of the box [lo, hi] are inside the view.

  fovy: vertical field of view in degrees; aspect: width / height assumed for
  the browser window; margin: fraction of the half-angles used.
  """
  corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
  forward = -direction
  right = np.cross(forward, [0.0, 0.0, 1.0])
  if np.linalg.norm(right) < 1e-6:  # looking straight down or up
    right = np.array([1.0, 0.0, 0.0])
  right /= np.linalg.norm(right)
  up = np.cross(right, forward)
  tan_v = np.tan(np.radians(fovy) / 2) * margin
  tan_h = tan_v * aspect

  def fits(dist: float) -> bool:
    v = corners - (centre + dist * direction)
    depth = v @ forward
    return bool(np.all(depth > 1e-3) and np.all(np.abs(v @ right) <= tan_h * depth)
                and np.all(np.abs(v @ up) <= tan_v * depth))

  radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.1)
  near, far = 0.0, radius / np.sin(np.radians(fovy) / 2) * 2 + 1.0
  for _ in range(40):  # bisection; the view only widens with distance
    mid = (near + far) / 2
    near, far = (near, mid) if fits(mid) else (mid, far)
  return far


def mjcf_camera(model: mujoco.MjModel, cam_id: int) -> tuple[np.ndarray, np.ndarray, float]:
  """(position f64[3], forward unit f64[3], fovy degrees) of an MJCF camera
  at the reference configuration."""
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  mujoco.mj_camlight(model, data)
  forward = -data.cam_xmat[cam_id].reshape(3, 3)[:, 2]  # cameras look along -z
  return data.cam_xpos[cam_id].copy(), forward, float(model.cam_fovy[cam_id])


def _finite_extent(com: np.ndarray, worlds: np.ndarray, bodies: np.ndarray,
                   chunk: int = 1024) -> np.ndarray:
  """f64[k, 3] (k = 0 or 2) finite min and max over com[worlds][:, :, bodies],
  in chunks of worlds so a large bank is never copied whole."""
  lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
  for start in range(0, len(worlds), chunk):
    part = com[worlds[start:start + chunk]][:, :, bodies].reshape(-1, 3).astype(np.float64)
    part = part[np.all(np.isfinite(part), axis=1)]
    if part.size:
      lo, hi = np.minimum(lo, part.min(axis=0)), np.maximum(hi, part.max(axis=0))
  return np.stack([lo, hi]) if np.all(np.isfinite(lo)) else np.zeros((0, 3))


class ViewSpec(NamedTuple):
  """Where the first view looks from.

  direction: f64[3] unit vector from the scene towards the eye.
  fovy: vertical field of view, degrees.
  eye: f64[3] exact eye position (an MJCF camera), or None to fit the scene.
  """

  direction: np.ndarray
  fovy: float
  eye: np.ndarray | None


def view_spec(model: mujoco.MjModel, camera: str | None = None,
              view_dir: Sequence[float] | None = None) -> ViewSpec:
  """camera: an MJCF camera name to view exactly from; None fits the scene
  into view, looking along `view_dir` (f[3], scene towards eye), else along
  the model's first camera, else obliquely from the front right."""
  if camera is not None:
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cam_id < 0:
      names = [model.camera(i).name for i in range(model.ncam)]
      raise ViewerError(f"camera: no MJCF camera named {camera!r} (cameras: {names})")
    eye, forward, fovy = mjcf_camera(model, cam_id)
    return ViewSpec(-forward, fovy, eye)
  fovy = float(model.cam_fovy[0]) if model.ncam > 0 else DEFAULT_FOVY
  if view_dir is not None:
    direction = np.asarray(view_dir, np.float64).reshape(-1)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.any(direction):
      raise ViewerError(f"view_dir: must be a finite nonzero 3-vector, got {direction.tolist()}")
  elif model.ncam > 0:
    direction = -mjcf_camera(model, 0)[1]
  else:
    direction = DEFAULT_VIEW_DIR
  return ViewSpec(direction / np.linalg.norm(direction), fovy, None)


def place_camera(vis, lo: np.ndarray, hi: np.ndarray, spec: ViewSpec) -> tuple[np.ndarray, np.ndarray]:
  """Aims meshcat's camera at the box [lo, hi]. Returns (centre f64[3],
  eye f64[3]) in world coordinates; the caller shifts the scene by -centre."""
  box_centre = (lo + hi) / 2
  radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.2)
  if spec.eye is not None:
    # Orbit about the point on the camera's axis nearest the scene, so the
    # first view looks exactly where the MJCF camera does.
    forward = -spec.direction
    depth = max(float(np.dot(box_centre - spec.eye, forward)), 0.1)
    eye = spec.eye
    centre = eye + depth * forward
  else:
    centre = box_centre
    eye = centre + spec.direction * fit_distance(lo, hi, centre, spec.direction, spec.fovy)
  d = eye - centre
  cam = vis["/Cameras/default/rotated/<object>"]
  # The camera's parent is rotated +90 deg about x (three.js is y-up):
  # world (x, y, z) = local (x, -z, y).
  cam.set_property("position", [float(d[0]), float(d[2]), float(-d[1])])
  cam.set_property("fov", spec.fovy)
  cam.set_property("far", float(max(100.0, 20 * (radius + np.linalg.norm(d)))))
  return centre, eye


def draw(vis, bank, worlds: Sequence[int] | None = None, *, paths: Any = None,
         path_worlds: Sequence[int] | None = None, match: np.ndarray | None = None,
         exclude: np.ndarray | None = None, queries: Sequence[Any] | None = None,
         layout: str = "overlay", camera: str | None = None,
         view_dir: Sequence[float] | None = None, play: bool = True,
         frustum_depth: float | None = None,
         visible_groups: tuple[int, ...] = DEFAULT_VISIBLE_GROUPS) -> DrawInfo:
  """Draws a bank's worlds, paths and queries into a meshcat visualizer.

  bank: a sampled bank (mwbx.bank contract).
  worlds: indices of worlds to play back; None = the first valid world, [] = none.
  paths: COM paths to draw for every valid world (or `path_worlds`): True for
    all tracked bodies, or body/object/group name(s); None = no paths.
  match, exclude: bool[W] worlds whose paths are green / red (others faint);
    when `queries` are mwbx.queries objects and both are None they come from
    evaluating the queries.
  queries: frustums to draw: QueryVolume, (corners f[8, 3], include) pairs or
    mwbx.queries query objects.
  layout: "overlay" (ghosted, tinted) or "grid" (side by side).
  camera: MJCF camera to view exactly from; None: fit everything into view,
    looking along the model's first camera where it has one.
  view_dir: f[3] direction from the scene towards the eye for the fitted view.
  frustum_depth: longest frustum side edge drawn, metres (None: 3x scene size).
  """
  if layout not in LAYOUTS:
    raise ViewerError(f"layout must be one of {LAYOUTS}, got {layout!r}")
  model = bank.model()
  worlds = resolve_worlds(bank, worlds)
  bodies = resolve_bodies(bank, paths)
  queries = as_query_list(queries)
  if queries and match is None and exclude is None:
    match, exclude = query_classes(bank, queries)
  classes = None
  if bodies is not None:
    classes = classify_worlds(np.asarray(bank.valid), path_worlds, match, exclude)
  volumes = [as_volume(q, i) for i, q in enumerate(queries)]
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
    draw_volume(root["queries"][f"q{i}"], volume, i, max_depth=depth, eye_radius=0.015 * radius)
  return DrawInfo(centre, worlds, offsets, counts, len(volumes), eye)


def as_query_list(queries: Any) -> list:
  """None, one query, a sequence of them, or a mwbx.queries.QuerySet -> list."""
  if queries is None:
    return []
  if isinstance(queries, QueryVolume) or hasattr(queries, "frustum"):
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
  from mwbx.viewer import query_adapter

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
  Stop a server this started with `vis.window.server_proc.kill()`.
  Other keyword arguments: see `draw` (path_worlds, match, exclude, camera,
  view_dir, play, frustum_depth, visible_groups).
  """
  if vis is None:
    vis = meshcat.Visualizer(zmq_url=zmq_url)
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
