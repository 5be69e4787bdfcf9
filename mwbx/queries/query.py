"""Queries: the one interface every query type implements, and the paper's volume query.

:class:`Query` is one constraint on worlds. Volume queries (:class:`VolumeQuery`,
below), joint queries (:class:`~mwbx.queries.joint.JointQuery`) and
orientation queries (:class:`~mwbx.queries.orientation.OrientationQuery`)
derive from it, and every caller (evaluation, gaps for ``solve``, query
files, the page, the viewer, the search) goes through it: a new query type is
a new class plus a line in :data:`mwbx.queries.query_file.QUERY_KINDS`, never
a switch in a caller.

A VolumeQuery (``mwbx.VolumeQuery(frustum, ...)``, ``Query.screen`` and
``Query.region`` build one) is a volume (usually a screen box seen through a camera), a sign
(`include`: the path must pass through it; `exclude`: it must not), a
selection of tracked bodies (body, object or group names) combined with
`any` or `all`, an optional time window in seconds and an optional swept
sphere radius; or, with ``shape="geometry"``, about any point of the bodies'
geoms instead of their COM (:mod:`.geometry`). A list of queries is their
conjunction. Unstable worlds never match anything.

Per world, with `hit[b]` = "body b's path meets the volume in the window":
  include/any: some selected body hits;  include/all: every selected body hits
  exclude/any: no selected body hits;    exclude/all: not every selected one
(an empty selection: include/any and exclude/all never match, the other two
always do).

Example::

  q = mwbx.Query.screen(camera, [0.1, 0.2, 0.3, 0.4], bodies="ball")  # a VolumeQuery
  isinstance(q, mwbx.Query), q.describe()   # (True, "include ball")
  q.evaluate(bank)                          # bool[W]
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import ClassVar, NamedTuple, Sequence

import numpy as np

from mwbx.errors import MwbxError
from mwbx.queries import geometry as geometry_lib
from mwbx.queries import geometry_query
from mwbx.queries import index as index_lib
from mwbx.queries import paths
from mwbx.queries import selection
from mwbx.queries.camera import Camera
from mwbx.queries.camera import MAX_COORDINATE
from mwbx.queries.camera import ScreenBox
from mwbx.queries.frustum import Frustum
from mwbx.queries.intervals import checked_window

SIGNS = ("include", "exclude")
MODES = ("any", "all")
SHAPES = ("com", "geometry")


class Query(abc.ABC):
  """One constraint on worlds (the interface; concrete types derive from it).

  An abstract base: it is never built itself. ``Query.screen`` and
  ``Query.region`` are named constructors of the concrete type most people
  mean, a :class:`VolumeQuery` (the paper's query); ``VolumeQuery(frustum,
  ...)`` builds one from a frustum.

  Attributes every query has:
    name: label for output (query files name an unnamed one ``q<i>``).
    sign: ``include`` (the world must meet it) or ``exclude`` (must not).
    bodies: tracked body, object or group names its answer is about (None:
      every tracked body, or none for a query not about bodies).
    window: (t0, t1) seconds, None ends open; None: the whole world.
    frustum: the volume a viewer draws for it (a
      :class:`~mwbx.queries.frustum.Frustum` with corners), or None.
    goal: ``place`` (decided by where bodies go: volumes, joints) or
      ``pose`` (decided by how they come to rest turned); a search ranks and
      repairs places first.
    until_rest: met only if its bodies stay where they end up, not only by
      the path there (an include volume): a search restarts for it no
      earlier than they settle.
    error_metric: the name of a per-world error it can rank by
      (:meth:`error`, smallest first), or None.
    needs_events: answered from the bank's contact events (event queries).
  """

  name: str = ""
  sign: str = "include"
  bodies: tuple[str, ...] | None = None
  window: tuple[float | None, float | None] | None = None
  frustum = None
  goal: ClassVar[str] = "place"
  error_metric: ClassVar[str | None] = None
  needs_events: ClassVar[bool] = False  # answered from the bank's contact events

  @classmethod
  def screen(cls, camera, box, *, near: float | None = None, far: float | None = None, **fields):
    """A :class:`VolumeQuery` from a screen box [u0, v0, u1, v1] seen through a camera."""
    return VolumeQuery.screen(camera, box, near=near, far=far, **fields)

  @classmethod
  def region(cls, lo, hi, **fields):
    """A :class:`VolumeQuery` on an axis-aligned world box [lo, hi], metres."""
    return VolumeQuery.region(lo, hi, **fields)

  @property
  def include(self) -> bool:
    """Whether a world must meet it (``sign == "include"``)."""
    return self.sign == "include"

  @property
  def until_rest(self) -> bool:
    return False

  # -- answers ---------------------------------------------------------------------

  def check(self, bank) -> None:
    """MwbxError naming what the bank does not know (a body, object, group,
    joint or actor name), before any answer is asked for."""
    if self.bodies:
      bank.select_bodies(list(self.bodies))

  @abc.abstractmethod
  def evaluate(self, bank) -> np.ndarray:
    """bool[W] worlds meeting it (unstable worlds: False)."""

  @classmethod
  def evaluate_many(cls, bank, queries: Sequence["Query"]) -> np.ndarray:
    """bool[W, k] answers of several queries of this type: one pass where a
    type shares work between its queries (volume queries share one bounds
    hierarchy and one read of each shard); by default each on its own."""
    out = np.zeros((bank.n_worlds, len(queries)), bool)
    for i, query in enumerate(queries):
      out[:, i] = query.evaluate(bank)
    return out

  @abc.abstractmethod
  def gap(self, bank) -> np.ndarray:
    """f64[W] how far each world is from meeting it, ungated (>= 0; metres
    for volumes, radians or metres for joints, radians for orientations):
    :func:`mwbx.queries.query_gaps` makes it exactly 0 where met."""

  @classmethod
  def gap_many(cls, bank, queries: Sequence["Query"]) -> np.ndarray:
    """f64[W, k] the gaps of several queries of this type (one read of the
    bank where a type shares it, as :meth:`evaluate_many`); by default each on its own."""
    out = np.zeros((bank.n_worlds, len(queries)))
    for i, query in enumerate(queries):
      out[:, i] = query.gap(bank)
    return out

  def error(self, bank, reduce: str = "max", bodies=None) -> np.ndarray:
    """f64[W] the per-world error named by :attr:`error_metric` (rank smallest
    first), combined over its bodies (or ``bodies``) by ``max`` or ``sum``."""
    raise MwbxError(f"query {self.name!r}: {type(self).__name__} has no error to rank by")

  # -- what it is about --------------------------------------------------------------

  def objects(self, owner) -> list[str]:
    """Objects whose motion decides it, in the owner's order.

    Args:
      owner: a :class:`~mwbx.Bank` or :class:`~mwbx.Scene` (its tracked
        bodies, objects, groups and model).
    """
    if self.bodies is None:
      return list(owner.objects)
    chosen = set(selection.chosen_bodies(owner, self.bodies))
    return [obj for obj, bodies in owner.objects.items() if chosen & set(bodies)]

  def body_mask(self, bank) -> np.ndarray:
    """bool[B] the tracked bodies whose motion decides it (its ``bodies``)."""
    return selection.selection_mask(bank, self.bodies)

  def per_object(self, owner) -> dict[str, "Query"]:
    """{object: this query as that object alone would meet it} for a query
    that any one of several objects may meet (an include volume over ``any``
    body); {} for every other query."""
    return {}

  def deadline(self, bank, world: int) -> float:
    """Seconds by which its objects must be right in world ``world``: its
    window's start (else its end, else the world's end)."""
    end = _world_end(bank, world)
    window = self.window or (None, None)
    t = window[0] if window[0] is not None else window[1]
    return min(end, t) if t is not None else end

  # -- for people and files ----------------------------------------------------------

  @abc.abstractmethod
  def describe(self) -> str:
    """One line for people, e.g. ``include ball (geometry)``."""

  @abc.abstractmethod
  def to_dict(self) -> dict:
    """Its entry in a query file (:mod:`mwbx.queries.query_file`); read back
    by the type's :meth:`from_entry`."""

  @classmethod
  @abc.abstractmethod
  def claims(cls, entry) -> bool:
    """Whether a query-file entry (a parsed ``queries[i]``) is of this type."""

  @classmethod
  @abc.abstractmethod
  def from_entry(cls, entry, index: int, context) -> "Query":
    """The query of a query-file entry.

    Args:
      entry: the parsed entry (``mwbx.queries.query_file`` validates its fields).
      index: its place in the file's ``queries`` (``queries[i]`` in messages).
      context: the file's :class:`~mwbx.queries.query_file.FileContext`
        (its path, default camera, model and bank).

    Raises:
      MwbxError: naming the file, ``queries[i]`` and the field at fault.
    """


def who(query: Query) -> str:
  """The bodies a query names, for :meth:`Query.describe` (``any body`` for all)."""
  return ",".join(query.bodies) if query.bodies else "any body"


@dataclasses.dataclass(frozen=True, eq=False)
class VolumeQuery(Query):
  """One spatial constraint on worlds: bodies through (or not through) a volume.

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
      object.__setattr__(self, "window", checked_window(label, self.window))
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
  def until_rest(self) -> bool:
    return self.include  # an include volume holds where its bodies end up, not only on the way

  @classmethod
  def screen(cls, camera: Camera, box: ScreenBox | Sequence[float], *,
             near: float | None = None, far: float | None = None, **fields) -> VolumeQuery:
    """A query from a screen box [u0, v0, u1, v1] seen through a camera."""
    if not isinstance(box, ScreenBox):
      box = ScreenBox(*box)
    return cls(camera.frustum(box, near, far), camera=camera, box=box, near=near, far=far, **fields)

  @classmethod
  def region(cls, lo, hi, **fields) -> VolumeQuery:
    """A query on an axis-aligned world box [lo, hi], metres."""
    return cls(Frustum.box(lo, hi), world_box=(tuple(float(x) for x in lo), tuple(float(x) for x in hi)),
               **fields)

  # -- the Query interface -----------------------------------------------------------

  def evaluate(self, bank) -> np.ndarray:
    return self.evaluate_many(bank, [self])[:, 0]

  @classmethod
  def evaluate_many(cls, bank, queries) -> np.ndarray:
    """bool[W, k]: COM queries share one bounds hierarchy (and, for a bank
    streamed from disk, one read of each shard); geometry queries one
    geometry index."""
    out = np.zeros((bank.n_worlds, len(queries)), bool)
    if bank.n_worlds == 0 or not queries:
      return out
    valid = np.asarray(bank.valid, bool)
    com_queries = [i for i, q in enumerate(queries) if q.shape == "com"]
    for i, query in enumerate(queries):
      if query.shape == "geometry":
        mask = selection.selection_mask(bank, query.bodies)
        hits = geometry_query.geometry_hits(geometry_lib.geometry_index(bank), query.frustum, mask,
                                            query.window)
        out[:, i] = paths.combine(hits, mask, query) & valid
    if not com_queries:
      return out
    if paths.answered_from_boxes(bank):
      answers = paths.box_answers(bank, [queries[i] for i in com_queries], valid)
      if answers is not None:  # (None: the boxes left most worlds open; the bank is indexed whole below)
        out[:, com_queries] = answers
        return out
    blocks = paths.blocks(bank, valid) if paths.streams(bank) else [(slice(None), paths.bank_state(bank))]
    for rows, state in blocks:
      for i in com_queries:
        query = queries[i]
        normals, offsets, mask, window = paths.resolve(bank, query, int(state.index.n_segments))
        hits = np.asarray(index_lib.path_hits(state.index, normals, offsets, mask, window))
        out[rows, i] = paths.combine(hits, mask, query) & valid[rows]
    return out

  def gap(self, bank) -> np.ndarray:
    """f64[W], metres: an include query, how far the selected bodies' stored
    COM points in the window stay outside the volume (for a point, the
    largest signed distance to the volume's planes, swept radius included;
    over the window the closest point; over the bodies the closest (``any``)
    or the farthest (``all``)); an exclude query, how deep the offending
    bodies go inside (the deepest point; ``any``: the deepest body, ``all``:
    the shallowest). A whole-geometry query is graded on the COM points swept
    by each body's bounding sphere (the geometry lies in it, so the measure
    points the same way)."""
    return self.gap_many(bank, [self])[:, 0]

  @classmethod
  def gap_many(cls, bank, queries) -> np.ndarray:
    """f64[W, k]: the bank's COM polylines are read once for all of them."""
    com = np.asarray(bank.com[np.arange(bank.n_worlds)], np.float32)
    return np.stack([q._gap(bank, com) for q in queries], axis=1) if queries else np.zeros((bank.n_worlds, 0))

  def _gap(self, bank, com: np.ndarray) -> np.ndarray:
    """:meth:`gap` on the bank's COM polylines ``com`` f32[W, P, B, 3]."""
    mask = selection.selection_mask(bank, self.bodies)
    if not mask.any():
      return np.full(bank.n_worlds, np.inf if self.include else 0.0)
    if self.radius == "auto" or self.shape == "geometry":
      radius = paths.body_radii(bank.model, np.asarray(bank.body_ids)[mask])
    else:
      radius = np.full(int(mask.sum()), float(self.radius))
    points = com[:, paths.window_points(bank, self.window)][:, :, mask]  # [W, P, b, 3]
    # Outside distance per point: the largest plane distance, sphere pushed out.
    d = self.frustum.distances(points).max(axis=-1) - radius[None, None, :]  # [W, P, b]
    if self.include:
      per_body = np.maximum(d.min(axis=1), 0.0)
      return per_body.min(axis=1) if self.mode == "any" else per_body.max(axis=1)
    depth = np.maximum(-d.min(axis=1), 0.0)  # the deepest point inside
    return depth.max(axis=1) if self.mode == "any" else depth.min(axis=1)

  def per_object(self, owner) -> dict[str, Query]:
    """A ``mode: any`` include query over several objects, as each object
    alone would meet it: {object: the query on that object's bodies only};
    {} otherwise (an exclude query is met by each object that keeps out, so
    no one object holds it).

    Example::

      g_in_slot_2.per_object(bank)  # {'letter_G1': <query on letter_G1>, 'letter_G2': <query on letter_G2>}
    """
    if not self.include or self.mode != "any" or self.bodies is None:
      return {}
    chosen = selection.chosen_bodies(owner, self.bodies)
    per_object = {obj: tuple(f"body:{b}" for b in chosen if b in bodies) for obj, bodies in owner.objects.items()}
    per_object = {obj: bodies for obj, bodies in per_object.items() if bodies}
    if len(per_object) < 2:
      return {}
    return {obj: dataclasses.replace(self, bodies=bodies, name=f"{self.name or 'query'} [{obj}]")
            for obj, bodies in per_object.items()}

  def deadline(self, bank, world: int) -> float:
    """An include query's window start (else the world's end); an exclude
    query's first entry (a whole-geometry one's: its bounding sphere's, no later)."""
    if self.include:
      return super().deadline(bank, world)
    end = _world_end(bank, world)
    radius = "auto" if self.shape == "geometry" else self.radius
    t = paths.first_entry(bank, world, self.bodies, self.frustum, window=self.window, radius=radius)
    return end if t is None else t

  def describe(self) -> str:
    return f"{self.sign} {who(self)}" + (" (geometry)" if self.shape == "geometry" else "")

  def to_dict(self) -> dict:
    out: dict = {"name": self.name}
    if self.box is not None and self.camera is not None:
      out["box"] = [float(self.box.u0), float(self.box.v0), float(self.box.u1), float(self.box.v1)]
      out["camera"] = self.camera.to_dict()
      if self.near is not None:
        out["near"] = float(self.near)
      if self.far is not None:
        out["far"] = float(self.far)
    elif self.world_box is not None:
      out["region"] = {"min": list(self.world_box[0]), "max": list(self.world_box[1])}
    else:
      raise MwbxError("a query built from raw planes cannot be saved (build it with Query.screen or Query.region)")
    out["sign"] = self.sign
    if self.bodies is not None:
      out["bodies"] = list(self.bodies)
    out["mode"] = self.mode
    if self.window is not None:
      out["window"] = list(self.window)
    out["radius"] = self.radius
    if self.shape != "com":
      out["shape"] = self.shape
    return out

  @classmethod
  def claims(cls, entry) -> bool:
    return True  # the query file's default kind: what is not another kind is a volume

  @classmethod
  def from_entry(cls, entry, index: int, context) -> VolumeQuery:
    where = f"queries[{index}]"
    if (entry.box is None) == (entry.region is None):
      raise MwbxError(f"{context.path}: {where}: give exactly one of 'box' (screen) or 'region' (world)")
    fields = dict(bodies=entry.bodies, sign=entry.sign, mode=entry.mode, window=entry.window,
                  radius=entry.radius, name=entry.name or f"q{index}",
                  shape=entry.shape)
    try:
      if entry.box is not None:
        camera = context.default_camera if entry.camera is None else context.camera(entry.camera, f"{where}.camera")
        if camera is None:
          raise MwbxError("a screen box needs a camera (top-level 'camera' or the query's own)")
        query = cls.screen(camera, ScreenBox(*entry.box), near=entry.near, far=entry.far, **fields)
      else:
        if entry.near is not None or entry.far is not None or entry.camera is not None:
          raise MwbxError("'near', 'far' and 'camera' apply to screen boxes, not to a region")
        query = cls.region(entry.region.lo, entry.region.hi, **fields)
    except MwbxError as err:
      if str(err).startswith(context.path):
        raise
      raise MwbxError(f"{context.path}: {where}: {err}") from None
    context.check_bodies(query.bodies, where)
    return query


def unexpected_fields(entry, takes) -> list[str]:
  """The fields of a query-file entry (``mwbx.queries.query_file``) set to
  other than their defaults that are not among ``takes``, in the file
  format's order: what a query type names when it refuses them."""
  defaults = type(entry).model_fields
  return [field for field, value in entry if field not in takes and value != defaults[field].default]


def _world_end(bank, world: int) -> float:
  """Seconds of a world's last recorded frame."""
  return (int(bank.frame_count[bank.row_of(world)]) - 1) / bank.record_fps


def columns_by_type(queries) -> dict[type, list[int]]:
  """{query type: the indices of its queries}, in order: what one type answers together."""
  out: dict[type, list[int]] = {}
  for i, query in enumerate(queries):
    out.setdefault(type(query), []).append(i)
  return out


def as_queries(queries) -> tuple:
  """A query, a sequence of them or an object with `.queries` (a QuerySet) -> tuple."""
  if isinstance(queries, Query):
    return (queries,)
  queries = getattr(queries, "queries", queries)
  out = tuple(queries)
  for i, q in enumerate(out):
    if not isinstance(q, Query):
      raise MwbxError(f"queries[{i}]: expected a query (mwbx.Query: a volume, joint or orientation query), "
                      f"got {type(q).__name__}")
  return out


def evaluate_each(bank, queries) -> np.ndarray:
  """Each query's answer for each world: bool[W, Q]; unstable worlds False.

  Queries of one type are answered together (:meth:`Query.evaluate_many`).
  """
  queries = as_queries(queries)
  out = np.zeros((bank.n_worlds, len(queries)), bool)
  if bank.n_worlds == 0 or not queries:
    return out
  for kind, columns in columns_by_type(queries).items():
    out[:, columns] = kind.evaluate_many(bank, [queries[i] for i in columns])
  return out


class Kept(NamedTuple):
  """Which worlds a set of queries keeps (:func:`kept`).

  Attributes:
    match: bool[W] valid worlds that satisfy every query.
    rejected: bool[W] valid worlds an exclude query turns away.
  """

  match: np.ndarray
  rejected: np.ndarray


def kept(each: np.ndarray, include: np.ndarray, valid: np.ndarray) -> Kept:
  """The one rule for which worlds match and which are rejected, from the
  answers of Q queries: ``each`` bool[W, Q] (:func:`evaluate_each`),
  ``include`` bool[Q] each query's sign, ``valid`` bool[W] (no queries: every
  valid world matches). Evaluation, the page and the viewer all use it.

  Example::

    k = kept(evaluate_each(bank, qs), np.array([q.include for q in qs]), bank.valid)
  """
  each, valid = np.asarray(each, bool), np.asarray(valid, bool)
  exclude = ~np.asarray(include, bool).reshape(-1)
  rejected = np.any(~each[:, exclude], axis=1) if exclude.any() else np.zeros(len(valid), bool)
  return Kept(np.all(each, axis=1) & valid, rejected & valid)


def evaluate(bank, queries) -> np.ndarray:
  """Worlds that satisfy every query: bool[W] (no queries: all valid worlds)."""
  queries = as_queries(queries)
  return kept(evaluate_each(bank, queries), np.array([q.include for q in queries], bool), bank.valid).match


def constraints_satisfied(bank, queries) -> np.ndarray:
  """How many of the queries each world satisfies: i32[W] (0 if unstable),
  the paper's ranking for when no world satisfies them all (§4.3)."""
  return np.sum(evaluate_each(bank, queries), axis=1, dtype=np.int32)
