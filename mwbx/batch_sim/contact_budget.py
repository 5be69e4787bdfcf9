"""Contact budgets of the batched engines, sized by a short native pilot.

MJX (impl ``jax``) allocates a contact slot for every candidate geom pair
(6446 for the SIGGRAPH scene), and every step pays for all of them. Its MJCF
numerics ``max_geom_pairs`` (pairs kept per collision-function group; mwbx's
step, :mod:`mwbx.batch_sim.mjx_collision`, keeps those whose world bounding
boxes are nearest) and ``max_contact_points`` (contacts kept per condim
group, the most penetrating) bound that work. MuJoCo Warp (impl
``warp``) has fixed contact and constraint pools, ``nconmax`` and ``njmax``
per world. A pilot runs a few worlds of the config on the native backend
(MuJoCo C; :func:`mwbx.batch_sim.sampler.pilot_counts`); :func:`count_frames`
replays their recorded frames and counts what those caps must hold;
:func:`budget_from_counts` adds headroom and :func:`given` reads the values a
config sets (:func:`mwbx.batch_sim.sampler.resolve_contact_budget` puts them
together).

A budget trades exactness for speed only where it can be seen: a world whose
step may have needed more than the budget is flagged
(``FLAG_CONTACT_OVERFLOW``). :class:`JaxOverflowCheck` decides it on impl
``jax`` from what MJX kept (conservatively: it never misses a dropped active
contact); :func:`warp_overflow` reads MuJoCo Warp's own overflow counters.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import collision_driver

from mwbx.batch_sim.mjx_collision import GAP_TOLERANCE, box_gap, world_boxes
from mwbx import scene as scene_lib

# Slack added on top of headroom × measured: a pilot of a few worlds sees
# fewer peaks than a run of thousands.
MIN_SLACK_PAIRS = 4
MIN_SLACK_CONTACTS = 8
MIN_SLACK_ROWS = 16
MIN_SLACK_DOFS = 12
# A distance this close to a margin counts as within it (float32 rounding).
DIST_TOLERANCE = GAP_TOLERANCE


class ContactBudget(NamedTuple):
  """Contact capacity of the batched engines for one scene.

  Attributes:
    max_contact_points: impl jax: contacts kept per condim group, per world.
    max_geom_pairs: impl jax: geom pairs kept per collision-function group
      (planes and height fields are never culled), per world.
    nconmax: impl warp: contacts (and broadphase candidates) per world; the
      pool of a batch of W worlds holds ``W * nconmax``.
    njmax: impl warp: constraint rows per world.
    source: where the numbers came from, e.g. ``pilot (8 worlds, headroom
      1.5)``, ``config`` or ``config + pilot (...)``.
    nvmax: impl warp with sleep: degrees of freedom awake at once per world
      (MuJoCo Warp compacts the awake ones into this many; its Newton solver
      then works on nvmax x nvmax, not nv x nv); 0: the model's nv (no sleep).
  """

  max_contact_points: int
  max_geom_pairs: int
  nconmax: int
  njmax: int
  source: str
  nvmax: int = 0

  def describe(self) -> str:
    """One line for ``mwbx info`` and the run summary."""
    awake = f", nvmax {self.nvmax}" if self.nvmax else ""
    return (f"max_contact_points {self.max_contact_points}, max_geom_pairs {self.max_geom_pairs}"
            f" (jax); nconmax {self.nconmax}, njmax {self.njmax}{awake} per world (warp); from {self.source}")

  @classmethod
  def from_dict(cls, record: dict) -> "ContactBudget":
    """The budget of a run record (records from before ``nvmax`` have none: 0)."""
    return cls(**{k: (str(record[k]) if k == "source" else int(record[k]))
                  for k in cls._fields if k in record or k not in cls._field_defaults})


class PilotCounts(NamedTuple):
  """Most contacts any recorded frame of the pilot worlds needed.

  Attributes:
    geom_pairs: geom pairs whose world bounding boxes came within their
      margin, in one cullable collision-function group of MJX.
    contact_points: contact points MJX may keep active in one condim group:
      ``ncon`` of its collision function (the points it emits per pair, 2 to
      4; duplicates included) for each geom pair MuJoCo C has in contact.
    candidates: geom pairs in one world up to the farthest, by bounding
      sphere, whose boxes come within their margin, plane and height-field
      pairs included (MuJoCo Warp's broadphase).
    contacts: active contacts in one world.
    rows: constraint rows (``nefc``) in one world.
    worlds: pilot worlds run; frames: frames replayed.
    awake_dofs: where the scene sleeps, the most degrees of freedom awake
      at once in one pilot world (:func:`awake_dofs`); 0 where it does not.
    dofs: the model's nv (the most ``nvmax`` can be).
  """

  geom_pairs: int
  contact_points: int
  candidates: int
  contacts: int
  rows: int
  worlds: int
  frames: int
  awake_dofs: int = 0
  dofs: int = 0


class _PairGroup(NamedTuple):
  """One collision-function group of MJX: geom1, geom2 i32[P], margin f32[P]."""

  geom1: np.ndarray
  geom2: np.ndarray
  margin: np.ndarray
  cullable: bool
  ncon: int
  condim: int


def _pair_groups(m: mujoco.MjModel) -> list[_PairGroup]:
  """MJX's collision-function groups of ``m`` (the grouping its collision driver uses)."""
  out = []
  for key, pairs in collision_driver._geom_groups(m).items():  # pylint: disable=protected-access
    geom = np.asarray(pairs, np.int64).reshape(-1, 3)
    g1, g2, ip = geom[:, 0], geom[:, 1], geom[:, 2]
    margin = np.where(ip >= 0, m.pair_margin[np.maximum(ip, 0)] if m.npair else 0.0,
                      m.geom_margin[g1] + m.geom_margin[g2])
    cullable = not set(int(t) for t in key.types) & {int(t) for t in collision_driver._GEOM_NO_BROADPHASE}  # pylint: disable=protected-access
    func = collision_driver._COLLISION_FUNC.get(key.types)  # pylint: disable=protected-access
    ncon = func.ncon if func is not None else int(m.opt.sdf_initpoints)
    out.append(_PairGroup(g1, g2, margin.astype(np.float64), cullable, int(ncon), int(key.condim)))
  return out


def _pairs_needed(g: _PairGroup, boxes) -> int:
  """Pairs MJX must keep in group ``g`` so that none that can touch is
  dropped: those whose world boxes, grown by the margin, overlap (the step
  keeps the nearest by box gap). ``boxes``: ``world_boxes`` of the frame."""
  return int((box_gap(g.geom1, g.geom2, *boxes, g.margin) <= GAP_TOLERANCE).sum())


def _sphere_rank_needed(m: mujoco.MjModel, d: mujoco.MjData, g: _PairGroup, boxes) -> int:
  """Candidates of group ``g`` by bounding-sphere distance up to the farthest
  pair whose boxes overlap (MuJoCo Warp's pool holds its broadphase's
  candidates; sized so since the first pilot)."""
  gap = np.linalg.norm(d.geom_xpos[g.geom2] - d.geom_xpos[g.geom1], axis=-1) - (
      m.geom_rbound[g.geom1] + m.geom_rbound[g.geom2])
  near = box_gap(g.geom1, g.geom2, *boxes, g.margin) <= GAP_TOLERANCE
  return int((gap <= gap[near].max()).sum()) if near.any() else 0


def count_frames(scene, bank) -> PilotCounts:
  """Counts, over every recorded frame of ``bank``'s worlds (a pilot run on
  the native backend), what MJX's and MuJoCo Warp's caps must hold.

  Args:
    scene: the :class:`mwbx.scene.Scene` the worlds were sampled from.
    bank: the pilot worlds (:func:`mwbx.batch_sim.sampler.pilot_counts`).

  Returns:
    the :class:`PilotCounts`.
  """
  m = scene.model
  d = mujoco.MjData(m)
  groups = _pair_groups(m)
  # Each geom pair's (points MJX emits for it, condim group).
  emits = {(int(a), int(b)): (g.ncon, g.condim) for g in groups for a, b in zip(g.geom1, g.geom2)}
  counts = np.zeros(5, np.int64)  # geom_pairs, contact_points, candidates, contacts, rows
  frames = 0
  for world_id in bank.world_ids:
    for qpos in bank.qpos_frames(int(world_id)):
      d.qpos[:] = qpos
      mujoco.mj_fwdPosition(m, d)
      frames += 1
      boxes = world_boxes(d.geom_xpos, d.geom_xmat, m.geom_aabb)
      near = [_pairs_needed(g, boxes) for g in groups]
      cullable = [n for n, g in zip(near, groups) if g.cullable]
      candidates = sum(_sphere_rank_needed(m, d, g, boxes) for g in groups)
      points = np.zeros(7, np.int64)
      for a, b in {(int(min(p)), int(max(p))) for p in d.contact.geom[:d.ncon]}:
        ncon, condim = emits.get((a, b), emits.get((b, a), (4, 3)))
        points[condim] += ncon
      per_condim = int(points.max())
      counts = np.maximum(counts, [max(cullable, default=0), per_condim, candidates, d.ncon, d.nefc])
  return PilotCounts(*(int(c) for c in counts), worlds=bank.n_worlds, frames=frames)


def awake_dofs(model: mujoco.MjModel, qpos0: np.ndarray, qvel0: np.ndarray, n_steps: int) -> int:
  """The most degrees of freedom ``model`` (sleep enabled) has awake at once
  (``nv_awake``) over ``n_steps`` plain steps of each world from its initial
  state (qpos0 f64[W, nq], qvel0 f64[W, nv]): what MuJoCo Warp's ``nvmax``
  must hold. Without the perturbations (they move which blocks a world
  knocks down, not how many a hit wakes: the headroom covers it). A step
  over it is flagged (MuJoCo Warp's ``NVMAX`` overflow, :data:`WARP_DROPPED`)."""
  data = mujoco.MjData(model)
  most = 0
  for q, v in zip(qpos0, qvel0):
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:] = q, v
    for _ in range(n_steps):
      mujoco.mj_step(model, data)
      most = max(most, int(data.nv_awake))
  return most


def budget_from_counts(counts: PilotCounts, headroom: float, overrides: dict | None = None,
                       source: str | None = None) -> ContactBudget:
  """A budget of ``headroom`` × the pilot's counts plus a fixed slack; values
  in ``overrides`` (from the config) win."""
  size = lambda n, slack: int(max(math.ceil(headroom * n), n + slack))
  budget = {
      "max_geom_pairs": size(counts.geom_pairs, MIN_SLACK_PAIRS),
      "max_contact_points": size(counts.contact_points, MIN_SLACK_CONTACTS),
      "nconmax": size(max(counts.candidates, counts.contacts), MIN_SLACK_CONTACTS),
      "njmax": size(counts.rows, MIN_SLACK_ROWS),
      "nvmax": min(size(counts.awake_dofs, MIN_SLACK_DOFS), counts.dofs) if counts.awake_dofs else 0,
  }
  given = {k: v for k, v in (overrides or {}).items() if v is not None and k in budget}
  budget.update(given)
  pilot_source = source or f"pilot ({counts.worlds} worlds, {counts.frames} frames, headroom {headroom:g})"
  label = pilot_source if not given else f"config ({', '.join(sorted(given))}) + {pilot_source}"
  return ContactBudget(source=label, **{k: int(v) for k, v in budget.items()})


def given(settings) -> dict:
  """The budget values the config's :class:`mwbx.config.MjxSection` sets
  (None: left to the pilot)."""
  return {k: getattr(settings, k) for k in ("max_contact_points", "max_geom_pairs", "nconmax", "njmax")}


def budgeted_model(scene, budget: ContactBudget, timestep: float | None = None) -> mujoco.MjModel:
  """The scene's model with MJX's ``max_geom_pairs`` and ``max_contact_points``
  numerics (MJX reads them from the model; nothing else changes)."""
  spec = scene_lib.parse_mjcf(scene.mjcf_text, scene.mjcf_dir, scene.mjcf_includes, scene.mjcf_assets)
  for numeric in list(spec.numerics):
    if numeric.name in ("max_geom_pairs", "max_contact_points"):
      spec.delete(numeric)
  spec.add_numeric(name="max_geom_pairs", data=[budget.max_geom_pairs])
  spec.add_numeric(name="max_contact_points", data=[budget.max_contact_points])
  for sensor in list(spec.sensors):
    spec.delete(sensor)
  for body in scene.body_names:
    for name, sensor_type, _ in scene_lib.SENSORS:
      spec.add_sensor(name=f"mwbx_{name}_{body}", type=sensor_type, objtype=mujoco.mjtObj.mjOBJ_BODY,
                      objname=body)
  m = spec.compile()
  m.opt.timestep = scene.model.opt.timestep if timestep is None else timestep
  return m


class JaxOverflowCheck:
  """Whether a step of MJX (impl ``jax``) under a budget may have dropped an
  active contact, from the contacts it kept.

  Two caps can drop contacts. Geom pairs: a cullable group of P > cap pairs
  keeps the cap pairs whose world bounding boxes are nearest
  (:func:`mjx_collision.box_gap`); a dropped pair can touch only if its boxes,
  grown by the margin, overlap, i.e. only if more than cap pairs overlap.
  Contact points: a condim group keeps the ``cap`` most penetrating contacts;
  a dropped active contact lies within the group's largest margin, and then
  so does every kept one. Flagging when either count is reached never misses
  a dropped contact (and may flag a world that lost none).

  Args:
    m: the budgeted model (with the numerics MJX reads).
  """

  def __init__(self, m: mujoco.MjModel):
    numeric = lambda name: collision_driver._numeric(m, name)  # pylint: disable=protected-access
    pair_cap, point_cap = numeric("max_geom_pairs"), numeric("max_contact_points")
    self.pair_cap, self.point_cap = pair_cap, point_cap
    groups = _pair_groups(m)
    self.aabb = np.asarray(m.geom_aabb, np.float32)
    # Geom-pair groups the cap culls: their pairs and margins.
    self.culled = [(g.geom1, g.geom2, g.margin.astype(np.float32))
                   for g in groups if g.cullable and pair_cap > -1 and len(g.geom1) > pair_cap]
    # Condim groups the contact cap truncates: their slice of MJX's contact array.
    emitted: dict[int, int] = {}
    margin: dict[int, float] = {}
    for g in groups:
      pairs = min(len(g.geom1), pair_cap) if g.cullable and pair_cap > -1 else len(g.geom1)
      emitted[g.condim] = emitted.get(g.condim, 0) + g.ncon * pairs
      margin[g.condim] = max(margin.get(g.condim, 0.0), float(g.margin.max()))
    self.slices = []
    start = 0
    for condim in sorted(emitted):
      kept = min(point_cap, emitted[condim]) if point_cap > -1 else emitted[condim]
      if kept < emitted[condim]:
        self.slices.append((start, start + kept, margin[condim]))
      start += kept
    self.ncon = start

  @property
  def can_overflow(self) -> bool:
    return bool(self.culled or self.slices)

  def __call__(self, d) -> jax.Array:
    """bool[] for one world's ``mjx.Data`` after ``mjx_collision.step`` (its
    contacts and ``geom_xpos`` are those of the step's start state); vmap it
    for a batch."""
    flag = jnp.bool_(False)
    if self.culled:
      boxes = world_boxes(d.geom_xpos, d.geom_xmat, jnp.asarray(self.aabb))
    for g1, g2, margin in self.culled:
      overlapping = jnp.sum(box_gap(g1, g2, *boxes, jnp.asarray(margin)) <= GAP_TOLERANCE)
      flag |= overlapping > self.pair_cap
    if self.slices:
      dist = d._impl.contact.dist  # pylint: disable=protected-access
      for lo, hi, margin in self.slices:
        flag |= jnp.sum(dist[lo:hi] < margin + DIST_TOLERANCE) >= hi - lo
    return flag


# MuJoCo Warp's OverflowType bits that mean contacts or constraints were
# dropped: NEFC, NJMAX_NNZ, BROADPHASE, NARROWPHASE, CCD, HFIELD, NVMAX (not
# the solver's iteration limits).
WARP_DROPPED = 1 | 2 | 4 | 8 | 16 | 32 | 128


def warp_overflow(d) -> jax.Array:
  """bool[W] of a batched MuJoCo Warp ``mjx.Data``: an overflow counter was set
  (constraint rows of that world; contact pool overflows set every world's,
  since the pool is shared and which world lost a contact is not known)."""
  return (d._impl.overflow & WARP_DROPPED) != 0  # pylint: disable=protected-access


def quiet_warp() -> None:
  """Silences Warp's module-load messages (MuJoCo Warp's overflow prints are
  turned off per model: ``opt.warn_overflow = 0``)."""
  import warp
  warp.config.quiet = True
  if hasattr(warp.config, "log_level") and hasattr(warp, "LOG_WARNING"):
    warp.config.log_level = warp.LOG_WARNING
