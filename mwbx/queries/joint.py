"""Joint queries: how far a hinge or slide joint turned over a time window.

COM paths cannot see a bucket turning on its hinge; its joint angle can. A
JointQuery asks that the change of one hinge (radians) or slide (metres)
joint over a window lie in a range: ``turn=(0.5, None)`` turned at least
half a radian the positive way about the joint axis, ``turn=(None, -0.5)``
the other way. The change is measured between the window's ends
(``of="change"``), or as the largest (``"max"``) or smallest (``"min"``)
value of ``q(t) - q(t0)`` inside it: a bucket that tips and swings back has
no net change but a large ``max`` or ``min``. Angles come from the decoded stored
qpos (within the codec's ``e_scalar`` bound of the simulation), read once
per bank and joint and cached.

Example::

  q = JointQuery("bucket_top_hinge", turn=(0.5, None), of="max")  # tipped right at some time
  mwbx.evaluate(bank, [q, screen_query])   # mixes with frustum queries
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.joints import JNT_HINGE, JNT_SLIDE
from mwbx.queries.bank_cache import PerBank
from mwbx.queries.query import Query
from mwbx.queries.query import unexpected_fields
from mwbx.queries.intervals import checked_interval
from mwbx.queries.intervals import checked_window


@dataclasses.dataclass(frozen=True, eq=False)
class JointQuery(Query):
  """The change of one hinge/slide joint over a window lies in a range.

  joint: the joint's MJCF name (a hinge or slide joint).
  turn: (lo, hi) bounds of ``q(t1) - q(t0)``, radians or metres; None for an
    open end.
  window: (t0, t1) seconds, None ends for the path's start and end; past a
    world's last frame its last frame holds (it came to rest).
  name: label for output.
  of: ``change`` (t1 against t0), ``max`` or ``min`` (extremes of
    ``q(t) - q(t0)`` over the window).
  """

  joint: str
  turn: tuple[float | None, float | None] = (None, None)
  window: tuple[float | None, float | None] | None = None
  name: str = ""
  of: str = "change"
  # A joint query is a positive constraint on no tracked body's path and draws no volume.
  sign = "include"
  bodies = None

  def __post_init__(self):
    label = f"query {self.name!r}" if self.name else "query"
    object.__setattr__(self, "turn", checked_interval(label, "turn", self.turn))
    if self.of not in MEASURES:
      raise MwbxError(f"{label}: of must be one of {MEASURES}, got {self.of!r}")
    if self.window is not None:
      object.__setattr__(self, "window", checked_window(label, self.window))


  # -- the Query interface -----------------------------------------------------------

  def evaluate(self, bank) -> np.ndarray:
    return evaluate_joint(bank, self)

  def gap(self, bank) -> np.ndarray:
    """f64[W] how far the joint's turn lies outside its range, radians or metres."""
    turn = joint_turn(bank, self.joint, self.window, self.of)
    lo, hi = self.turn
    gap = np.zeros_like(turn)
    if lo is not None:
      gap = np.maximum(gap, lo - turn)
    if hi is not None:
      gap = np.maximum(gap, turn - hi)
    return gap

  def objects(self, owner) -> list[str]:
    """The object the joint belongs to (none if its body is no object)."""
    model = owner.model  # a bank's or a scene's MjModel
    body = model.jnt_bodyid[model.joint(self.joint).id]
    root = model.body(int(model.body_rootid[body])).name
    return [root] if root in owner.objects else []

  def body_mask(self, bank) -> np.ndarray:
    """bool[B] the tracked bodies of the joint's object (none if it is no object's)."""
    objects = self.objects(bank)
    mask = np.zeros(len(bank.body_names), bool)
    if objects:
      mask[np.asarray(bank.select_bodies(objects), np.int64)] = True
    return mask

  def check(self, bank) -> None:
    joint_column(bank.model, self.joint)

  def describe(self) -> str:
    return f"joint {self.joint} turns {self.turn}" + ("" if self.of == "change" else f" ({self.of})")

  def to_dict(self) -> dict:
    out: dict = {"name": self.name, "joint": self.joint, "turn": list(self.turn), "of": self.of}
    if self.window is not None:
      out["window"] = list(self.window)
    return out

  @classmethod
  def claims(cls, entry) -> bool:
    return entry.joint is not None or entry.turn is not None or entry.of is not None

  @classmethod
  def from_entry(cls, entry, index: int, context) -> JointQuery:
    where = f"queries[{index}]"
    # `shape` is ignored here, as it always was.
    extra = unexpected_fields(entry, ("joint", "turn", "of", "window", "name", "shape"))
    if extra:
      raise MwbxError(f"{context.path}: {where}: a joint query takes joint, turn, of, window and name, not "
                      f"{', '.join(extra)}")
    if entry.joint is None or entry.turn is None:
      raise MwbxError(f"{context.path}: {where}: a joint query needs both 'joint' and 'turn' ([lo, hi])")
    try:
      query = cls(entry.joint, entry.turn, entry.window, entry.name or where, entry.of or "change")
      if context.model is not None:
        joint_column(context.model, entry.joint)
    except MwbxError as err:
      raise MwbxError(f"{context.path}: {where}: {err}") from None
    return query


_CACHE = PerBank()
MEASURES = ("change", "max", "min")


def joint_column(model: mujoco.MjModel, joint: str) -> int:
  """qpos address of a hinge or slide joint; MwbxError naming it otherwise."""
  jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
  if jid < 0:
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
    scalar = [n for j, n in enumerate(names) if n and int(model.jnt_type[j]) in (JNT_HINGE, JNT_SLIDE)]
    raise MwbxError(f"joint query: unknown joint {joint!r} (hinge and slide joints: "
                    f"{', '.join(scalar) or 'none'})")
  if int(model.jnt_type[jid]) not in (JNT_HINGE, JNT_SLIDE):
    raise MwbxError(f"joint query: joint {joint!r} is not a hinge or slide joint")
  return int(model.jnt_qposadr[jid])


def joint_paths(bank, joint: str) -> np.ndarray:
  """f32[W, F] the joint's decoded value at every recorded frame (tails hold
  the last frame), cached per bank and joint."""
  column = joint_column(bank.model, joint)
  return _CACHE.get(bank, joint, (bank.n_worlds, id(bank.qpos_store)), lambda: _decoded(bank, column))


def _decoded(bank, column: int) -> np.ndarray:
  n = bank.n_worlds
  counts = np.asarray(bank.frame_count, np.int64)
  out = np.zeros((n, max(int(counts.max(initial=1)), 1)), np.float32)
  frames = bank.qpos_store.frames_of_rows(None, columns=np.array([column]))
  for w, f in enumerate(frames):
    if len(f):
      out[w, :len(f)] = f[:, column]
      out[w, len(f):] = f[-1, column]
  return out


def joint_turn(bank, joint: str, window=None, of: str = "change") -> np.ndarray:
  """f64[W] ``q(t1) - q(t0)`` of a hinge/slide joint (radians or metres), or
  the max / min of ``q(t) - q(t0)`` over the window (``of``)."""
  paths = joint_paths(bank, joint)
  t0, t1 = (None, None) if window is None else window
  fps = float(bank.record_fps)
  last = np.maximum(np.asarray(bank.frame_count, np.int64) - 1, 0)
  f0 = np.zeros_like(last) if t0 is None else np.minimum(int(round(t0 * fps)), last)
  f1 = last if t1 is None else np.minimum(int(round(t1 * fps)), last)
  rows = np.arange(bank.n_worlds)
  start = paths[rows, f0].astype(np.float64)
  if of == "change":
    return paths[rows, f1] - start
  frames = np.arange(paths.shape[1])[None]
  inside = (frames >= f0[:, None]) & (frames <= f1[:, None])
  fill = -np.inf if of == "max" else np.inf
  values = np.where(inside, paths, fill)
  extreme = values.max(axis=1) if of == "max" else values.min(axis=1)
  return extreme - start


def evaluate_joint(bank, query: JointQuery) -> np.ndarray:
  """bool[W] worlds whose joint change lies in ``query.turn`` (unstable: False)."""
  turn = joint_turn(bank, query.joint, query.window, query.of)
  lo, hi = query.turn
  ok = np.ones(bank.n_worlds, bool)
  if lo is not None:
    ok &= turn >= lo
  if hi is not None:
    ok &= turn <= hi
  return ok & np.asarray(bank.valid, bool)
