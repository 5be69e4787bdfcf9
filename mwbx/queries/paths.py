"""Where stored COM paths meet volumes: the bank's bounds hierarchy (built
once and cached per bank, or a shard at a time for a big bank on disk), the
per-path hits of a volume and the time a path first enters one.

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
  radii: np.ndarray | None = None


_CACHE = PerBank()

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


def blocks(bank, valid: np.ndarray):
  """(i64[k] rows, _BankState of those rows) a shard at a time: the whole bank."""
  radii = None
  for rows, com in bank.com.blocks():
    state = _BankState(None, index_lib.build_index(com, valid[rows]), radii)
    yield rows, state
    radii = state.radii  # body radii are the bank's: computed once


def bank_state(bank) -> _BankState:
  """The bank's index state (bounds hierarchy, body radii), built on first use and cached per bank."""
  com = bank.com
  if _lazy(com):  # small enough to index whole: read every shard once
    com = com.materialized()
  valid = np.asarray(bank.valid, bool)
  key = (id(com), com.shape, valid.tobytes())
  return _CACHE.get(bank, "index", key, lambda: _BankState(key, index_lib.build_index(com, valid)))


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


def _radii(bank, state: _BankState) -> np.ndarray:
  if state.radii is None:
    state.radii = body_radii(bank.model, bank.body_ids)
  return state.radii


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


def resolve(bank, query, state: _BankState | None = None):
  """A volume query's arrays for the kernels on this bank.

  Args:
    bank: the bank.
    query: its ``frustum``, ``radius`` (metres or ``auto``), ``bodies`` and
      ``window`` (a :class:`~mwbx.queries.query.VolumeQuery`).
    state: the bank's (or a block's) index state; None: the bank's, cached.

  Returns:
    (normals f32[F, 3], offsets f64[B, F], body_mask bool[B], window f64[2]).
  """
  state = state or bank_state(bank)
  n_bodies = len(bank.body_names)
  if query.radius == "auto":
    radius = _radii(bank, state)
  else:
    radius = np.full(n_bodies, float(query.radius))
  n_segments = int(state.index.n_segments)
  return (query.frustum.normals, plane_offsets(query.frustum, radius),
          selection_mask(bank, query.bodies), window_units(bank, query.window, n_segments))


def combine(hits: np.ndarray, body_mask: np.ndarray, query) -> np.ndarray:
  """Per-world answer from per-path hits bool[W, B] -> bool[W] (by the
  query's ``mode`` and ``sign``)."""
  if query.mode == "any":
    met = np.any(hits & body_mask, axis=1)
  else:
    met = np.all(hits | ~body_mask, axis=1)
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
