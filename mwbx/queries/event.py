"""Event queries: what touches what, and in which order.

They read a bank's contact events (:mod:`mwbx.events`: at every stored frame,
which actors touch) and never simulate. An **actor** is an object, a named
static geom (a floor, a bin), or ``world`` for the unnamed static geoms; a
group name stands for its objects ("any of a group").

* :class:`TouchQuery`: two sides touch (``include``) or never touch
  (``exclude``), inside an optional time window. A side is one name or a list
  (any of them).
* :class:`OrderQuery`: several touches, in order: each first happens
  (within the window) strictly after the one before it first happened.

Touches are known at every physics step (ticks: ``tick / (record_fps ·
ticks_per_frame)`` seconds; banks whose events were found on the stored
frames know them at the frames): a window holds the ticks whose times lie in
it, and past a world's last frame that frame holds (it came to rest), so a
touch on at the end goes on. ``impulse`` and ``force`` keep only the
episodes that hit that hard (the normal impulse, N·s, or the largest normal
force, N, MuJoCo's solver gave the contacts of the episode).

Example::

  hit = mwbx.TouchQuery("rock", "tower", window=(0.0, 2.0))
  chain = mwbx.OrderQuery([("ball", "domino_0"), ("domino_4", "lever"), ("lever", "cup")])
  mwbx.evaluate(bank, [hit, chain])
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Sequence

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.events.record import ROW, EventRecord
from mwbx.queries import paths
from mwbx.queries import selection
from mwbx.queries.intervals import checked_window
from mwbx.queries.query import Query
from mwbx.queries.query import unexpected_fields

Side = tuple[str, ...]  # actor, object or group names: any of them
FRAME_SLACK = 1e-9  # s: window ends compare with frame times exactly, less float noise
KNOWN_SHOWN = 20  # actor names an unknown-actor message lists


def _side(label: str, field: str, value) -> Side:
  names = (value,) if isinstance(value, str) else tuple(value)
  if not names or not all(isinstance(n, str) and n for n in names):
    raise MwbxError(f"{label}: {field} must be an actor name or a non-empty list of names, got {value!r}")
  return names


def _pair(label: str, field: str, pair) -> tuple[Side, Side]:
  if isinstance(pair, str) or len(pair) != 2:
    raise MwbxError(f"{label}: {field} must be two sides [A, B] (each a name or a list of names), got {pair!r}")
  return _side(label, field, pair[0]), _side(label, field, pair[1])


def actor_mask(bank, side: Side, label: str = "query") -> np.ndarray:
  """bool[A] the bank's actors a side names (objects, groups, static geoms)."""
  actors = tuple(bank.event_actors)
  mask = np.zeros(len(actors), bool)
  for name in side:
    if name in bank.groups:
      members = bank.groups[name]
    elif name.startswith("group:") and name[6:] in bank.groups:
      members = bank.groups[name[6:]]
    else:
      members = (name.split(":", 1)[1] if name.startswith("object:") else name,)
    for member in members:
      if member not in actors:
        known = actors + tuple(bank.groups)
        shown = ", ".join(known[:KNOWN_SHOWN]) + (f", ... ({len(known)} in all)" if len(known) > KNOWN_SHOWN else "")
        raise MwbxError(f"{label}: unknown actor {name!r} (objects, groups and named static geoms: {shown})")
      mask[actors.index(member)] = True
  return mask


def _events(bank, label: str):
  if bank.events is None:
    raise MwbxError(f"{label}: this bank has no contact events (it was saved before mwbx recorded them);"
                    f" sample it again to ask event queries")
  return bank.events


class _PairEpisodes(NamedTuple):
  """A pair of sides' episodes in a bank's record (:func:`_pair_episodes`).

  Attributes:
    record: the bank's EventRecord. pair: bool[N] its episodes between an
      actor of one side and one of the other.
    rate: ticks a second. lo, hi: the window's first and last tick (None: open).
  """

  record: EventRecord
  pair: np.ndarray
  rate: float
  lo: int | None
  hi: int | None


def _pair_episodes(bank, a: Side, b: Side, window, label: str) -> _PairEpisodes:
  """The episodes between sides ``a`` and ``b``, and the window in ticks."""
  window = checked_window(label, window)  # a time no tick holds fails here, in one line
  record = _events(bank, label)
  ma, mb = actor_mask(bank, a, label), actor_mask(bank, b, label)
  ra, rb = record.rows[:, ROW["a"]], record.rows[:, ROW["b"]]
  rate = float(bank.record_fps) * record.ticks_per_frame
  t0, t1 = (None, None) if window is None else window
  return _PairEpisodes(record, (ma[ra] & mb[rb]) | (mb[ra] & ma[rb]), rate,
                       None if t0 is None else math.ceil(t0 * rate - FRAME_SLACK * rate),
                       None if t1 is None else math.floor(t1 * rate + FRAME_SLACK * rate))


def _last_ticks(bank, record) -> np.ndarray:
  """i64[N] each episode's last tick; the largest int64 where it is on at its
  world's last frame (which holds after: it goes on)."""
  last = record.rows[:, ROW["last"]].astype(np.int64)
  ends = np.repeat(record.end_ticks(bank.frame_count), record.counts)
  return np.where(last >= ends, np.iinfo(np.int64).max, last)


def _hard_enough(label: str, record, impulse=None, force=None) -> np.ndarray | bool:
  """bool[N] the episodes whose impulse (N·s) and peak force (N) lie in the
  (lo, hi) ranges given (None ends open); True where none is given."""
  keep = True
  for what, bounds, values in (("impulse", impulse, record.impulse), ("force", force, record.peak_force)):
    if bounds is None:
      continue
    if len(values) and np.isnan(values).all():
      raise MwbxError(f"{label}: {what}: this bank's contact events were found on its stored frames and"
                      f" carry no contact forces; sample it again to ask how hard things hit")
    lo, hi = bounds
    inside = ~np.isnan(values)
    if lo is not None:
      inside &= values >= lo
    if hi is not None:
      inside &= values <= hi
    keep = keep & inside
  return keep


def _strength_range(label: str, field: str, value) -> tuple[float | None, float | None] | None:
  """(lo, hi) of a strength filter, each a finite number >= 0 or None (open)."""
  if value is None:
    return None
  if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
    raise MwbxError(f"{label}: {field} must be [lo, hi] (null for an open end), got {value!r}")
  out = []
  for end in value:
    if end is not None and (isinstance(end, bool) or not isinstance(end, (int, float)) or not math.isfinite(end)
                            or end < 0):
      raise MwbxError(f"{label}: {field} ends must be finite numbers >= 0 or null, got {value!r}")
    out.append(None if end is None else float(end))
  if out[0] is not None and out[1] is not None and out[0] > out[1]:
    raise MwbxError(f"{label}: {field} is empty: {out[0]:g} > {out[1]:g}")
  return out[0], out[1]


def first_touch(bank, a: Side, b: Side, window=None, label: str = "query", impulse=None,
                force=None) -> np.ndarray:
  """f64[W] the first time (a physics step's, or a stored frame's in banks
  found on frames) inside ``window`` at which sides ``a`` and ``b`` touch,
  seconds; inf where there is none. Past a world's last frame that frame
  holds (at the times that follow).

  Args:
    bank: a bank with contact events.
    a, b: the sides (names; any of each).
    window: (t0, t1) seconds, None ends open; None: the whole world.
    impulse, force: optional (lo, hi): only episodes whose normal impulse
      (N·s) or largest normal force (N) lie in it count.
  """
  e = _pair_episodes(bank, a, b, window, label)
  record, rows = e.record, e.record.rows
  out = np.full(bank.n_worlds, np.inf)
  if not len(rows):
    return out
  pair = e.pair & _hard_enough(label, record, impulse, force)
  first = rows[:, ROW["first"]].astype(np.int64)
  tick = first if e.lo is None else np.maximum(first, e.lo)
  inside = pair & (tick <= _last_ticks(bank, record))
  if e.hi is not None:
    inside &= tick <= e.hi
  # Each world's rows are contiguous: the least per world in one reduction.
  has = record.counts > 0
  out[has] = np.minimum.reduceat(np.where(inside, tick / e.rate, np.inf), record.offsets[:-1][has])
  return out


def hardest_hit(bank, a: Side, b: Side, window=None, label: str = "query", by: str = "impulse") -> np.ndarray:
  """f64[W] the hardest touch of sides ``a`` and ``b`` going on inside
  ``window``: the largest normal impulse of an episode, N·s (``by="force"``:
  the largest normal force, N); 0 where they never touch, NaN where the
  bank does not know (events found on stored frames)."""
  e = _pair_episodes(bank, a, b, window, label)
  record, rows, pair = e.record, e.record.rows, e.pair
  out = np.zeros(bank.n_worlds)
  if not len(rows):
    return out
  if e.lo is not None:
    pair = pair & (_last_ticks(bank, record) >= e.lo)
  if e.hi is not None:
    pair = pair & (rows[:, ROW["first"]] <= e.hi)
  values = np.asarray(record.impulse if by == "impulse" else record.peak_force, np.float64)
  world = record.world_of_rows()[pair]
  np.fmax.at(out, world, values[pair])  # NaN only where every touch is unknown
  unknown = np.zeros(bank.n_worlds, bool)
  np.logical_or.at(unknown, world, np.isnan(values[pair]))
  return np.where(unknown & (out == 0), np.nan, out)


def touch_seconds(bank, a: Side, b: Side, window=None, label: str = "query") -> np.ndarray:
  """f64[W] how long sides ``a`` and ``b`` touch inside ``window``, seconds
  (ticks touching / ticks a second; a touch on at a world's end counts to it)."""
  e = _pair_episodes(bank, a, b, window, label)
  record, rows = e.record, e.record.rows
  out = np.zeros(bank.n_worlds)
  if not len(rows):
    return out
  lo = rows[:, ROW["first"]].astype(np.float64)
  hi = rows[:, ROW["last"]].astype(np.float64) + 1
  if e.lo is not None:
    lo = np.maximum(lo, e.lo)
  if e.hi is not None:
    hi = np.minimum(hi, e.hi + 1)
  ticks = np.where(e.pair, np.maximum(hi - lo, 0.0), 0.0)
  np.add.at(out, record.world_of_rows(), ticks / e.rate)
  return out


def side_objects(owner, side: Side) -> list[str]:
  """The objects among a side's names (groups expanded; static geoms left out)."""
  out = []
  for name in side:
    bare = name.split(":", 1)[1] if name.startswith(("group:", "object:")) else name
    members = owner.groups.get(bare, (bare,)) if not name.startswith("object:") else (bare,)
    out.extend(m for m in members if m in owner.objects and m not in out)
  return out


def approach_gap(bank, a: Side, b: Side, window=None) -> np.ndarray:
  """f64[W], metres: how near the sides come inside the window: over the
  stored COM points of a side's objects, the least distance to the other
  side's objects (less both bounding radii) or static geoms (a plane's
  distance, else to its bounding sphere), less the object's bounding radius;
  >= 0. 0 where neither side has an object."""
  model = bank.model
  radii = paths.body_radii(model, np.asarray(bank.body_ids))
  com = np.asarray(bank.com[np.arange(bank.n_worlds)], np.float32)[:, paths.window_points(bank, window)]
  best = np.full(bank.n_worlds, np.inf)
  scenery = mujoco.MjData(model)  # the static geoms where the model puts them
  mujoco.mj_kinematics(model, scenery)
  for mine, other in ((a, b), (b, a)):
    objects = side_objects(bank, mine)
    if not objects:
      continue
    mask = selection.selection_mask(bank, objects)
    points = com[:, :, mask].astype(np.float64)  # [W, P, k, 3]
    reach = radii[mask]
    others = side_objects(bank, other)
    if others:
      omask = selection.selection_mask(bank, others)
      d = np.linalg.norm(points[:, :, :, None] - com[:, :, omask][:, :, None].astype(np.float64), axis=-1)
      d = d - reach[None, None, :, None] - radii[omask][None, None, None, :]
      best = np.minimum(best, d.reshape(bank.n_worlds, -1).min(axis=1))
    for geom in _static_geoms(bank, model, other):
      d = _geom_distance(model, scenery, geom, points) - reach[None, None, :]
      best = np.minimum(best, d.reshape(bank.n_worlds, -1).min(axis=1))
  return np.where(np.isfinite(best), np.maximum(best, 0.0), 0.0)


def _static_geoms(bank, model, side: Side) -> list[int]:
  """Ids of the static geoms a side names (``world``: every unnamed one)."""
  objects = set(side_objects(bank, side))
  out = []
  for name in side:
    if name in objects or name in bank.groups:
      continue
    if name == "world":
      out.extend(g for g in range(model.ngeom)
                 if not mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
                 and model.body(int(model.body_rootid[model.geom_bodyid[g]])).name not in bank.objects)
    else:
      g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
      if g >= 0:
        out.append(g)
  return out


def _geom_distance(model, data, geom: int, points: np.ndarray) -> np.ndarray:
  """f64[...] distance from points (f[..., 3], m) to a static geom at its
  pose in ``data`` (after ``mj_kinematics``): a plane's (its +z side), else
  to its bounding sphere (>= 0)."""
  centre = data.geom_xpos[geom]
  if int(model.geom_type[geom]) == int(mujoco.mjtGeom.mjGEOM_PLANE):
    normal = data.geom_xmat[geom].reshape(3, 3)[:, 2]
    return np.abs((points - centre) @ normal)
  return np.maximum(np.linalg.norm(points - centre, axis=-1) - float(model.geom_rbound[geom]), 0.0)


def _names(side: Side):
  return side[0] if len(side) == 1 else list(side)


def _say(side: Side) -> str:
  return side[0] if len(side) == 1 else "any of " + ",".join(side)


def _check_actors(context, sides, where: str) -> None:
  """MwbxError naming the file and entry: a bank without events, or an actor it does not know."""
  if context.bank is None:
    return
  _events(context.bank, f"{context.path}: {where}")
  for side in sides:
    try:
      actor_mask(context.bank, side)
    except MwbxError as err:
      raise MwbxError(f"{context.path}: {where}: {str(err).removeprefix('query: ')}") from None


@dataclasses.dataclass(frozen=True, eq=False)
class TouchQuery(Query):
  """Two sides touch (include) or never touch (exclude) inside a window.

  a, b: the sides: an actor (object, named static geom), a group, or a list
    of them (any of them).
  window: (t0, t1) seconds, None ends open; None: the whole world.
  sign: include (they touch) or exclude (they never touch).
  name: label for output.
  impulse: optional (lo, hi) N·s, None ends open: only touches whose normal
    impulse lies in it count (how hard: "the rock smashes into the tower").
  force: optional (lo, hi) N: the same for the touch's largest normal force.

  Example::

    smash = mwbx.TouchQuery("rock", "tower", impulse=(50.0, None))
  """

  a: Side
  b: Side
  window: tuple[float | None, float | None] | None = None
  sign: str = "include"
  name: str = ""
  impulse: tuple[float | None, float | None] | None = None
  force: tuple[float | None, float | None] | None = None
  bodies = None  # about actors, not tracked bodies: objects() and body_mask() say which
  needs_events = True
  error_metric = "hardest_hit"

  def check(self, bank) -> None:
    _events(bank, self.label)
    for side in (self.a, self.b):
      actor_mask(bank, side, self.label)

  def error(self, bank, reduce: str = "max", bodies=None) -> np.ndarray:
    """f64[W] its sides' hardest touch inside the window, N·s of normal
    impulse (:func:`hardest_hit`; rank it largest first: "the hardest hit
    between A and B"); ``reduce`` and ``bodies`` do not apply."""
    return hardest_hit(bank, self.a, self.b, self.window, self.label)

  def __post_init__(self):
    label = f"query {self.name!r}" if self.name else "query"
    object.__setattr__(self, "a", _side(label, "touch", self.a))
    object.__setattr__(self, "b", _side(label, "touch", self.b))
    object.__setattr__(self, "window", checked_window(label, self.window))
    if self.sign not in ("include", "exclude"):
      raise MwbxError(f"{label}: sign must be include or exclude, got {self.sign!r}")
    object.__setattr__(self, "impulse", _strength_range(label, "impulse", self.impulse))
    object.__setattr__(self, "force", _strength_range(label, "force", self.force))

  @property
  def label(self) -> str:
    return f"query {self.name!r}" if self.name else "query"

  def evaluate(self, bank) -> np.ndarray:
    touched = np.isfinite(first_touch(bank, self.a, self.b, self.window, self.label, self.impulse, self.force))
    return (touched if self.include else ~touched) & np.asarray(bank.valid, bool)

  def gap(self, bank) -> np.ndarray:
    """Include: how near the sides' objects come (metres, :func:`approach_gap`),
    and where they touch but not as hard as ``impulse`` or ``force`` ask,
    the fraction of the bound the hardest touch misses by (0 to 1);
    exclude: how long they touch (seconds)."""
    if not self.include:
      return touch_seconds(bank, self.a, self.b, self.window, self.label)
    touched = np.isfinite(first_touch(bank, self.a, self.b, self.window, self.label))
    # Touching is no distance away, whatever the stored frames show of it.
    gap = np.where(touched, 0.0, approach_gap(bank, self.a, self.b, self.window))
    for by, bounds in (("impulse", self.impulse), ("force", self.force)):
      if bounds is None:
        continue
      lo, hi = bounds
      hit = np.nan_to_num(hardest_hit(bank, self.a, self.b, self.window, self.label, by))
      short = np.zeros(bank.n_worlds)
      if lo:
        short = np.maximum(short, (lo - hit) / lo)
      if hi is not None:
        short = np.maximum(short, (hit - hi) / max(hi, 1e-12))
      gap = np.where(touched, gap + np.clip(short, 0.0, 1.0), gap)
    return gap

  def objects(self, owner) -> list[str]:
    return side_objects(owner, self.a + self.b)

  def body_mask(self, bank) -> np.ndarray:
    objects = self.objects(bank)
    return selection.selection_mask(bank, objects) if objects else np.zeros(len(bank.body_names), bool)

  def describe(self) -> str:
    verb = "touches" if self.include else "never touches"
    hard = "".join(f" with {what} {_say_range(r, unit)}" for what, r, unit in
                   (("impulse", self.impulse, "N·s"), ("force", self.force, "N")) if r is not None)
    return f"{_say(self.a)} {verb} {_say(self.b)}{hard}"

  def to_dict(self) -> dict:
    out: dict = {"name": self.name, "touch": [_names(self.a), _names(self.b)], "sign": self.sign}
    for field in ("window", "impulse", "force"):
      if getattr(self, field) is not None:
        out[field] = list(getattr(self, field))
    return out

  @classmethod
  def claims(cls, entry) -> bool:
    return entry.touch is not None

  @classmethod
  def from_entry(cls, entry, index: int, context) -> TouchQuery:
    where = f"queries[{index}]"
    _refuse_others(entry, where, context, "touch", ("touch", "sign", "window", "impulse", "force", "name"))
    try:
      a, b = _pair(f"{context.path}: {where}", "touch", entry.touch)
      query = cls(a, b, entry.window, entry.sign, entry.name or f"q{index}", entry.impulse, entry.force)
    except MwbxError as err:
      raise MwbxError(str(err) if str(err).startswith(context.path) else f"{context.path}: {where}: {err}") from None
    _check_actors(context, (query.a, query.b), where)
    return query


@dataclasses.dataclass(frozen=True, eq=False)
class OrderQuery(Query):
  """Touches in order: each pair first touches (inside the window) strictly
  after the pair before it first touched.

  events: two or more (a, b) pairs of sides (as :class:`TouchQuery`'s).
  window: (t0, t1) seconds every touch must happen in; None: the whole world.
  name: label for output.
  """

  events: tuple[tuple[Side, Side], ...]
  window: tuple[float | None, float | None] | None = None
  name: str = ""
  sign = "include"
  bodies = None  # about actors, not tracked bodies: objects() and body_mask() say which
  needs_events = True

  def check(self, bank) -> None:
    _events(bank, self.label)
    for pair in self.events:
      for side in pair:
        actor_mask(bank, side, self.label)

  def __post_init__(self):
    label = f"query {self.name!r}" if self.name else "query"
    events = tuple(_pair(label, f"then[{i}]", pair) for i, pair in enumerate(self.events))
    if len(events) < 2:
      raise MwbxError(f"{label}: then needs at least two touches in order, got {len(events)}")
    object.__setattr__(self, "events", events)
    object.__setattr__(self, "window", checked_window(label, self.window))

  @property
  def label(self) -> str:
    return f"query {self.name!r}" if self.name else "query"

  def times(self, bank) -> np.ndarray:
    """f64[W, E] each touch's first time inside the window, seconds (inf: never)."""
    return np.stack([first_touch(bank, a, b, self.window, self.label) for a, b in self.events], axis=1)

  def evaluate(self, bank) -> np.ndarray:
    t = self.times(bank)
    met = np.all(np.isfinite(t), axis=1) & np.all(t[:, 1:] > t[:, :-1], axis=1)
    return met & np.asarray(bank.valid, bool)

  def gap(self, bank) -> np.ndarray:
    """Per touch that never happens, how near its objects come (metres); per
    touch that comes no later than the one before, by how much (seconds, plus
    one tick: a physics step, or a frame in banks found on frames)."""
    t = self.times(bank)
    gap = np.zeros(bank.n_worlds)
    for i, (a, b) in enumerate(self.events):
      missing = ~np.isfinite(t[:, i])
      if missing.any():
        gap = gap + np.where(missing, approach_gap(bank, a, b, self.window), 0.0)
    tick = 1.0 / (float(bank.record_fps) * _events(bank, self.label).ticks_per_frame)  # strictly later: a step
    both = np.isfinite(t[:, 1:]) & np.isfinite(t[:, :-1])
    ahead = np.subtract(t[:, :-1], t[:, 1:], out=np.zeros_like(t[:, 1:]), where=both)  # no inf - inf
    late = np.where(both, np.maximum(ahead + tick, 0.0), 0.0)
    return gap + late.sum(axis=1)

  def objects(self, owner) -> list[str]:
    return side_objects(owner, tuple(n for a, b in self.events for n in a + b))

  def body_mask(self, bank) -> np.ndarray:
    objects = self.objects(bank)
    return selection.selection_mask(bank, objects) if objects else np.zeros(len(bank.body_names), bool)

  def describe(self) -> str:
    return " then ".join(f"{_say(a)} touches {_say(b)}" for a, b in self.events)

  def to_dict(self) -> dict:
    out: dict = {"name": self.name, "then": [[_names(a), _names(b)] for a, b in self.events]}
    if self.window is not None:
      out["window"] = list(self.window)
    return out

  @classmethod
  def claims(cls, entry) -> bool:
    return entry.then is not None

  @classmethod
  def from_entry(cls, entry, index: int, context) -> OrderQuery:
    where = f"queries[{index}]"
    _refuse_others(entry, where, context, "then", ("then", "window", "name"))
    try:
      query = cls(tuple(entry.then), entry.window, entry.name or f"q{index}")
    except MwbxError as err:
      raise MwbxError(f"{context.path}: {where}: {str(err).removeprefix('query: ')}") from None
    _check_actors(context, [side for pair in query.events for side in pair], where)
    return query


def _say_range(bounds, unit: str) -> str:
  lo, hi = bounds
  if hi is None:
    return f">= {lo:g} {unit}"
  if lo is None:
    return f"<= {hi:g} {unit}"
  return f"{lo:g}–{hi:g} {unit}"


def _refuse_others(entry, where: str, context, kind: str, takes: Sequence[str]) -> None:
  """MwbxError naming the fields an event entry does not take."""
  extra = unexpected_fields(entry, takes)
  if extra:
    raise MwbxError(f"{context.path}: {where}: a '{kind}' query takes {', '.join(takes)}, not {', '.join(extra)}")
