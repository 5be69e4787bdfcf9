"""Where stored COM paths meet volumes: the bank's bounds hierarchy (built
once and cached per bank, or a shard at a time for a big bank on disk), a
lazily opened bank's answers from its stored path boxes first
(:func:`box_answers`), the per-path hits of a volume and the time a path
first enters one.

What :class:`~mwbx.queries.query.VolumeQuery` answers with; the kernels are
in :mod:`.index` and :mod:`.segments`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
from jax import numpy as jp
import mujoco
import numpy as np

from mwbx.queries import index as index_lib
from mwbx.queries import path_boxes
from mwbx.queries import segments
from mwbx.queries.bank_cache import PerBank
from mwbx.queries.frustum import Frustum
from mwbx.queries.selection import selection_mask


def window_points(bank, window) -> np.ndarray:
  """bool[P] stored COM points in a window (seconds; the tail repeats the last point)."""
  n_points = bank.com.shape[1]
  t = np.arange(n_points) / float(bank.query_fps)
  t0, t1 = (None, None) if window is None else window
  inside = np.ones(n_points, bool)
  if t0 is not None:
    inside &= t >= t0 - 1e-9
  if t1 is not None:
    inside &= t <= t1 + 1e-9
  if not inside.any():  # a window between two points: the nearest one
    centre = 0.5 * ((t0 or 0.0) + (t[-1] if t1 is None else t1))
    inside[np.argmin(np.abs(t - centre))] = True
  return inside


@dataclasses.dataclass
class _BankState:
  key: tuple
  index: index_lib.PathIndex


_CACHE = PerBank()

# COM polylines up to this size (decoded, 1 GiB) are indexed whole and the index is
# cached: browsing asks again and again. A lazily opened bank beyond it is
# indexed a shard at a time in each evaluation, in the memory of one shard.
IN_MEMORY_COM_BYTES = 1 << 30
# Worlds left undecided by the stored boxes are decoded and tested in blocks of
# about this many bytes of decoded polylines.
DECODED_BLOCK_BYTES = 256 << 20
# Path chunks whose boxes are tested at once (float64 temporaries of about 200
# bytes each).
BOXED_CHUNKS = 1 << 18
# A bank that fits in memory whose boxes leave more than this fraction of its
# worlds open is decoded whole instead (and its index kept, for the next question).
OPEN_FRACTION = 0.5
# Evaluations of a lazily opened bank (that fits in memory) answered from its
# stored boxes before it is decoded and indexed whole: one, so a fresh
# `mwbx query` decodes only what its boxes leave open, and the page, asking
# again and again, gets the full index from its second box on.
BOX_ANSWERED_EVALUATIONS = 1


def streams(bank) -> bool:
  """Whether queries on this bank go a shard at a time (see ``IN_MEMORY_COM_BYTES``)."""
  com = bank.com
  return _lazy(com) and com.nbytes > IN_MEMORY_COM_BYTES


def _lazy(com) -> bool:
  """A bank's ``com`` read from shards on demand (``mwbx.bank.lazy.LazyRows``)."""
  return hasattr(com, "blocks") and hasattr(com, "materialized")


def blocks(bank, valid: np.ndarray):
  """(i64[k] rows, _BankState of those rows) a shard at a time: the whole bank."""
  for rows, com in bank.com.blocks():
    yield rows, _BankState(None, index_lib.build_index(com, valid[rows]))


def bank_state(bank) -> _BankState:
  """The bank's index state (bounds hierarchy), built on first use and cached per bank."""
  com = bank.com
  if _lazy(com):  # small enough to index whole: read every shard once
    com = com.materialized()
  valid = np.asarray(bank.valid, bool)
  key = (id(com), com.shape, valid.tobytes())
  return _CACHE.get(bank, "index", key, lambda: _BankState(key, index_lib.build_index(com, valid)))


def has_stored_boxes(bank) -> bool:
  """Whether ``stored_boxes`` reads the bank's path boxes without decoding a
  path: a lazily opened bank whose shards hold them."""
  return _lazy(bank.com) and bank.com.companions_stored()


def answered_from_boxes(bank) -> bool:
  """Whether this evaluation of volume queries starts from the bank's stored
  path boxes (:mod:`.path_boxes`): a lazily opened bank whose shards hold
  them, too big to keep decoded or answered from them fewer than
  ``BOX_ANSWERED_EVALUATIONS`` times."""
  if not has_stored_boxes(bank) or bank.com.is_materialized:  # (decoded whole already: its index is cheap)
    return False
  return streams(bank) or _box_answered(bank)[0] < BOX_ANSWERED_EVALUATIONS


def _box_answered(bank) -> list[int]:
  """[evaluations of this bank answered from its boxes] (kept per bank)."""
  return _CACHE.get(bank, "box_answered", id(bank.com), lambda: [0])


def stored_boxes(bank) -> path_boxes.PathBoxes:
  """The path boxes of every world of a lazily opened bank, in row order: each
  shard's as stored (computed from its decoded paths where a shard has none)."""
  com = bank.com

  def piece(rows, local, boxes, chunk):
    if boxes.chunk != chunk:  # boxed otherwise (in-memory worlds beside stored ones): boxed again alike
      return path_boxes.build(com.rows(rows), chunk)
    return boxes if np.array_equal(local, np.arange(boxes.n_worlds)) else boxes.take(local)

  def gather():
    parts = com.companions(path_boxes.build)
    boxes = path_boxes.concat([piece(*part, parts[0][2].chunk) for part in parts])
    rows = np.concatenate([rows for rows, _, _ in parts])
    return boxes if np.array_equal(rows, np.arange(len(rows))) else boxes.take(np.argsort(rows))

  return _CACHE.get(bank, "boxes", id(com), gather)


def box_answers(bank, queries, valid: np.ndarray) -> np.ndarray | None:
  """bool[W, k] answers of COM volume queries, from the stored path boxes
  where they decide a world, else from the world's decoded paths (the same
  answers as the full test: the boxes decide only what it would); None when
  they leave most worlds of a bank that fits in memory open.

  Args:
    bank: a lazily opened bank (``answered_from_boxes``).
    queries: volume queries with ``shape`` "com".
    valid: bool[W] worlds that may match.
  """
  _box_answered(bank)[0] += 1
  boxes = stored_boxes(bank)
  n_worlds = len(valid)
  met = np.zeros((n_worlds, len(queries)), bool)  # before each query's sign
  undecided = np.zeros((n_worlds, len(queries)), bool)
  resolved = []
  per_block = max(1, BOXED_CHUNKS // int(np.prod(boxes.chunk_lo.shape[1:3])))
  for j, query in enumerate(queries):
    resolved.append(resolve(bank, query, boxes.n_segments))
    for start in range(0, n_worlds, per_block):  # bounded temporaries
      part = slice(start, start + per_block)
      state = path_boxes.classify(boxes.take(part), *resolved[j])
      known, met[part, j] = path_boxes.world_answers(state, resolved[j][2], query.mode)
      undecided[part, j] = ~known & valid[part]
    if not streams(bank) and undecided.any(axis=1).sum() > OPEN_FRACTION * n_worlds:
      return None  # decoded whole, once, and indexed: what the next question wants too
  rows = np.flatnonzero(undecided.any(axis=1))
  row_bytes = max(1, int(np.prod(bank.com.shape[1:], dtype=np.int64)) * 4)
  per_block = max(1, DECODED_BLOCK_BYTES // row_bytes)
  for start in range(0, rows.size, per_block):
    block = rows[start:start + per_block]
    index = _padded_index(bank.com, block)
    for j, query in enumerate(queries):
      open_ = undecided[block, j]
      if open_.any():
        hits = np.asarray(index_lib.path_hits(index, *resolved[j]))[:block.size]
        met[block[open_], j] = met_by(hits, resolved[j][2], query.mode)[open_]
  include = np.array([query.include for query in queries], bool)
  return np.where(include, met, ~met) & valid[:, None]


def _padded_index(com, rows: np.ndarray) -> index_lib.PathIndex:
  """The index of some worlds' paths, padded with invalid copies of the first
  to 64·√2^k worlds: the kernels compile for a few sizes, not for every count
  of undecided worlds, and at most 42 % of the index is padding."""
  n = rows.size
  size = 64
  while size < n:
    size = int(round(size * 2**0.5)) if size == 1 << (size.bit_length() - 1) else 1 << size.bit_length()
  padded = np.empty((size,) + tuple(com.shape[1:]), np.float32)
  com.rows(rows, out=padded[:n])
  padded[n:] = padded[:1]
  return index_lib.build_index(padded, np.arange(size) < n)


def path_index(bank) -> index_lib.PathIndex:
  """The bank's bounds hierarchy (built on first use, then cached)."""
  return bank_state(bank).index


def body_radii(model: mujoco.MjModel, body_ids) -> np.ndarray:
  """Bounding radius of each body about its centre of mass, from its own geoms.

  Args:
    model: the scene model.
    body_ids: i[B] MuJoCo body ids.

  Returns:
    f64[B] max over the body's geoms of |geom centre - COM| + geom bounding
    radius, metres; a flex's vertex body at least the flex's radius (what
    its collisions see); 0 for a body with neither.
  """
  radii = np.zeros(len(body_ids))
  flex_radius = np.zeros(model.nbody)
  for f in range(model.nflex):
    adr, n = int(model.flex_vertadr[f]), int(model.flex_vertnum[f])
    bodies = model.flex_vertbodyid[adr:adr + n]
    flex_radius[bodies] = np.maximum(flex_radius[bodies], float(model.flex_radius[f]))
  for i, body in enumerate(np.asarray(body_ids)):
    geoms = np.flatnonzero(model.geom_bodyid == body)
    if geoms.size:
      reach = np.linalg.norm(model.geom_pos[geoms] - model.body_ipos[body], axis=1)
      radii[i] = float(np.max(reach + model.geom_rbound[geoms]))
    radii[i] = max(radii[i], flex_radius[int(body)])
  return radii


def bank_radii(bank) -> np.ndarray:
  """f64[B] the bank's tracked bodies' bounding radii (:func:`body_radii`), kept per bank."""
  ids = np.asarray(bank.body_ids)
  return _CACHE.get(bank, "radii", ids.tobytes(), lambda: body_radii(bank.model, ids))


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


def resolve(bank, query, n_segments: int):
  """A volume query's arrays for the kernels on this bank.

  Args:
    bank: the bank.
    query: its ``frustum``, ``radius`` (metres or ``auto``), ``bodies`` and
      ``window`` (a :class:`~mwbx.queries.query.VolumeQuery`).
    n_segments: segments per stored path (the index's ``n_segments``).

  Returns:
    (normals f32[F, 3], offsets f64[B, F], body_mask bool[B], window f64[2]).
  """
  n_bodies = len(bank.body_names)
  if query.radius == "auto":
    radius = bank_radii(bank)
  else:
    radius = np.full(n_bodies, float(query.radius))
  return (query.frustum.normals, plane_offsets(query.frustum, radius),
          selection_mask(bank, query.bodies), window_units(bank, query.window, int(n_segments)))


def met_by(hits: np.ndarray, body_mask: np.ndarray, mode: str) -> np.ndarray:
  """Per-world answer before the sign from per-path hits bool[W, B]: one
  selected body met the volume ("any") or every one did ("all")."""
  if mode == "any":
    return np.any(hits & body_mask, axis=1)
  return np.all(hits | ~body_mask, axis=1)


def combine(hits: np.ndarray, body_mask: np.ndarray, query) -> np.ndarray:
  """Per-world answer from per-path hits bool[W, B] -> bool[W] (by the
  query's ``mode`` and ``sign``)."""
  met = met_by(hits, body_mask, query.mode)
  return met if query.include else ~met


class _Volume(NamedTuple):
  """What :func:`resolve` reads of a volume query."""

  frustum: Frustum
  bodies: tuple[str, ...] | None
  window: tuple[float | None, float | None] | None
  radius: float | str


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
  query = _Volume(frustum, bodies, window, radius)
  if streams(bank):  # index this one world
    state = _BankState(None, index_lib.build_index(bank.com[row:row + 1], np.ones(1, bool)))
    row = 0
  else:
    state = bank_state(bank)
  normals, offsets, mask, win = resolve(bank, query, int(state.index.n_segments))
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
