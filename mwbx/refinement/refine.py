"""Refinement (paper §5): resample only the objects a user marks, from t_min.

``refine(bank, world, objects, t_min=… | frustum=…, n_samples, key)`` picks
the parent world's stored state at t_min (decoded ``qpos``, ``qvel`` by
differentiating the decoded path), simulates the marked objects with fresh
perturbations, replays every other object's stored motion, and activates an
object as soon as an active object or a ghost of one may touch it (see
:mod:`mwbx.refinement.interactions` and :mod:`mwbx.refinement.loop`).

The new worlds are ordinary bank worlds: frames before t_min are the
parent's, then the new motion; objects never activated keep the parent's
decoded path, COM polylines and metrics exactly. They get new world ids;
their lineage (parent id, t_min, objects asked for, final active set) is in
``bank.lineage`` under the new id, plus ``parent_world``/``refine_time``
columns.

Objects can be added and removed at t_min (paper §5, the refrigerator toy):
an added object (of a later scene version, :mod:`mwbx.bank.versions`) is
inserted into the active set at its configured initial state; a removed one
is parked, colliding with nothing, while its ghost stays, so the objects it
used to touch become active.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import secrets
import time
from typing import NamedTuple, Sequence

import jax

from mwbx import bank as bank_lib
from mwbx.batch_sim import mujoco_c
from mwbx.batch_sim.sampler import MAX_WORLD_ID, Sampler, check_chunk_memory
from mwbx.config import Config, load_config
from mwbx.errors import MwbxError
from mwbx.queries import first_entry
from mwbx.refinement import runners
from mwbx.refinement.plan import RefinePlan, RefineStats, run_plan  # noqa: F401 (RefineStats re-exported)
from mwbx.scene import Scene, objects_of

DEFAULT_MARGIN = 0.01  # m, contact margin of the interaction test


def resolve_objects(bank, objects: str | Sequence[str], field: str = "objects",
                    required: bool = True) -> tuple[str, ...]:
  """Object names for object or group names (``object:``/``group:`` prefixes
  allowed; MwbxError naming an unknown one)."""
  if objects is None:
    objects = ()
  if isinstance(objects, str):
    objects = [o for o in objects.split(",") if o]
  out: list[str] = []
  for name in objects:
    try:
      members = objects_of(name, tuple(bank.objects), bank.groups, field, "refine")
    except MwbxError as err:
      if field != "add":
        raise
      raise MwbxError(f"{err}; to add an object, give the scene version that has it (scene=, mwbx refine"
                      " --scene NEW.yaml)") from None
    out.extend(m for m in members if m not in out)
  if required and not out:
    raise MwbxError("refine: objects: name at least one object or group to refine")
  return tuple(out)


def _resolve_changes(bank, world: int, names, added, removed, t_min: float):
  """The objects already gone from world ``world`` at t_min (removed by an
  ancestor, or of a later scene version) and not added back; MwbxError if an
  object to add is there, or one to refine or remove is not."""
  if not (names or added or removed):
    raise MwbxError("refine: name objects to refine, add or remove")
  absent = bank.absent(world)
  gone = {o for o, (since, until) in absent.items() if since <= t_min + 1e-9 < until}
  for o in added:
    if o not in gone:
      raise MwbxError(f"refine: add: object {o!r} is already in world {world} at {t_min:g} s"
                      + ("" if o in absent else " (to add an object, refine with a scene version that has it:"
                         " scene=/--scene)"))
  for o in removed + names:
    if o in gone:
      raise MwbxError(f"refine: {'remove' if o in removed else 'objects'}: object {o!r} is not in world "
                      f"{world} at {t_min:g} s")
  for a, b, what in ((names, added, "add"), (names, removed, "remove"), (added, removed, "remove")):
    both = [o for o in a if o in b]
    if both:
      raise MwbxError(f"refine: {what}: {', '.join(both)} also named elsewhere; name each object once")
  return tuple(o for o in bank.objects if o in gone and o not in added)


def resolve_t_min(bank, world: int, objects: tuple[str, ...], frustum=None, t_min: float | None = None,
                  row: int | None = None) -> float:
  """t_min in seconds: given, or the first time an object's COM enters ``frustum``
  (``row``: the world's bank row, if known)."""
  if (frustum is None) == (t_min is None):
    raise MwbxError("refine: give exactly one of frustum (a screen box through a camera) or t_min")
  row = bank.row_of(world) if row is None else row
  last = (int(bank.frame_count[row]) - 1) / bank.record_fps
  if frustum is not None:
    t_min = first_entry(bank, world, list(objects), frustum)
    if t_min is None:
      raise MwbxError(f"refine: no object of {', '.join(objects)} enters the box in world {world}")
  t_min = float(t_min)
  if not (math.isfinite(t_min) and 0.0 <= t_min <= last + 1e-9):
    raise MwbxError(f"refine: t_min {t_min:g} s is outside world {world}'s recording [0, {last:g}] s")
  return t_min


class RefineRequest(NamedTuple):
  """What to refine: the one argument of :func:`run_refinement` (and of :func:`refine`).

  Attributes:
    world: the parent's world id.
    objects: object or group names (a list, or one comma-separated string);
      may be empty when objects are added or removed.
    t_min: the restart time in seconds (rounded down to a recorded frame); or
    frustum: a :class:`mwbx.queries.Frustum` (e.g. ``camera.frustum(box)``):
      t_min is the first time any of the objects' COM is inside it.
    n_samples: refined worlds to make.
    key: run key; refined world i draws from ``fold_in(key, i)``. None: a fresh
      random key, so repeating a refinement gives new worlds.
    backend: ``auto`` | ``native`` | ``mjx`` (default: the config's).
    chunk_size: worlds per lockstep batch.
    margin: contact margin of the interaction test, m (larger is safer).
    playback: native backend only: ``step`` (default) puts inactive objects
      on their stored path before every physics step; ``frame`` only at every
      frame boundary (a few per cent cheaper; inside a frame they move freely
      from the stored state, touching nothing). MJX always does it every step.
    loop: native backend, ``playback="step"``: ``auto`` | ``compiled`` (each
      refined world in compiled calls, the fast path) | ``lockstep``
      (``mujoco.rollout`` a step at a time).
    scene: a later version of the bank's scene (a :class:`mwbx.Scene`, a
      :class:`mwbx.config.Config` or a config file path) holding the objects
      to ``add``; the bank moves to it first, every world kept.
    add: objects (of ``scene``) inserted into the active set at t_min, at
      their configured initial state (randomized per refined world).
    remove: objects taken out at t_min: parked, colliding with nothing; their
      ghosts stay, so the objects they used to touch are resimulated.
    events: find the refined worlds' contact events (default). False: the
      new worlds have none (``Refinement.new.events`` is None), for a caller
      that keeps a few of many and finds theirs (``solve`` without event
      queries: :meth:`mwbx.Sampler.events_of`).
  """

  world: int
  objects: str | Sequence[str] = ()
  t_min: float | None = None
  frustum: object = None
  n_samples: int = 32
  key: jax.Array | None = None
  backend: str | None = None
  chunk_size: int | None = None
  margin: float = DEFAULT_MARGIN
  playback: str = "step"
  loop: str = "auto"
  scene: object = None
  add: str | Sequence[str] = ()
  remove: str | Sequence[str] = ()
  events: bool = True


def plan_refinement(bank, request: RefineRequest) -> RefinePlan:
  """Resolves and checks a refinement of ``bank`` (its ``scene`` already moved to, if any).

  Raises:
    MwbxError: naming the argument or value that cannot be refined.
  """
  world, objects, frustum, t_min, n_samples, key, backend, chunk_size, margin, playback, loop, add, remove = (
      request.world, request.objects, request.frustum, request.t_min, request.n_samples, request.key,
      request.backend, request.chunk_size, request.margin, request.playback, request.loop, request.add,
      request.remove)
  world = int(world)
  try:
    row = bank.row_of(world)
  except MwbxError as err:
    raise MwbxError(f"refine: {err}") from None
  if key is None:  # fresh randomness: repeating a refinement gives new worlds
    key = jax.random.key(secrets.randbits(63))
  if not bank.valid[row]:
    raise MwbxError(f"refine: world {world} went unstable while sampling; refine a stable world")
  if n_samples < 1:
    raise MwbxError(f"refine: n_samples must be at least 1, got {n_samples}")
  if playback not in ("frame", "step"):
    raise MwbxError(f"refine: playback must be 'frame' or 'step', got {playback!r}")
  if not margin >= 0:
    raise MwbxError(f"refine: margin must be >= 0 m, got {margin!r}")
  if loop not in ("auto", "compiled", "lockstep"):
    raise MwbxError(f"refine: loop must be 'auto', 'compiled' or 'lockstep', got {loop!r}")
  if loop == "compiled" and not mujoco_c.available():
    raise MwbxError("refine: loop='compiled' needs MuJoCo's C library bound for numba; use 'lockstep'")
  names = resolve_objects(bank, objects, required=not (add or remove))
  added = resolve_objects(bank, add, "add", required=False)
  removed = resolve_objects(bank, remove, "remove", required=False)
  t_min = resolve_t_min(bank, world, names or added or removed, frustum, t_min, row=row)
  # Objects already gone at t_min stay out: colliding with nothing even if
  # something activates them.
  gone = _resolve_changes(bank, world, names, added, removed, t_min)
  sampler = sampler_for(bank, backend)
  runners.runner_for(sampler).check(sampler.scene.model, removed, gone)
  f0 = int(math.floor(t_min * bank.record_fps + 1e-6))
  if f0 >= sampler.n_frames:
    raise MwbxError(f"refine: t_min {t_min:g} s is at or past the end time")
  chunk = int(min(chunk_size or sampler.scene.config.sim.chunk_size, n_samples))
  if bank.next_world_id + n_samples - 1 > MAX_WORLD_ID:
    raise MwbxError(f"refine: {n_samples:,} refined worlds from id {bank.next_world_id:,} would pass the last"
                    f" world id {MAX_WORLD_ID:,}")
  try:  # the refined worlds are kept in one bank in memory until they are saved
    check_chunk_memory(sampler.scene, chunk, n_samples)
  except MwbxError as err:
    raise MwbxError(f"refine: n_samples {n_samples:,}: {err}") from None
  return RefinePlan(
      world=world, row=row, objects=names, added=added, removed=removed, gone=gone, t_min=t_min, first_frame=f0,
      n_samples=n_samples, chunk=chunk,
      key=key, backend=backend, playback=playback,
      compiled_loop=loop == "compiled" or (loop == "auto" and mujoco_c.available()), margin=margin,
      # An added object puts a world in the bank's current scene version.
      scene_version=len(bank.versions) if added else int(bank.scene_version[row]),
      first_id=bank.next_world_id, bounds=sampler.scene.config.codec.bounds(),
      contact_budget=bank.run.get("contact_budget"), events=bool(request.events))


_SAMPLERS: dict = {}


def sampler_for(bank, backend: str | None = None) -> Sampler:
  """A sampler for the bank's scene, kept for later refinements of that scene
  (its thread pool and compiled kernels are reused)."""
  # MJX refines under the contact budget and mjx:warp's solver settings its bank was sampled with, if any.
  budget, warp_solver = bank.run.get("contact_budget"), bank.run.get("warp_solver")
  # The native engine sleeps as the bank's worlds did (off for banks sampled without sleep).
  sleep = bank.run.get("sleep") or {"enabled": False, "tolerance": 1e-3, "reason": "the bank was sampled awake"}
  frozen = lambda record: None if record is None else tuple(sorted(record.items()))
  cache_key = (_stored_scene_key(bank), backend, frozen(budget), frozen(warp_solver), frozen(sleep))
  if cache_key not in _SAMPLERS:
    if len(_SAMPLERS) >= 4:
      _SAMPLERS.pop(next(iter(_SAMPLERS))).close()
    _SAMPLERS[cache_key] = Sampler(bank.scene(), backend, contact_budget=budget, warp_solver=warp_solver,
                                   sleep=sleep)
  return _SAMPLERS[cache_key]


def _stored_scene_key(bank) -> str:
  """A hash of what the bank's scene is built from (its stored config, MJCF
  text, included files and folder), not of the digest it claims: a bank
  whose stored text differs from one refined before builds, and checks, its
  own scene."""
  digest = hashlib.sha256()
  for part in (json.dumps(bank.config, sort_keys=True, default=str), bank.mjcf_text,
               json.dumps(bank.mjcf_includes, sort_keys=True, default=str), str(bank.mjcf_dir())):
    digest.update(part.encode())
    digest.update(b"\0")
  return digest.hexdigest()


def refine(bank, world, objects=(), *, progress=None, **fields):
  """Resamples the marked objects of one world from t_min on (paper §5).

  Args:
    bank: the bank holding the parent world.
    world: the parent's world id, or a whole :class:`RefineRequest`.
    objects: object or group names (a list, or one comma-separated string).
    progress: optional callback taking a :class:`mwbx.progress.Progress`.
    **fields: the other :class:`RefineRequest` fields (``t_min`` or
      ``frustum``, ``n_samples``, ``key``, ``backend``, ``scene``, ``add``,
      ``remove``, ...).

  Returns:
    ``bank`` (in ``scene``'s version if given) with the refined worlds
    appended, with new ids from ``bank.next_world_id`` on, each with
    ``parent_world``, ``refine_time`` and ``lineage`` entries
    (``bank.children(world)`` lists them; ``added``/``removed`` name the
    objects changed, ``bank.absent(id)`` when they are not there).

  Raises:
    MwbxError: unknown object, unknown world id, unstable parent, t_min
      outside the recording, a box the objects never enter, an object to add
      that is already there or to remove that is not, or a scene that is not a
      later version of the bank's.

  Example:
    >>> bank = mwbx.refine(bank, 4, "ball", t_min=1.0, n_samples=16)
    >>> bank = mwbx.refine(bank, 4, scene="configs/refrigerator_toy_block.yaml", add="block", t_min=0.0,
    ...                    n_samples=16)
  """
  request = world if isinstance(world, RefineRequest) else RefineRequest(world, objects, **fields)
  return run_refinement(bank, request, progress).bank


@dataclasses.dataclass(frozen=True)
class Refinement:
  """What one refinement made (:func:`run_refinement`; what ``mwbx refine`` reports).

  Attributes:
    parent_bank: the bank refined (in ``scene``'s version if given).
    new: the refined worlds alone (ids from the bank's ``next_world_id`` on).
    stats: timing and perturbation audit.
    plan: the refinement as resolved (objects, t_min, frame, key, ...).
    scene_version: the scene version the bank moved to for ``scene``; None:
      it stayed in its own.
  """

  parent_bank: bank_lib.Bank
  new: bank_lib.Bank
  stats: RefineStats
  plan: RefinePlan
  scene_version: int | None

  @property
  def bank(self) -> bank_lib.Bank:
    """The bank with the refined worlds appended (made on each access)."""
    return self.parent_bank.append(self.new)


def run_refinement(bank, request: RefineRequest, progress=None) -> Refinement:
  """The one refinement entry: moves the bank to ``request.scene`` if given,
  resolves and checks the request (:func:`plan_refinement`), runs it on the
  bank scene's sampler and returns what it made.

  Example::

    done = run_refinement(bank, RefineRequest(4, "ball", t_min=1.0, n_samples=16))
    done.new.world_ids, done.stats.world_steps
  """
  start_wall = time.perf_counter()
  moved = None
  if request.scene is not None:
    before = bank.digest
    bank = bank.with_scene(as_scene(request.scene), progress)
    moved = len(bank.versions) if bank.digest != before else None
  plan = plan_refinement(bank, request)
  new, stats = run_plan(bank, plan, sampler_for(bank, plan.backend), progress, start_wall)
  return Refinement(parent_bank=bank, new=new, stats=stats, plan=plan, scene_version=moved)


def as_scene(scene):
  """A :class:`mwbx.Scene` from a Scene, a Config or a config file path."""
  if isinstance(scene, Scene):
    return scene
  if isinstance(scene, Config):
    return Scene(scene)
  return Scene(load_config(scene))
