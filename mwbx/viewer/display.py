"""What both viewers draw, as plain arrays: one display model, two renderers.

The meshcat viewer (:mod:`mwbx.viewer.api`) and the browsing page
(:mod:`mwbx.browser`) draw the same things: COM paths in three classes
(faint, match, exclude) in the colours of one table, thinned to a segment
budget; query volumes (solid, outline, the camera they came from); and a
first view framed around the scene or copied from an MJCF camera. This module
computes them with numpy only; each front end only translates them into its
own calls (meshcat objects, viser scene nodes).
"""

from __future__ import annotations

from typing import Any, Mapping, NamedTuple

import numpy as np

from mwbx.viewer.errors import ViewerError
from mwbx.viewer.hull import frustum_eye, hull_mesh, plane_vertices, truncate

# MuJoCo's own viewer shows geom groups 0-2 by default; 3+ usually hold
# collision-only geoms that would hide the visual ones.
DEFAULT_VISIBLE_GROUPS = (0, 1, 2)


class Rgba(NamedTuple):
  """A colour with opacity, components in [0, 1]."""

  r: float
  g: float
  b: float
  a: float

  def hex(self) -> int:
    """0xRRGGBB, as meshcat/three.js materials take it."""
    c = self.u8()
    return c[0] << 16 | c[1] << 8 | c[2]

  def u8(self) -> tuple[int, int, int]:
    """(r, g, b) in 0..255, opacity left out."""
    c = np.clip(np.round(np.asarray(self[:3]) * 255.0), 0, 255).astype(int)
    return int(c[0]), int(c[1]), int(c[2])

  def over(self, background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> tuple[int, int, int]:
    """(r, g, b) in 0..255 of this colour blended over an opaque background:
    what a front end without per-line opacity draws instead."""
    rgb = self.a * np.asarray(self[:3]) + (1.0 - self.a) * np.asarray(background, np.float64)
    return Rgba(*rgb, 1.0).u8()


# Path classes, drawn in this order (later ones on top): every other world
# faint, worlds satisfying every query green, worlds an exclude query rejects red.
PATH_CLASSES = ("faint", "match", "exclude")
PATH_RGBA = {
    "faint": Rgba(0.55, 0.55, 0.6, 0.35),
    "match": Rgba(0.0, 0.9, 0.1, 1.0),
    "exclude": Rgba(0.95, 0.05, 0.05, 1.0),
}
# Query volumes: translucent, in the colour of the paths they let through or reject.
QUERY_RGBA = {
    "include": PATH_RGBA["match"]._replace(a=0.22),
    "exclude": PATH_RGBA["exclude"]._replace(a=0.22),
}
CAMERA_RGBA = Rgba(0.15, 0.15, 0.15, 1.0)


# -- paths --------------------------------------------------------------------------------

class PathClasses(NamedTuple):
  """Which worlds' paths are drawn and how.

  faint: i64[n] world rows drawn faint (neither matching nor excluded).
  match: i64[m] world rows drawn green.
  exclude: i64[e] world rows drawn red.
  """

  faint: np.ndarray
  match: np.ndarray
  exclude: np.ndarray


class PathLayer(NamedTuple):
  """One class of paths, ready to draw.

  name: "faint", "match" or "exclude".
  rgba: its colour (:data:`PATH_RGBA`).
  segments: f32[S, 2, 3] segment end points, metres.
  worlds: i64[n] the world rows drawn.
  left_out: how many worlds of the class the segment budget left out.
  """

  name: str
  rgba: Rgba
  segments: np.ndarray
  worlds: np.ndarray
  left_out: int


def classify_worlds(valid: np.ndarray, worlds: np.ndarray | None,
                    match: np.ndarray | None, exclude: np.ndarray | None) -> PathClasses:
  """Splits the worlds whose paths are drawn into faint / match / exclude.

  valid: bool[W]; invalid (unstable) worlds are never drawn.
  worlds: i[n] rows to draw, or None for every valid world.
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


def polyline_segments(com: np.ndarray, count: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
  """Line segments of COM polylines, zero-length tails and non-finite points dropped.

  com: f[N, P, K, 3] points (metres) of N worlds and K bodies, point p at time
    p / query_fps; points at index >= count[n] repeat the last valid point.
  count: i[N] valid points per world.
  keep: optional bool[N, P, K] points to join (:func:`simplify_polylines`);
    a segment then joins each kept point to the next kept one.
  Returns f32[S, 2, 3]: the two ends of each segment, world by world.
  """
  com = np.asarray(com, np.float32)
  count = np.asarray(count)
  if com.ndim != 4 or com.shape[-1] != 3 or count.shape != com.shape[:1]:
    raise ViewerError(f"com must be f32[N, P, K, 3] with count i32[N]; got {com.shape} and {count.shape}")
  if keep is not None:
    return _kept_segments(com, count, np.asarray(keep, bool))
  starts, ends = com[:, :-1], com[:, 1:]  # [N, P-1, K, 3]
  # Segment p joins points p and p + 1; it exists while p + 1 < count.
  exists = np.arange(com.shape[1] - 1)[None, :] < (count[:, None] - 1)  # [N, P-1]
  exists = np.broadcast_to(exists[:, :, None], starts.shape[:3])
  exists = exists & np.all(np.isfinite(starts) & np.isfinite(ends), axis=-1)
  return np.ascontiguousarray(np.stack([starts[exists], ends[exists]], axis=1))


def _valid_points(com: np.ndarray, count) -> np.ndarray:
  """bool[N, P, K]: the finite points of polylines ``com`` f[N, P, K, 3] before ``count`` i[N]."""
  return (np.arange(com.shape[1])[None, :, None] < np.asarray(count)[:, None, None]) & np.all(np.isfinite(com), axis=-1)


def _kept_segments(com: np.ndarray, count: np.ndarray, keep: np.ndarray) -> np.ndarray:
  """:func:`polyline_segments` joining kept points only (keep: bool[N, P, K]);
  never across a non-finite or missing point."""
  valid = _valid_points(com, count)
  points = np.swapaxes(com, 1, 2).reshape(-1, 3)  # polyline by polyline: [(N K) P, 3]
  line_valid = np.swapaxes(valid, 1, 2)
  gaps = np.cumsum(~line_valid, axis=-1).reshape(-1)  # invalid points so far in the polyline
  index = np.nonzero(np.swapaxes(keep & valid, 1, 2).reshape(-1))[0]
  line = index // com.shape[1]
  joined = (line[:-1] == line[1:]) & (gaps[index[:-1]] == gaps[index[1:]])
  return np.ascontiguousarray(np.stack([points[index[:-1][joined]], points[index[1:][joined]]], axis=1))


def simplify_polylines(com: np.ndarray, count: np.ndarray, tolerance: float) -> np.ndarray:
  """Points of COM polylines worth drawing: bool[N, P, K].

  A body flying straight, or lying at rest, needs two points, not one per
  frame. Dyadic rounds: round j may drop the point at an odd multiple of 2**j
  whose 2**j neighbours on either side were all dropped, when every recorded
  point between the points 2**j away on either side lies within
  ``tolerance`` of the chord joining them; so the drawn line strays less
  than ``tolerance`` from every point. Only windows whose inner points are
  all dropped are measured, so the work is about one pass over the points
  per round. Invalid points (past ``count``, or non-finite) and the ends of
  each run of valid points are always kept.

  Args:
    com: f[N, P, K, 3] polylines as for :func:`polyline_segments`, metres.
    count: i[N] valid points per world.
    tolerance: metres.

  Example:
    >>> line = np.zeros((1, 5, 1, 3)); line[0, :, 0, 0] = np.arange(5)  # straight, along x
    >>> simplify_polylines(line, np.array([5]), 1e-3)[0, :, 0].tolist()
    [True, False, False, False, True]
  """
  com = np.asarray(com, np.float32)
  n, p, k = com.shape[:3]
  valid = _valid_points(com, count)
  before = np.concatenate([np.zeros((n, 1, k), bool), valid[:, :-1]], axis=1)
  after = np.concatenate([valid[:, 1:], np.zeros((n, 1, k), bool)], axis=1)
  droppable = valid & before & after  # not an end of a run of valid points
  rounds = max(int(np.ceil(np.log2(max(p - 1, 2)))), 1)
  size = 1 << rounds  # points 0..size, the tail padded with the last one
  pad = size + 1 - p
  points = np.concatenate([com, np.repeat(com[:, -1:], pad, axis=1)], axis=1)
  droppable = np.concatenate([droppable, np.zeros((n, pad, k), bool)], axis=1)
  keep = np.ones((n, size + 1, k), bool)
  clear = np.ones((n, size, k), bool)  # blocks [i h, (i + 1) h] whose inner points are all dropped
  tolerance2 = np.float32(tolerance) ** 2
  for j in range(rounds):
    h = 1 << j
    width = 2 * h
    candidate = droppable[:, h:size:width] & clear[:, 0::2] & clear[:, 1::2]  # [n, size / width, k]
    world, window, body = np.nonzero(candidate)
    drop = np.zeros_like(candidate)
    if world.size:  # every point of each candidate's window against its chord
      frames = window[:, None] * width + np.arange(width + 1)[None, :]
      span = points[world[:, None], frames, body[:, None]]  # [c, width + 1, 3]
      a, ab = span[:, :1], span[:, -1:] - span[:, :1]
      t = np.clip(np.sum((span - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), np.float32(1e-30)), 0, 1)
      off2 = np.sum((span - (a + t[..., None] * ab)) ** 2, axis=-1)
      drop[world, window, body] = off2.max(axis=1) <= tolerance2
    keep[:, h:size:width] = ~drop
    clear = clear[:, 0::2] & clear[:, 1::2] & drop
  return keep[:, :p]


def thin(worlds: np.ndarray, per_world: int, budget: int | None) -> tuple[np.ndarray, int]:
  """(kept i64[k], left out): an evenly spaced subset of ``worlds`` drawing at
  most ``budget`` segments at ``per_world`` each (never fewer than one
  world); all of them when ``budget`` is None."""
  worlds = np.asarray(worlds, np.int64)
  if budget is None:
    return worlds, 0
  keep = max(int(budget) // max(int(per_world), 1), 1)
  if worlds.size <= keep:
    return worlds, 0
  kept = worlds[np.linspace(0, worlds.size - 1, keep).round().astype(np.int64)]
  return kept, int(worlds.size - keep)


class PathSimplifier:
  """:func:`simplify_polylines` of one bank's worlds, each computed once.

  A page redraws the same worlds' paths on every query change (only their
  classes change), so the points kept are remembered per world, for one
  ``com`` array and one choice of bodies at a time.

  Args:
    tolerance: metres a drawn path may stray from a recorded point.
  """

  def __init__(self, tolerance: float):
    self.tolerance = float(tolerance)
    self._com = self._bodies = None
    self._keep = self._done = None

  def __call__(self, com: np.ndarray, count: np.ndarray, worlds: np.ndarray, bodies: np.ndarray,
               points: np.ndarray | None = None) -> np.ndarray:
    """bool[len(worlds), P, K]: the points of ``com[worlds][:, :, bodies]`` to join
    (``points``: those, when the caller has read them already)."""
    bodies = tuple(np.asarray(bodies).reshape(-1).tolist())
    if com is not self._com or bodies != self._bodies:  # (the array itself is held: its id is never reused)
      self._com, self._bodies = com, bodies
      self._keep = np.zeros((com.shape[0], com.shape[1], len(bodies)), bool)
      self._done = np.zeros(com.shape[0], bool)
    worlds = np.asarray(worlds, np.int64)
    todo = np.unique(worlds[~self._done[worlds]])
    if todo.size:
      if points is None:
        todo_points = np.asarray(com[todo])[:, :, list(bodies)]
      else:  # the caller's rows: a lazily opened bank's paths are not read twice
        seen, first = np.unique(worlds, return_index=True)
        todo_points = np.asarray(points)[first[np.searchsorted(seen, todo)]]
      self._keep[todo] = simplify_polylines(todo_points, np.asarray(count)[todo], self.tolerance)
      self._done[todo] = True
    return self._keep[worlds]


def path_layers(com: np.ndarray, count: np.ndarray, bodies: np.ndarray, classes: PathClasses,
                budget: Mapping[str, int | None], simplify: PathSimplifier | None = None) -> tuple[PathLayer, ...]:
  """The three path classes of tracked bodies ``bodies``, each thinned to its budget.

  com: f32[W, P, B, 3] the bank's COM polylines (metres); count: i32[W];
  bodies: i[K] indices into B; budget: {class name: most segments drawn, or
  None for all}; simplify: the points worth joining (:class:`PathSimplifier`;
  None: every point). Returns one layer per class, in :data:`PATH_CLASSES` order.
  """
  bodies = np.asarray(bodies, np.int64).reshape(-1)
  per_world = max(com.shape[1] - 1, 0) * bodies.size
  out = []
  for name, worlds in zip(PATH_CLASSES, classes):
    kept, left_out = thin(worlds, per_world, budget.get(name))
    if kept.size and bodies.size and com.shape[1] >= 2:
      points, counts = np.asarray(com[kept])[:, :, bodies], np.asarray(count)[kept]
      keep = None if simplify is None else simplify(com, count, kept, bodies, points)
      segments = polyline_segments(points, counts, keep)
    else:
      segments = np.zeros((0, 2, 3), np.float32)
    out.append(PathLayer(name, PATH_RGBA[name], segments, kept, left_out))
  return tuple(out)


# -- query volumes ------------------------------------------------------------------------

class DrawnVolume(NamedTuple):
  """A query's volume as the viewer draws it (a frustum or a convex hull; not a query).

  corners: f64[8, 3] world-space corners in metres, near face then far face
    (far corner i lies on the ray from the camera through near corner i);
    or f64[N, 3] vertices of any convex volume (then never truncated).
  include: True for a positive query (must pass through), False for negative.
  eye: f64[3] camera position, or None to infer it from the side edges.
  """

  corners: np.ndarray
  include: bool
  eye: np.ndarray | None = None


class VolumeShape(NamedTuple):
  """A query volume, ready to draw.

  rgba: its colour (:data:`QUERY_RGBA`).
  vertices: f32[N, 3] and faces: u32[F, 3] the translucent solid (outward
    counter-clockwise), metres.
  edges: f32[E, 2, 3] its outline (between faces that are not coplanar).
  eye: f64[3] the camera it was seen through, or None (orthographic, unknown).
  rays: f32[R, 2, 3] eye to near corners (R = 4, or 0 without an eye).
  """

  rgba: Rgba
  vertices: np.ndarray
  faces: np.ndarray
  edges: np.ndarray
  eye: np.ndarray | None
  rays: np.ndarray


def as_volume(query: Any, index: int = 0) -> DrawnVolume:
  """Turns one query description into a DrawnVolume.

  Accepted: a DrawnVolume; a (corners f[8, 3], include) pair; or an object
  with a `frustum` / `corners` attribute (mwbx.queries), where include comes
  from `include` / `positive` / `negative` and the eye from `camera`.
  """
  if isinstance(query, DrawnVolume):
    corners, include, eye = query
  elif isinstance(query, tuple) and len(query) == 2:
    corners, include = query
    eye = None
  else:
    corners, include, eye = _from_query_object(query, index)
  corners = np.asarray(corners, np.float64)
  if corners.ndim != 2 or corners.shape[1] != 3 or corners.shape[0] < 4 \
      or not np.all(np.isfinite(corners)):
    raise ViewerError(f"query {index}: frustum corners must be finite 3-D points, 8 for a frustum "
                      f"(near face then far face), got shape {corners.shape}")
  if eye is not None:
    eye = np.asarray(eye, np.float64).reshape(3)
  return DrawnVolume(corners, bool(include), eye)


def _from_query_object(query: Any, index: int):
  frustum = getattr(query, "frustum", query)
  corners = getattr(frustum, "corners", None)
  if corners is None and getattr(frustum, "normals", None) is not None:
    corners = plane_vertices(frustum.normals, frustum.offsets, index)
  if corners is None:
    raise ViewerError(f"query {index}: expected a DrawnVolume, a (corners, include) pair or a "
                      f"query with frustum corners; got {type(query).__name__}")
  if hasattr(query, "include"):
    include = bool(query.include)
  elif hasattr(query, "positive"):
    include = bool(query.positive)
  elif hasattr(query, "negative"):
    include = not bool(query.negative)
  else:
    include = True
  camera = getattr(query, "camera", None) or getattr(frustum, "camera", None)
  eye = None
  for holder, name in ((camera, "position"), (camera, "pos"), (camera, "eye"), (frustum, "eye")):
    if holder is not None and getattr(holder, name, None) is not None:
      eye = getattr(holder, name)
      break
  return corners, include, eye


def volume_shape(volume: DrawnVolume, index: int = 0, max_depth: float | None = None) -> VolumeShape:
  """The solid, outline and camera of one query volume, its far face moved in
  so no side edge is longer than ``max_depth`` metres (None: as given)."""
  corners = truncate(volume.corners, max_depth)
  vertices, faces, edge_ids = hull_mesh(corners, index)
  edges = np.ascontiguousarray(vertices[edge_ids.reshape(-1)].reshape(-1, 2, 3), np.float32)
  eye = volume.eye if volume.eye is not None else frustum_eye(volume.corners)
  rays = np.zeros((0, 2, 3), np.float32)
  if eye is not None and volume.corners.shape[0] == 8:
    rays = np.stack([np.repeat(eye[None], 4, axis=0), volume.corners[:4]], axis=1).astype(np.float32)
  return VolumeShape(QUERY_RGBA["include" if volume.include else "exclude"], vertices, faces, edges, eye, rays)


# -- the first view -----------------------------------------------------------------------

class ViewSpec(NamedTuple):
  """Where the first view looks from.

  direction: f64[3] unit vector from the scene towards the eye.
  fovy: vertical field of view, degrees.
  eye: f64[3] exact eye position (an MJCF camera), or None to fit the scene.
  """

  direction: np.ndarray
  fovy: float
  eye: np.ndarray | None


class CameraPose(NamedTuple):
  """A viewing camera: eye and target f64[3] (metres, world frame; the view
  orbits the target), fovy (vertical, degrees); world +z is up."""

  eye: np.ndarray
  target: np.ndarray
  fovy: float


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


def frame_box(lo: np.ndarray, hi: np.ndarray, spec: ViewSpec,
              aspect: float = 4 / 3) -> tuple[np.ndarray, np.ndarray]:
  """(centre f64[3], eye f64[3]): where a first view of the box [lo, hi]
  orbits about and looks from, metres.

  Without an exact eye the eye is along ``spec.direction`` from the box's
  centre, as near as lets every corner of the box be seen in front of it: it
  is outside the box, whatever the direction.
  """
  box_centre = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2
  if spec.eye is not None:
    # Orbit about the point on the camera's axis nearest the scene, so the
    # first view looks exactly where the MJCF camera does.
    forward = -spec.direction
    depth = max(float(np.dot(box_centre - spec.eye, forward)), 0.1)
    return spec.eye + depth * forward, np.asarray(spec.eye, np.float64)
  eye = box_centre + spec.direction * fit_distance(lo, hi, box_centre, spec.direction, spec.fovy, aspect)
  return box_centre, eye


def camera_pose(lo: np.ndarray, hi: np.ndarray, spec: ViewSpec, aspect: float = 4 / 3) -> CameraPose:
  """The first view of the box [lo, hi] (metres) as ``spec`` asks for it."""
  target, eye = frame_box(lo, hi, spec, aspect)
  return CameraPose(np.asarray(eye, np.float64), np.asarray(target, np.float64), float(spec.fovy))
