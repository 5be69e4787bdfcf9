"""Queries over a bank: which worlds' COM paths pass through which volumes.

A Query is a volume (usually a screen box seen through a camera), a sign
(`include`: the path must pass through it; `exclude`: it must not), a
selection of tracked bodies (body, object or group names) combined with
`any` or `all`, an optional time window in seconds and an optional swept
sphere radius; or, with ``shape="geometry"``, about any point of the bodies'
geoms instead of their COM (:mod:`.geometry`). A list of queries is their
conjunction (with joint and orientation queries mixed in). Unstable worlds
never match anything.

Per world, with `hit[b]` = "body b's path meets the volume in the window":
  include/any: some selected body hits;  include/all: every selected body hits
  exclude/any: no selected body hits;    exclude/all: not every selected one
(an empty selection: include/any and exclude/all never match, the other two
always do).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence
import weakref

import jax
from jax import numpy as jp
import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries import geometry as geometry_lib
from mwbx.queries import geometry_query
from mwbx.queries import index as index_lib
from mwbx.queries import orientation as orientation_lib
from mwbx.queries.intervals import checked_interval
from mwbx.queries import joint as joint_lib
from mwbx.queries import segments
from mwbx.queries.camera import Camera
from mwbx.queries.camera import MAX_COORDINATE
from mwbx.queries.camera import ScreenBox
from mwbx.queries.frustum import Frustum

SIGNS = ("include", "exclude")
MODES = ("any", "all")
SHAPES = ("com", "geometry")


@dataclasses.dataclass(frozen=True, eq=False)
class Query:
  """One spatial constraint on worlds.

  frustum: the volume.
  bodies: names of tracked bodies, objects or groups (mixed freely), or None
    for every tracked body.
  sign: "include" or "exclude".
  mode: "any" or "all" over the selected bodies.
  window: (t0, t1) seconds, either end None for open; None: the whole path.
    Times past the end of a path see its last point (the world is at rest).
  radius: swept-sphere radius in metres, or "auto" for each body's bounding
    radius (from its own geoms, about its centre of mass).
  shape: "com" (the centre-of-mass path, swept by `radius`) or "geometry"
    (any point of the body's geoms, :mod:`.geometry`; radius must be 0).
  name: label for output. camera, box, near, far (screen queries) or
    world_box ((lo, hi), region queries): where the frustum came from, so it
    can be saved.
  """

  frustum: Frustum
  bodies: tuple[str, ...] | None = None
  sign: str = "include"
  mode: str = "any"
  window: tuple[float | None, float | None] | None = None
  radius: float | str = 0.0
  name: str = ""
  camera: Camera | None = None
  box: ScreenBox | None = None
  near: float | None = None
  far: float | None = None
  world_box: tuple | None = None
  shape: str = "com"

  def __post_init__(self):
    label = f"query {self.name!r}" if self.name else "query"
    if not isinstance(self.frustum, Frustum):
      raise MwbxError(f"{label}: frustum must be a Frustum, got {type(self.frustum).__name__}")
    if isinstance(self.bodies, str):
      object.__setattr__(self, "bodies", (self.bodies,))
    elif self.bodies is not None:
      object.__setattr__(self, "bodies", tuple(str(b) for b in self.bodies))
    if self.sign not in SIGNS:
      raise MwbxError(f"{label}: sign must be one of {SIGNS}, got {self.sign!r}")
    if self.mode not in MODES:
      raise MwbxError(f"{label}: mode must be one of {MODES}, got {self.mode!r}")
    if self.window is not None:
      object.__setattr__(self, "window", checked_interval(label, "window", self.window, ("t0", "t1"), "seconds"))
    if isinstance(self.radius, str):
      if self.radius != "auto":
        raise MwbxError(f"{label}: radius must be a number of metres or 'auto', got {self.radius!r}")
    else:
      r = float(self.radius)
      if not (math.isfinite(r) and 0 <= r <= MAX_COORDINATE):
        raise MwbxError(f"{label}: radius must be a number from 0 to {MAX_COORDINATE:g} (metres), got {self.radius!r}")
      object.__setattr__(self, "radius", r)
    if self.shape not in SHAPES:
      raise MwbxError(f"{label}: shape must be one of {SHAPES}, got {self.shape!r}")
    if self.shape == "geometry" and self.radius != 0.0:
      raise MwbxError(f"{label}: a geometry query tests the geoms themselves: radius must be 0, "
                      f"got {self.radius!r}")

  @property
  def include(self) -> bool:
    return self.sign == "include"

  @classmethod
  def screen(cls, camera: Camera, box: ScreenBox | Sequence[float], *,
             near: float | None = None, far: float | None = None, **fields) -> Query:
    """A query from a screen box [u0, v0, u1, v1] seen through a camera."""
    if not isinstance(box, ScreenBox):
      box = ScreenBox(*box)
    return cls(camera.frustum(box, near, far), camera=camera, box=box, near=near, far=far, **fields)

  @classmethod
  def region(cls, lo, hi, **fields) -> Query:
    """A query on an axis-aligned world box [lo, hi], metres."""
    return cls(Frustum.box(lo, hi), world_box=(tuple(float(x) for x in lo), tuple(float(x) for x in hi)),
               **fields)


QUERY_TYPES = (Query, joint_lib.JointQuery, orientation_lib.OrientationQuery)


def as_queries(queries) -> tuple:
  """A Query (JointQuery, OrientationQuery), a sequence of them or an object
  with `.queries` -> tuple."""
  if isinstance(queries, QUERY_TYPES):
    return (queries,)
  queries = getattr(queries, "queries", queries)
  out = tuple(queries)
  for i, q in enumerate(out):
    if not isinstance(q, QUERY_TYPES):
      raise MwbxError(f"queries[{i}]: expected a Query, JointQuery or OrientationQuery, "
                      f"got {type(q).__name__}")
  return out


# ---------------------------------------------------------------------------
# Per-bank state: the bounds hierarchy and body radii, built once and cached.


@dataclasses.dataclass
class _BankState:
  key: tuple
  index: index_lib.PathIndex
  radii: np.ndarray | None = None


_CACHE: dict[int, tuple[object, _BankState]] = {}

# COM polylines up to this size (decoded, 1 GiB) are indexed whole and the index is
# cached: browsing asks again and again. A lazily opened bank beyond it is
# indexed a shard at a time in each evaluation, in the memory of one shard.
IN_MEMORY_COM_BYTES = 1 << 30


def streams(bank) -> bool:
  """Whether queries on this bank go a shard at a time (see ``IN_MEMORY_COM_BYTES``)."""
  com = bank.com
  return _lazy(com) and com.nbytes > IN_MEMORY_COM_BYTES


def _lazy(com) -> bool:
  """A bank's ``com`` read from shards on demand (``mwbx.bank.lazy.LazyRows``)."""
  return hasattr(com, "blocks") and hasattr(com, "materialized")


def _blocks(bank, valid: np.ndarray):
  """(i64[k] rows, _BankState of those rows) a shard at a time: the whole bank."""
  radii = None
  for rows, com in bank.com.blocks():
    state = _BankState(None, index_lib.build_index(com, valid[rows]), radii)
    yield rows, state
    radii = state.radii  # body radii are the bank's: computed once


def _state(bank) -> _BankState:
  com = bank.com
  if _lazy(com):  # small enough to index whole: read every shard once
    com = com.materialized()
  valid = np.asarray(bank.valid, bool)
  key = (id(com), com.shape, valid.tobytes())
  entry = _CACHE.get(id(bank))
  if entry is not None:
    ref, state = entry
    alive = ref() if isinstance(ref, weakref.ref) else ref
    if alive is bank and state.key == key:
      return state
  state = _BankState(key, index_lib.build_index(com, valid))
  try:
    ref = weakref.ref(bank, lambda _, k=id(bank): _CACHE.pop(k, None))
  except TypeError:  # not weak-referenceable: keep it, but only the latest
    ref = bank
    for k in [k for k, (r, _) in _CACHE.items() if not isinstance(r, weakref.ref)]:
      del _CACHE[k]
  _CACHE[id(bank)] = (ref, state)
  return state


def path_index(bank) -> index_lib.PathIndex:
  """The bank's bounds hierarchy (built on first use, then cached)."""
  return _state(bank).index


def body_radii(model: mujoco.MjModel, body_ids) -> np.ndarray:
  """Bounding radius of each body about its centre of mass, from its own geoms.

  Args:
    model: the scene model.
    body_ids: i[B] MuJoCo body ids.

  Returns:
    f64[B] max over the body's geoms of |geom centre - COM| + geom bounding
    radius, metres (0 for a body without geoms).
  """
  radii = np.zeros(len(body_ids))
  for i, body in enumerate(np.asarray(body_ids)):
    geoms = np.flatnonzero(model.geom_bodyid == body)
    if geoms.size:
      reach = np.linalg.norm(model.geom_pos[geoms] - model.body_ipos[body], axis=1)
      radii[i] = float(np.max(reach + model.geom_rbound[geoms]))
  return radii


def _radii(bank, state: _BankState) -> np.ndarray:
  if state.radii is None:
    state.radii = body_radii(bank.model(), bank.body_ids)
  return state.radii


def selection_mask(bank, bodies) -> np.ndarray:
  """bool[B] of the tracked bodies named by body/object/group names."""
  n_bodies = len(bank.body_names)
  if bodies is None:
    return np.ones(n_bodies, bool)
  if isinstance(bodies, str):
    bodies = (bodies,)
  mask = np.zeros(n_bodies, bool)
  if len(bodies):
    mask[np.asarray(bank.select_bodies(list(bodies)), np.int64)] = True
  return mask


def window_units(bank, window, n_segments: int) -> np.ndarray:
  """A window in seconds -> f64[2] segment units clamped to [0, n_segments]."""
  t0, t1 = (None, None) if window is None else window
  fps = float(bank.query_fps)
  w0 = 0.0 if t0 is None else min(max(t0 * fps, 0.0), float(n_segments))
  w1 = float(n_segments) if t1 is None else min(max(t1 * fps, 0.0), float(n_segments))
  return np.array([w0, w1])


def plane_offsets(frustum: Frustum, radius: np.ndarray) -> np.ndarray:
  """f64[B, F] plane offsets with each body's sphere radius added."""
  return frustum.offsets[None, :] + np.asarray(radius, np.float64)[:, None]


def resolve(bank, query: Query, state: _BankState | None = None):
  """A query's arrays for the kernels on this bank.

  Returns:
    (normals f32[F, 3], offsets f64[B, F], body_mask bool[B], window f64[2]).
  """
  state = state or _state(bank)
  n_bodies = len(bank.body_names)
  if query.radius == "auto":
    radius = _radii(bank, state)
  else:
    radius = np.full(n_bodies, float(query.radius))
  n_segments = int(state.index.n_segments)
  return (query.frustum.normals, plane_offsets(query.frustum, radius),
          selection_mask(bank, query.bodies), window_units(bank, query.window, n_segments))


def combine(hits: np.ndarray, body_mask: np.ndarray, query: Query) -> np.ndarray:
  """Per-world answer from per-path hits bool[W, B] -> bool[W]."""
  if query.mode == "any":
    met = np.any(hits & body_mask, axis=1)
  else:
    met = np.all(hits | ~body_mask, axis=1)
  return met if query.include else ~met


def evaluate_each(bank, queries) -> np.ndarray:
  """Each query's answer for each world: bool[W, Q]; unstable worlds False."""
  queries = as_queries(queries)
  out = np.zeros((bank.n_worlds, len(queries)), bool)
  if bank.n_worlds == 0 or not queries:
    return out
  valid = np.asarray(bank.valid, bool)
  paths = [i for i, q in enumerate(queries) if isinstance(q, Query) and q.shape == "com"]
  for i, query in enumerate(queries):
    if isinstance(query, joint_lib.JointQuery):
      out[:, i] = joint_lib.evaluate_joint(bank, query)
    elif isinstance(query, orientation_lib.OrientationQuery):
      out[:, i] = orientation_lib.evaluate_orientation(bank, query, selection_mask(bank, query.bodies))
    elif query.shape == "geometry":
      mask = selection_mask(bank, query.bodies)
      hits = geometry_query.geometry_hits(geometry_lib.geometry_index(bank), query.frustum, mask,
                                          query.window)
      out[:, i] = combine(hits, mask, query) & valid
  if not paths:
    return out
  blocks = _blocks(bank, valid) if streams(bank) else [(slice(None), _state(bank))]
  for rows, state in blocks:
    for i in paths:
      query = queries[i]
      normals, offsets, mask, window = resolve(bank, query, state)
      hits = np.asarray(index_lib.path_hits(state.index, normals, offsets, mask, window))
      out[rows, i] = combine(hits, mask, query) & valid[rows]
  return out


def evaluate(bank, queries) -> np.ndarray:
  """Worlds that satisfy every query: bool[W] (no queries: all valid worlds)."""
  valid = np.asarray(bank.valid, bool)
  return np.all(evaluate_each(bank, queries), axis=1) & valid


def constraints_satisfied(bank, queries) -> np.ndarray:
  """How many of the queries each world satisfies: i32[W] (0 if unstable),
  the paper's ranking for when no world satisfies them all (§4.3)."""
  return np.sum(evaluate_each(bank, queries), axis=1, dtype=np.int32)


def first_entry(bank, world: int, bodies, frustum: Frustum, *,
                window=None, radius: float | str = 0.0) -> float | None:
  """Earliest time any of the bodies' COM (or swept sphere) is in the volume.

  Args:
    bank: the bank. world: world id.
    bodies: body/object/group names, or None for all tracked bodies.
    frustum: the volume (e.g. `camera.frustum(box)`).
    window: optional (t0, t1) seconds; entry is searched inside it.
    radius: swept-sphere radius in metres or "auto".

  Returns:
    seconds from the start of the world, or None if it never enters.
  """
  row = bank.row_of(int(world))
  query = Query(frustum, bodies=bodies, window=window, radius=radius)
  if streams(bank):  # index this one world
    state = _BankState(None, index_lib.build_index(bank.com[row:row + 1], np.ones(1, bool)))
    row = 0
  else:
    state = _state(bank)
  normals, offsets, mask, win = resolve(bank, query, state)
  chosen = np.flatnonzero(mask)
  if chosen.size == 0:
    return None
  points = state.index.points[chosen, row]  # [k, P', 3] padded paths
  with jax.enable_x64(True):
    t = _first_entry(points, normals, offsets[chosen], win, state.index.n_segments)
  t = float(t)
  return None if math.isinf(t) else t / float(bank.query_fps)


@jax.jit
def _first_entry(points, normals, offsets, window, n_segments):
  def one(p, off):
    hit, enter = segments.polyline_hits(p, normals, off, window, 0, n_segments)
    k = jp.arange(p.shape[0] - 1, dtype=jp.float64)
    return jp.min(jp.where(hit, k + enter, jp.inf))
  return jp.min(jax.vmap(one)(points, offsets))
