"""Whole-geometry queries: does any point of a body's geoms enter a volume?

A COM path can miss a box that a body's corner passes through. With
``VolumeQuery(..., shape="geometry")`` a body hits the volume if some point of its
geoms (their true shapes, see :mod:`.shapes`) enters it during the window.

What is tested, and the bound: the stored qpos frames (decoded, at
``record_fps``) give each body's pose by forward kinematics. Poses are kept
every ``stride`` frames (the query rate); for each interval between two kept
frames a sweep margin ``m`` bounds how far any point of the body gets from
its place at the nearer kept frame, over every stored frame in between and
the motion between consecutive stored frames (linear in position, shortest
rotation):  with c the centre of mass, theta the rotation between two poses
and `reach` the body's farthest geom point from c,

  m = max_j min(|c_j - c_A| + 2 sin(theta_jA / 2) reach, same to B)
      + max_j (|c_j+1 - c_j| / 2 + 2 sin(theta_j,j+1 / 4) reach).

The codec's bound adds a constant per body (its joints' position, rotation
and scalar bounds times their lever arms), and a float tolerance.

The answer is that of every stored frame: a body hits when, at some stored
frame whose step (to the next or previous stored frame) overlaps the window,
its exact geom shapes come within that step's margin (the second term of m
for the one step, at most half the step's motion) plus the codec's bound of
the volume (:mod:`.convex`). So a world a brute-force test finds (some point
of some geom inside the volume at some stored frame in the window) is always
found, and a reported hit is never further out than the motion between two
stored frames and the codec's error. The kept frames, with their interval
margins, decide most worlds at once; a world that meets the volume only
within an interval's margin is settled on its stored frames
(:class:`StoredFrames`, decoded on demand and kept).

Fast path, all conservative (:mod:`.geometry_cull`): per body, one compiled
pass culls worlds, groups and chunks of kept frames by boxes of the COM
grown by the reach, the codec's bound and the largest margin inside, then
decides kept frames by their bounding sphere, each geom's extent along the
planes, a vertex in or projected into the volume and the nearest vertex's
exact distance; only frames near an edge or corner of the volume reach the
full separating-axis test. The index is built by :mod:`.kept_poses`.
"""

from __future__ import annotations

import collections
import dataclasses
import threading
import weakref

import numpy as np

from mwbx.joints import JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE
from mwbx.queries import geometry_cull
from mwbx.queries.bank_cache import PerBank
from mwbx.queries import kept_poses
from mwbx.queries import poses as poses_lib
from mwbx.queries import shapes as shapes_lib

BLOCK = 64  # worlds decoded at once while building
CHUNK = 4  # kept frames per chunk box of the culling pass
GROUP = 4  # chunks per group box


@dataclasses.dataclass
class GeometryIndex:
  """Kept poses, sweep margins and prefilter boxes of a bank's tracked bodies.

  frames: i64[K] kept record frames (the last holds each world's rest).
  times: f64[K] their times, seconds.
  com: f32[B, W, K, 3] centres of mass, metres.
  quat: f32[B, W, K, 4] orientations (w, x, y, z).
  sweep: f32[B, W, K - 1] margin of each interval between kept frames, m.
  codec: f64[B] the codec bound's reach per body, m (0 for raw qpos).
  reach: f64[B] farthest geom point from the COM, m.
  cores: per body, its geoms' cores (:mod:`.shapes`).
  ipos: f64[B, 3] COM in the body frame.
  repeat: bool[B, W, K] the pose equals the previous kept frame's (at rest):
    testing it again with no larger margin cannot add a hit.
  lo, hi: f64[3] a box holding every grown shape (the volume is clipped to it).
  valid: bool[W].
  chunk: kept frames per chunk box; group: chunks per group box.
  bounds: the culling boxes of :func:`.geometry_cull.chunk_bounds`.
  stride: stored frames per interval between kept frames.
  tol: metres of float slack (float32 storage of poses and margins).
  stored: the poses at every stored frame, for the worlds a query must
    settle there (None where every stored frame is kept).
  answers: the latest query answers by their volume, bodies and window (a
    page re-evaluates its whole query stack when one query changes).
  """

  frames: np.ndarray
  times: np.ndarray
  com: np.ndarray
  quat: np.ndarray
  sweep: np.ndarray
  codec: np.ndarray
  reach: np.ndarray
  cores: list
  ipos: np.ndarray
  repeat: np.ndarray
  lo: np.ndarray
  hi: np.ndarray
  valid: np.ndarray
  chunk: int
  group: int
  bounds: tuple = dataclasses.field(repr=False)
  stride: int = 1
  tol: float = 0.0
  stored: "StoredFrames | None" = dataclasses.field(default=None, repr=False)
  answers: dict = dataclasses.field(default_factory=dict, repr=False)


def codec_reach(model, body: int, reach: float, bounds) -> float:
  """Metres the codec's error can move a point of a body: per joint placing
  it, the joint's bound times its lever (free: sqrt(3) e_pos + e_rot lever;
  ball: e_rot lever; hinge: e_scalar lever; slide: e_scalar).

  The lever is bounded by the chain's lengths from the joint to the body's
  farthest geom point, whatever the configuration.
  """
  if bounds is None:
    return 0.0
  total = 0.0
  below = float(np.linalg.norm(model.body_ipos[body])) + reach  # from the body's origin
  b = int(body)
  while b > 0:
    for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b] + model.body_jntnum[b])):
      kind = int(model.jnt_type[j])
      lever = below + float(np.linalg.norm(model.jnt_pos[j]))
      if kind == JNT_FREE:
        total += np.sqrt(3.0) * bounds.e_pos + bounds.e_rot * lever
      elif kind == JNT_BALL:
        total += bounds.e_rot * lever
      elif kind == JNT_HINGE:
        total += bounds.e_scalar * lever
      elif kind == JNT_SLIDE:
        total += bounds.e_scalar
    below += float(np.linalg.norm(model.body_pos[b]))
    b = int(model.body_parentid[b])
  return total


def _chord(dot: np.ndarray) -> np.ndarray:
  """2 sin(theta / 2) of rotations with |q1·q2| = cos(theta / 2)."""
  return 2.0 * np.sqrt(np.clip(1.0 - dot * dot, 0.0, 1.0))


def _quarter_chord(dot: np.ndarray) -> np.ndarray:
  """2 sin(theta / 4) of rotations with |q1·q2| = cos(theta / 2)."""
  return 2.0 * np.sqrt(np.clip((1.0 - np.abs(dot)) / 2.0, 0.0, 1.0))


def sweep_margins(com: np.ndarray, quat: np.ndarray, reach: np.ndarray, stride: int) -> np.ndarray:
  """The margin of each interval between kept frames (module docstring).

  Args:
    com: f64[..., T, B, 3] centres of mass at every stored frame, T = 1 + k stride.
    quat: f64[..., T, B, 4] unit orientations.
    reach: f64[B] metres.
    stride: stored frames per interval.

  Returns:
    f64[..., k, B] metres.
  """
  t = com.shape[-3]
  n_int = (t - 1) // stride
  start = np.arange(n_int) * stride
  steps = start[:, None] + np.arange(stride + 1)[None]  # [k, s+1] frames of each interval
  c, q = com[..., steps, :, :], quat[..., steps, :, :]  # [..., k, s+1, B, *]

  def apart(end: int) -> np.ndarray:
    """How far any point gets from its place at one end of its interval."""
    dc = np.linalg.norm(c - c[..., end:end + 1, :, :], axis=-1)
    dot = np.abs(np.sum(q * q[..., end:end + 1, :, :], axis=-1))
    return dc + _chord(dot) * reach

  to_ends = np.minimum(apart(0), apart(stride)).max(axis=-2)  # [..., k, B]
  step_c = np.linalg.norm(np.diff(c, axis=-3), axis=-1) / 2.0
  step_q = _quarter_chord(np.sum(q[..., 1:, :, :] * q[..., :-1, :, :], axis=-1)) * reach
  return to_ends + (step_c + step_q).max(axis=-2)


def build(bank, valid: np.ndarray, stride: int | None = None, chunk: int = CHUNK,
          group: int = GROUP) -> GeometryIndex:
  """The geometry index of a bank's tracked bodies (decodes every world once)."""
  if stride is None:
    stride = max(1, int(round(float(bank.record_fps) / float(bank.query_fps))))
  model = bank.model
  body_ids = np.asarray(bank.body_ids, np.int64)
  counts = np.asarray(bank.frame_count, np.int64)
  n_frames = max(int(counts.max(initial=1)), 1)
  n_int = max(1, -(-(n_frames - 1) // stride))
  cores = [shapes_lib.body_cores(model, int(b)) for b in body_ids]
  reach = np.array([shapes_lib.reach(model, int(b), c) for b, c in zip(body_ids, cores)])
  bounds = getattr(bank.qpos_store, "bounds", None)
  codec = np.array([codec_reach(model, int(b), r, bounds) for b, r in zip(body_ids, reach)])
  ipos = np.asarray(model.body_ipos[body_ids], np.float64)
  kinematics = _Kinematics(kept_poses.tree(model, body_ids), body_ids, ipos, reach, n_int * stride + 1)
  com, quat, sweep = kinematics.poses(bank, np.arange(bank.n_worlds), stride)
  finite = np.isfinite(com).all(axis=(0, 2, 3)) & valid
  extent = float(np.max(np.abs(com[:, finite]), initial=0.0))
  sweep_tol = 1e-6 * (1.0 + extent)  # float32 storage of poses and margins
  sweep = _with_tol(sweep, sweep_tol)
  grow = float(np.max(reach + codec, initial=0.0)) + float(np.max(np.where(np.isfinite(sweep[:, finite]),
                                                                          sweep[:, finite], 0.0),
                                                                 initial=0.0))
  lo = np.full(3, -(extent + grow + 1.0))
  hi = -lo
  frames = np.arange(n_int + 1) * stride
  stored = None if stride == 1 else StoredFrames(bank, kinematics, sweep_tol, chunk * stride, group)
  return _index(frames, frames / float(bank.record_fps), com, quat, sweep, codec, reach, cores, ipos, lo, hi,
                np.asarray(valid, bool), chunk, group, stride, stored)


def _with_tol(sweep: np.ndarray, tol: float) -> np.ndarray:
  """Margins grown by the float tolerance; non-finite ones (an unstable world) infinite."""
  return np.where(np.isfinite(sweep), sweep + np.float32(tol), np.inf).astype(np.float32)


def _index(frames, times, com, quat, sweep, codec, reach, cores, ipos, lo, hi, valid, chunk, group, stride,
           stored) -> GeometryIndex:
  """A :class:`GeometryIndex` of poses and margins already computed."""
  repeat = np.zeros(com.shape[:3], bool)
  repeat[:, :, 1:] = (np.all(com[:, :, 1:] == com[:, :, :-1], axis=-1)
                      & np.all(quat[:, :, 1:] == quat[:, :, :-1], axis=-1))
  return GeometryIndex(frames, times, com, quat, sweep, codec, reach, cores, ipos, repeat, lo, hi, valid, chunk,
                       group, geometry_cull.chunk_bounds(com, sweep, chunk, group), stride,
                       1e-6 * (1.0 + float(np.max(np.abs(hi)))), stored)


@dataclasses.dataclass(frozen=True)
class _Kinematics:
  """What :func:`kept_poses.kept_poses` needs of a bank's model."""

  tree: kept_poses.KinematicTree
  body_ids: np.ndarray
  ipos: np.ndarray
  reach: np.ndarray
  n_stored: int  # stored frames per world, padded (1 + intervals x stride)

  def poses(self, bank, rows: np.ndarray, stride: int) -> tuple:
    """(com f32[B, w, K, 3], quat f32[B, w, K, 4], sweep f32[B, w, K - 1]) of
    bank rows, every `stride`-th stored frame kept (sweep without tolerance)."""
    n_bodies, n_kept = len(self.body_ids), (self.n_stored - 1) // stride + 1
    com = np.zeros((n_bodies, len(rows), n_kept, 3), np.float32)
    quat = np.zeros((n_bodies, len(rows), n_kept, 4), np.float32)
    sweep = np.zeros((n_bodies, len(rows), n_kept - 1), np.float32)
    for s in range(0, len(rows), BLOCK):
      block = rows[s:s + BLOCK]
      qpos = poses_lib.padded(poses_lib.decoded_frames(bank, block), self.n_stored)  # [w, T, nq]
      part = slice(s, s + len(block))
      kept_poses.kept_poses(qpos, self.tree, self.body_ids, self.ipos, self.reach, stride, com[:, part],
                            quat[:, part], sweep[:, part])
    return com, quat, sweep


STORED_FRAMES_BYTES = 1 << 30  # poses at every stored frame kept per index, at most


class StoredFrames:
  """A bank's poses at every stored frame, for the worlds a query settles there.

  A hit found only with an interval's sweep margin is settled on the stored
  frames, by the same evaluation on a stride-1 :class:`GeometryIndex` (each
  stored frame in the window on its own, the codec's bound its only margin:
  :func:`.geometry_query.window_frames`). Where the whole
  bank's stored-frame poses fit in ``STORED_FRAMES_BYTES``, that index is
  built for every world on the first settle (one more decode of the bank)
  and kept: a settle is then one masked pass. Otherwise it holds just the
  worlds asked for, each decoded once and kept (most recently used first,
  within the same budget).
  """

  def __init__(self, bank, kinematics: _Kinematics, sweep_tol: float, chunk: int, group: int):
    try:
      self._bank = weakref.ref(bank)
    except TypeError:  # not weak-referenceable (a test's stand-in)
      self._bank = lambda bank=bank: bank
    self._kinematics, self._sweep_tol, self._chunk, self._group = kinematics, sweep_tol, chunk, group
    self._record_fps = float(bank.record_fps)
    per_world = len(kinematics.body_ids) * kinematics.n_stored * 4 * (3 + 4 + 1)  # float32 com, quat, sweep
    self._whole = per_world * bank.n_worlds <= STORED_FRAMES_BYTES
    self._all: GeometryIndex | None = None
    self._kept: collections.OrderedDict = collections.OrderedDict()  # row -> (com, quat, sweep)
    self._bytes = 0
    self._lock = threading.Lock()

  def _live_bank(self):
    bank = self._bank()
    if bank is None:
      raise RuntimeError("the bank of this geometry index is gone")
    return bank

  def index(self, parent: GeometryIndex, rows: np.ndarray) -> tuple[GeometryIndex, np.ndarray]:
    """(stride-1 index holding bank rows i64[n], clipped as ``parent``; the rows' places in it)."""
    rows = np.asarray(rows, np.int64)
    with self._lock:
      if self._whole:
        if self._all is None:
          self._all = self._stride_one(parent, *self._poses(np.arange(parent.com.shape[1])), parent.valid)
        return self._all, rows
      missing = np.array([r for r in rows.tolist() if r not in self._kept], np.int64)
      if missing.size:
        com, quat, sweep = self._poses(missing)
        for i, r in enumerate(missing.tolist()):
          entry = (com[:, i].copy(), quat[:, i].copy(), sweep[:, i].copy())
          self._kept[r] = entry
          self._bytes += sum(a.nbytes for a in entry)
      entries = [self._kept[r] for r in rows.tolist()]
      for r in rows.tolist():
        self._kept.move_to_end(r)
      while self._bytes > STORED_FRAMES_BYTES and len(self._kept) > len(rows):
        _, old = self._kept.popitem(last=False)
        self._bytes -= sum(a.nbytes for a in old)
    com, quat, sweep = (np.stack([e[i] for e in entries], axis=1) for i in range(3))
    return self._stride_one(parent, com, quat, sweep, parent.valid[rows]), np.arange(len(rows))

  def _poses(self, rows: np.ndarray) -> tuple:
    com, quat, sweep = self._kinematics.poses(self._live_bank(), rows, 1)
    return com, quat, _with_tol(sweep, self._sweep_tol)

  def _stride_one(self, parent: GeometryIndex, com, quat, sweep, valid) -> GeometryIndex:
    frames = np.arange(com.shape[2])
    return _index(frames, frames / self._record_fps, com, quat, sweep, parent.codec, parent.reach, parent.cores,
                  parent.ipos, parent.lo, parent.hi, valid, self._chunk, self._group, 1, None)


# ---------------------------------------------------------------------------
# Per-bank cache


_CACHE = PerBank()


def geometry_index(bank) -> GeometryIndex:
  """The bank's geometry index (built on first use, then cached per bank)."""
  valid = np.asarray(bank.valid, bool)
  key = (bank.n_worlds, valid.tobytes(), id(bank.qpos_store))
  return _CACHE.get(bank, "geometry", key, lambda: build(bank, valid))
