"""Orientation queries: a body ends (or stays, over a window) within an angle
of an orientation.

Two kinds of goal:

* **upright**: a body axis (body frame, e.g. ``"z"`` or ``[0, 0, 1]``) points
  within ``within_deg`` of a world direction ``up`` (default +z). Two upright
  queries on two axes of one body fix its orientation ("upright, facing the
  viewer": ``axis: z, up: z`` and ``axis: -y, up: -y``);
* **target**: the body's rotation is within ``within_deg`` of a quaternion
  ``(w, x, y, z)``, or of its own orientation at the start of the world
  (``target="initial"``).

Without a window the query asks about each world's last stored frame (where
it came to rest); with a window, about every stored frame in it (past a
world's end its last frame holds). The error is the angle in radians (the
axis' angle to ``up``, or the rotation angle to the target), from forward
kinematics on the decoded stored qpos: the codec's rotation bound ``e_rot``
(and its chain's bounds for articulated bodies) is the difference to the
simulation. Bodies, ``mode`` (any/all) and ``sign`` (include/exclude) combine
as in :class:`~mwbx.Query`.

Example::

  q = mwbx.OrientationQuery(bodies="S", axis="z", within_deg=15)   # ends upright
  mwbx.evaluate(bank, [q, in_slot])
  mwbx.rank(bank, mwbx.orientation_error(bank, q), descending=False)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mwbx.errors import MwbxError
from mwbx.joints import QPOS_WIDTH
from mwbx.queries import poses as poses_lib
from mwbx.queries.bank_cache import PerBank
from mwbx.queries.query import Query
from mwbx.queries.query import unexpected_fields
from mwbx.queries.query import who
from mwbx.queries.intervals import checked_window
from mwbx.queries.selection import turning_mask

AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
BLOCK = 128  # worlds decoded at once


def direction(label: str, field: str, value) -> tuple[float, float, float]:
  """``"z"``, ``"-x"``, ... or three numbers -> a unit 3-vector."""
  if isinstance(value, str):
    name = value.strip().lower()
    sign = -1.0 if name.startswith("-") else 1.0
    if name.lstrip("+-") not in AXES:
      raise MwbxError(f"{label}: {field} must be x, y, z (optionally signed) or [x, y, z], got {value!r}")
    return tuple(sign * c for c in AXES[name.lstrip("+-")])
  try:
    v = np.asarray(value, np.float64).reshape(3)
  except (TypeError, ValueError):
    raise MwbxError(f"{label}: {field} must be x, y, z (optionally signed) or [x, y, z], got {value!r}") from None
  norm = float(np.linalg.norm(v))
  if not (math.isfinite(norm) and norm > 0):
    raise MwbxError(f"{label}: {field} must be a finite nonzero direction, got {value!r}")
  return tuple(float(c) for c in v / norm)


@dataclasses.dataclass(frozen=True, eq=False)
class OrientationQuery(Query):
  """Bodies end (or stay over a window) within an angle of an orientation.

  bodies: tracked body, object or group names (None: every tracked body).
  axis: a body-frame axis that should point along ``up`` (upright), or None.
  up: the world direction for ``axis``, default +z.
  target: (w, x, y, z) quaternion or ``"initial"`` (the body's orientation at
    the world's start), when ``axis`` is None.
  within_deg: the angle, degrees, 0 <= within_deg <= 180.
  window: None: at each world's last stored frame; (t0, t1) seconds: at every
    stored frame in it (None ends open).
  sign: include (within) or exclude (not within). mode: any or all bodies.
  name: label for output.
  """

  bodies: tuple[str, ...] | None = None
  axis: tuple[float, float, float] | None = None
  up: tuple[float, float, float] = (0.0, 0.0, 1.0)
  target: tuple[float, float, float, float] | str | None = None
  within_deg: float = 10.0
  window: tuple[float | None, float | None] | None = None
  sign: str = "include"
  mode: str = "any"
  name: str = ""
  goal = "pose"  # decided by how the bodies come to rest turned
  error_metric = "orientation_error"

  def __post_init__(self):
    label = f"query {self.name!r}" if self.name else "query"
    if isinstance(self.bodies, str):
      object.__setattr__(self, "bodies", (self.bodies,))
    elif self.bodies is not None:
      object.__setattr__(self, "bodies", tuple(str(b) for b in self.bodies))
    if (self.axis is None) == (self.target is None):
      raise MwbxError(f"{label}: give exactly one of axis (upright) or target (a quaternion or 'initial')")
    if self.axis is not None:
      object.__setattr__(self, "axis", direction(label, "axis", self.axis))
    object.__setattr__(self, "up", direction(label, "up", self.up))
    if self.target is not None and not (isinstance(self.target, str) and self.target == "initial"):
      try:
        t = np.asarray(self.target, np.float64).reshape(4)
      except (TypeError, ValueError):
        raise MwbxError(f"{label}: target must be [w, x, y, z] or 'initial', got {self.target!r}") from None
      norm = float(np.linalg.norm(t))
      if not (math.isfinite(norm) and norm > 0):
        raise MwbxError(f"{label}: target must be a finite nonzero quaternion, got {self.target!r}")
      object.__setattr__(self, "target", tuple(float(c) for c in t / norm))
    try:
      within = float(self.within_deg)
    except (TypeError, ValueError):
      within = float("nan")
    if not (0.0 <= within <= 180.0):
      raise MwbxError(f"{label}: within_deg must be an angle in [0, 180] degrees, got {self.within_deg!r}")
    object.__setattr__(self, "within_deg", within)
    if self.window is not None:
      object.__setattr__(self, "window", checked_window(label, self.window))
    if self.sign not in ("include", "exclude"):
      raise MwbxError(f"{label}: sign must be include or exclude, got {self.sign!r}")
    if self.mode not in ("any", "all"):
      raise MwbxError(f"{label}: mode must be any or all, got {self.mode!r}")

  @property
  def within(self) -> float:
    """The angle in radians."""
    return math.radians(self.within_deg)

  # -- the Query interface -----------------------------------------------------------

  def check(self, bank) -> None:
    super().check(bank)
    _mask(bank, self)

  def evaluate(self, bank) -> np.ndarray:
    return evaluate_orientation(bank, self, _mask(bank, self))

  @classmethod
  def evaluate_many(cls, bank, queries) -> np.ndarray:
    """bool[W, k]: the bodies of all ``queries`` decoded in one pass."""
    _decode_together(bank, queries)
    return super().evaluate_many(bank, queries)

  def gap(self, bank) -> np.ndarray:
    return orientation_gap(bank, self, _mask(bank, self))

  @classmethod
  def gap_many(cls, bank, queries) -> np.ndarray:
    """f64[W, k]: the bodies of all ``queries`` decoded in one pass."""
    _decode_together(bank, queries)
    return super().gap_many(bank, queries)

  def error(self, bank, reduce: str = "max", bodies=None) -> np.ndarray:
    """f64[W] the angle to the goal, radians, per body at the world's last
    frame (no window) or the largest over the window, combined over the
    query's bodies (or ``bodies``) by ``max`` or ``sum``."""
    mask = _mask(bank, self, bodies)
    err = body_errors(bank, self, mask)[:, mask]
    return np.sum(err, axis=1) if reduce == "sum" else np.max(err, axis=1, initial=-np.inf)

  def describe(self) -> str:
    goal = "initial orientation" if self.target is not None else "upright"
    return f"{self.sign} {who(self)} within {self.within_deg:g}° of {goal}"

  @classmethod
  def claims(cls, entry) -> bool:
    return entry.upright is not None or entry.orientation is not None or entry.within_deg is not None

  @classmethod
  def from_entry(cls, entry, index: int, context) -> OrientationQuery:
    where = f"queries[{index}]"
    extra = unexpected_fields(entry, ("name", "bodies", "upright", "orientation", "within_deg", "window", "sign",
                                      "mode"))
    if extra:
      raise MwbxError(f"{context.path}: {where}: an orientation query takes bodies, upright or orientation, "
                      f"within_deg, window, sign, mode and name, not {', '.join(extra)}")
    if (entry.upright is None) == (entry.orientation is None):
      raise MwbxError(f"{context.path}: {where}: an orientation query needs exactly one of 'upright' "
                      f"(a body axis) or 'orientation' (a quaternion or 'initial')")
    if entry.within_deg is None:
      raise MwbxError(f"{context.path}: {where}: an orientation query needs 'within_deg' (degrees)")
    upright = entry.upright
    if isinstance(upright, (str, tuple)):
      axis, up = upright, "z"
    elif upright is not None:
      axis, up = upright.axis, upright.up
    fields = dict(bodies=entry.bodies, within_deg=entry.within_deg, window=entry.window, sign=entry.sign,
                  mode=entry.mode, name=entry.name or where)
    try:
      if upright is not None:
        query = cls(axis=axis, up=up, **fields)
      else:
        query = cls(target=entry.orientation, **fields)
    except MwbxError as err:
      raise MwbxError(f"{context.path}: {where}: {err}") from None
    context.check_bodies(query.bodies, where, field=False)
    return query

  def to_dict(self) -> dict:
    """The query's entry in a query file (see :mod:`.query_file`)."""
    out: dict = {"name": self.name}
    if self.bodies is not None:
      out["bodies"] = list(self.bodies)
    if self.axis is not None:
      out["upright"] = {"axis": list(self.axis), "up": list(self.up)}
    else:
      out["orientation"] = self.target if isinstance(self.target, str) else list(self.target)
    out["within_deg"] = self.within_deg
    if self.window is not None:
      out["window"] = list(self.window)
    out.update(sign=self.sign, mode=self.mode)
    return out


# ---------------------------------------------------------------------------
# Orientations at every stored frame, per body, cached per bank.

_CACHE = PerBank()


def body_quats(bank, body: int) -> np.ndarray:
  """f32[W, T, 4] a tracked body's orientation (w, x, y, z) at every stored
  frame (tails hold each world's last frame), from the decoded qpos.

  Args:
    bank: the bank. body: index into the tracked bodies.
  """
  return all_quats(bank, [int(body)])[int(body)]


def all_quats(bank, bodies) -> dict:
  """{body index: f32[W, T, 4]} for tracked bodies (as :func:`body_quats`);
  the ones not cached yet are decoded together, in one pass over the worlds."""
  state = (bank.n_worlds, id(bank.qpos_store))
  out, missing = {}, []
  for body in bodies:
    kept = _CACHE.peek(bank, int(body), state)
    if kept is not None:
      out[int(body)] = kept
    else:
      missing.append(int(body))
  if not missing:
    return out
  model = bank.model
  body_ids = [int(np.asarray(bank.body_ids)[b]) for b in missing]
  columns = np.unique(np.concatenate([_chain_columns(model, b) for b in body_ids]))
  counts = np.asarray(bank.frame_count, np.int64)
  n_frames = max(int(counts.max(initial=1)), 1)
  fresh = np.zeros((len(missing), bank.n_worlds, n_frames, 4), np.float32)
  for s in range(0, bank.n_worlds, BLOCK):
    rows = np.arange(s, min(bank.n_worlds, s + BLOCK))
    qpos = poses_lib.padded(poses_lib.decoded_frames(bank, rows, columns), n_frames)
    _, quat = poses_lib.body_poses(model, qpos.reshape(len(rows) * n_frames, -1), body_ids)
    fresh[:, rows] = np.moveaxis(quat.reshape(len(rows), n_frames, len(body_ids), 4), 2, 0)
  for i, body in enumerate(missing):
    out[body] = fresh[i]
    _CACHE.put(bank, body, state, fresh[i])
  return out


def _decode_together(bank, queries) -> None:
  """Caches the orientations of every body ``queries`` select, decoded in
  one pass over the worlds (each query alone would decode the stored
  streams again for its own bodies). Refuses a flex first, as each query would."""
  if bank.n_worlds == 0:
    return
  chosen = np.zeros(len(bank.body_names), bool)
  for query in queries:
    chosen |= _mask(bank, query)
  all_quats(bank, np.flatnonzero(chosen).tolist())


def _chain_columns(model, body_id: int) -> np.ndarray:
  columns = []
  for b in poses_lib.chain(model, [body_id]):
    for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b] + model.body_jntnum[b])):
      adr = int(model.jnt_qposadr[j])
      columns.extend(range(adr, adr + QPOS_WIDTH[int(model.jnt_type[j])]))
  return np.asarray(sorted(columns), np.int64)


def frame_range(bank, window) -> tuple[np.ndarray, np.ndarray]:
  """(first, last) i64[W] stored frames a window covers per world (the last
  frame only when there is no window), rounded to the nearest frame."""
  last = np.maximum(np.asarray(bank.frame_count, np.int64) - 1, 0)
  if window is None:
    return last, last
  t0, t1 = window
  fps = float(bank.record_fps)
  f0 = np.zeros_like(last) if t0 is None else np.minimum(max(int(round(t0 * fps)), 0), last)
  f1 = last if t1 is None else np.minimum(max(int(round(t1 * fps)), 0), last)
  return f0, np.maximum(f1, f0)


def angle_errors(query: OrientationQuery, quats: np.ndarray) -> np.ndarray:
  """f64[W, T] the query's error, radians, at every frame of one body's
  orientations quats f32[W, T, 4]."""
  return _angle(query, _closeness(query, quats))


def _angle(query: OrientationQuery, c: np.ndarray) -> np.ndarray:
  """The error, radians, from :func:`_closeness` (a decreasing function)."""
  if query.axis is not None:
    return np.arccos(np.clip(c, -1.0, 1.0))
  return 2.0 * np.arccos(np.clip(c, 0.0, 1.0))


def _closeness(query: OrientationQuery, quats: np.ndarray) -> np.ndarray:
  """f64[W, T] the cosine of the axis' angle to up (upright), or |q·target|
  (the cosine of half the rotation angle): the larger, the closer."""
  w, x, y, z = (quats[..., i].astype(np.float64) for i in range(4))
  if query.axis is not None:
    # up·(R a) for q = (w, u): up·a (1 - 2|u|²) + 2 w u·(a × up) + 2 (u·up)(u·a).
    a, up = np.asarray(query.axis), np.asarray(query.up)
    k = np.cross(a, up)
    dot = lambda v: x * v[0] + y * v[1] + z * v[2]
    return (float(up @ a) * (1.0 - 2.0 * (x * x + y * y + z * z)) + 2.0 * w * dot(k)
            + 2.0 * dot(up) * dot(a))
  if query.target == "initial":
    t = [c[:, :1] for c in (w, x, y, z)]
  else:
    t = list(query.target)
  return np.abs(w * t[0] + x * t[1] + y * t[2] + z * t[3])


def _mask(bank, query: OrientationQuery, bodies=None) -> np.ndarray:
  """bool[B] the query's bodies (or ``bodies``), without a flex's vertices;
  MwbxError where a name selects only those (a cloth has no orientation)."""
  label = f"query {query.name!r}" if query.name else "query"
  return turning_mask(bank, query.bodies if bodies is None else bodies, label)


def body_errors(bank, query: OrientationQuery, mask: np.ndarray) -> np.ndarray:
  """f64[W, B] each selected body's largest error over the query's frames,
  radians (NaN for unselected bodies)."""
  out = np.full((bank.n_worlds, len(mask)), np.nan)
  f0, f1 = frame_range(bank, query.window)
  rows = np.arange(bank.n_worlds)
  lo, hi = int(f0.min(initial=0)), int(f1.max(initial=0))
  cached = all_quats(bank, np.flatnonzero(mask).tolist())
  for b in np.flatnonzero(mask):
    quats = cached[int(b)]
    if query.window is None:  # the last frames only
      last = quats[rows, f1][:, None]
      first = quats[:, :1]
      err = angle_errors(query, np.concatenate([first, last], axis=1))[:, 1]
      out[:, b] = err
      continue
    span = quats[:, lo:hi + 1]
    if query.target == "initial" and lo > 0:
      span = np.concatenate([quats[:, :1], span], axis=1)
      close = _closeness(query, span)[:, 1:]
    else:
      close = _closeness(query, span)  # [W, hi - lo + 1]
    frames = np.arange(lo, hi + 1)[None]
    inside = (frames >= f0[:, None]) & (frames <= f1[:, None])
    out[:, b] = _angle(query, np.min(np.where(inside, close, np.inf), axis=1))  # the farthest frame
  return out


def evaluate_orientation(bank, query: OrientationQuery, mask: np.ndarray) -> np.ndarray:
  """bool[W] worlds meeting the query (unstable worlds: False)."""
  err = body_errors(bank, query, mask)
  within = err <= query.within  # NaN (unselected) -> False
  if query.mode == "any":
    met = np.any(within & mask, axis=1)
  else:
    met = np.all(within | ~mask, axis=1)
  met = met if query.include else ~met
  return met & np.asarray(bank.valid, bool)


def orientation_gap(bank, query: OrientationQuery, mask: np.ndarray) -> np.ndarray:
  """f64[W] ungated distance to meeting the query, radians: how far the
  error exceeds the angle (include), or how far inside it lies (exclude),
  over bodies closest (any) or farthest (all), as the volume gaps do."""
  if not mask.any():
    return np.full(bank.n_worlds, np.inf if query.include else 0.0)
  err = body_errors(bank, query, mask)[:, mask]
  if query.include:
    per_body = np.maximum(err - query.within, 0.0)
    return per_body.min(axis=1) if query.mode == "any" else per_body.max(axis=1)
  depth = np.maximum(query.within - err, 0.0)
  return depth.max(axis=1) if query.mode == "any" else depth.min(axis=1)
