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
import math
import secrets
import time
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import bank as bank_lib
from mwbx.batch_sim import controls
from mwbx.batch_sim import mujoco_c
from mwbx.batch_sim import rows as rows_lib
from mwbx.batch_sim import world as world_lib
from mwbx.bank.versions import parked_columns, parked_qpos
from mwbx.batch_sim.sampler import Sampler, SampleStats, world_keys
from mwbx.errors import MwbxError
from mwbx.progress import Progress
from mwbx.joints import DOF_WIDTH, QPOS_WIDTH
from mwbx.refinement import interactions, kinematic
from mwbx.scene import objects_of
from mwbx.refinement import loop as refine_loop
from mwbx.refinement import runners

DEFAULT_MARGIN = 0.01  # m, contact margin of the interaction test


def _scene_of(bank):
  from mwbx.config import config_from_dict
  from mwbx.scene import Scene
  data = dict(bank.config)
  data.pop("source", None)
  scene = Scene(config_from_dict(data, source="<bank config>"), mjcf_text=bank.mjcf_text,
                mjcf_includes=bank.mjcf_includes,
                mjcf_dir=bank.mjcf_dir())
  if scene.body_names != tuple(bank.body_names):
    raise MwbxError("refine: the bank's tracked bodies do not match its own config")
  return scene


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
    from mwbx.queries import first_entry
    t_min = first_entry(bank, world, list(objects), frustum)
    if t_min is None:
      raise MwbxError(f"refine: no object of {', '.join(objects)} enters the box in world {world}")
  t_min = float(t_min)
  if not (math.isfinite(t_min) and 0.0 <= t_min <= last + 1e-9):
    raise MwbxError(f"refine: t_min {t_min:g} s is outside world {world}'s recording [0, {last:g}] s")
  return t_min


def object_coordinates(model: mujoco.MjModel, object_names) -> tuple[np.ndarray, np.ndarray]:
  """(bool[O, nq], bool[O, nv]) coordinates of each object's joints."""
  qm = np.zeros((len(object_names), model.nq), bool)
  vm = np.zeros((len(object_names), model.nv), bool)
  for o, name in enumerate(object_names):
    root = model.body(name).id
    for j in range(model.njnt):
      if model.body_rootid[model.jnt_bodyid[j]] == root:
        t = int(model.jnt_type[j])
        qm[o, model.jnt_qposadr[j]:model.jnt_qposadr[j] + QPOS_WIDTH[t]] = True
        vm[o, model.jnt_dofadr[j]:model.jnt_dofadr[j] + DOF_WIDTH[t]] = True
  return qm, vm


@dataclasses.dataclass
class RefineStats(SampleStats):
  """Timing of a refinement run, plus per refined world the largest applied
  ``‖perturbation‖ / (α‖Δv‖)`` (at most 1) and the perturbations drawn for
  inactive bodies (always 0); ``first_frame`` is the frame at t_min."""

  first_frame: int = 0
  max_perturbation_ratio: np.ndarray | None = None
  inactive_perturbations: np.ndarray | None = None


class RefinePlan(NamedTuple):
  """One refinement resolved against its bank, checked: what the loops take.

  Attributes:
    world: the parent's world id; row: its bank row.
    objects: objects asked for (refined from t_min).
    added: objects inserted at t_min; removed: objects taken out at t_min.
    gone: objects already absent from the parent at t_min, kept out.
    t_min: the restart time asked for, s (the worlds restart at
      ``first_frame``, t_min rounded down to a recorded frame).
    first_frame: f0, the frame at t_min.
    n_samples: refined worlds to make; chunk: worlds per lockstep batch.
    key: the run key (refined world i draws from ``fold_in(key, i)``).
    backend: the backend asked for (None: the config's).
    playback: ``step`` | ``frame``; compiled_loop: native ``step`` playback
      runs each world in compiled calls.
    margin: contact margin of the interaction test, m.
    scene_version: the new worlds' scene version (the bank's current one when
      objects are added, else the parent's).
    first_id: the first new world's id.
    bounds: the codec's (e_pos m, e_rot rad, e_scalar) error bounds.
    contact_budget: the MJX contact budget the bank was sampled with (None: none).
  """

  world: int
  row: int
  objects: tuple[str, ...]
  added: tuple[str, ...]
  removed: tuple[str, ...]
  gone: tuple[str, ...]
  t_min: float
  first_frame: int
  n_samples: int
  chunk: int
  key: jax.Array
  backend: str | None
  playback: str
  compiled_loop: bool
  margin: float
  scene_version: int
  first_id: int
  bounds: tuple[float, float, float]
  contact_budget: dict | None


def plan_refinement(bank, world: int, objects, *, frustum=None, t_min: float | None = None, n_samples: int,
                    key: jax.Array | None = None, backend: str | None = None, chunk_size: int | None = None,
                    margin: float = DEFAULT_MARGIN, playback: str = "step", loop: str = "auto",
                    add=(), remove=()) -> RefinePlan:
  """Resolves and checks a refinement of ``bank`` (arguments as :func:`refine_run`).

  Raises:
    MwbxError: naming the argument or value that cannot be refined.
  """
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
  codec = sampler.scene.config.codec
  return RefinePlan(
      world=world, row=row, objects=names, added=added, removed=removed, gone=gone, t_min=t_min, first_frame=f0,
      n_samples=n_samples, chunk=int(min(chunk_size or sampler.scene.config.sim.chunk_size, n_samples)),
      key=key, backend=backend, playback=playback,
      compiled_loop=loop == "compiled" or (loop == "auto" and mujoco_c.available()), margin=margin,
      # An added object puts a world in the bank's current scene version.
      scene_version=len(bank.versions) if added else int(bank.scene_version[row]),
      first_id=bank.next_world_id, bounds=(codec.e_pos, float(np.deg2rad(codec.e_rot_deg)), codec.e_scalar),
      contact_budget=bank.run.get("contact_budget"))


def refine_run(bank, world: int, objects, *, frustum=None, t_min: float | None = None, n_samples: int,
               key: jax.Array | None = None, backend: str | None = None, chunk_size: int | None = None,
               margin: float = DEFAULT_MARGIN, playback: str = "step", loop: str = "auto", progress=None,
               add=(), remove=()):
  """:func:`refine` that also returns :class:`RefineStats` and only the new worlds.

  The bank must already be in the scene version holding objects to ``add``
  (:meth:`mwbx.Bank.with_scene`; :func:`refine` does that from ``scene=``).

  ``loop`` (native backend, ``playback="step"``): ``compiled`` runs each
  refined world in compiled calls (:mod:`mwbx.refinement.world_loop`),
  ``lockstep`` steps the batch through ``mujoco.rollout`` a step at a time
  (:func:`mwbx.refinement.loop.run_native`), ``auto`` the first where
  MuJoCo's C library can be bound.
  """
  start_wall = time.perf_counter()
  plan = plan_refinement(bank, world, objects, frustum=frustum, t_min=t_min, n_samples=n_samples, key=key,
                         backend=backend, chunk_size=chunk_size, margin=margin, playback=playback, loop=loop,
                         add=add, remove=remove)
  return run_plan(bank, plan, progress, start_wall)


_SAMPLERS: dict = {}


def sampler_for(bank, backend: str | None = None) -> Sampler:
  """A sampler for the bank's scene, kept for later refinements of that scene
  (its thread pool and compiled kernels are reused)."""
  # MJX refines under the contact budget its bank was sampled with, if any.
  budget = bank.run.get("contact_budget")
  cache_key = (bank.digest, backend, None if budget is None else tuple(sorted(budget.items())))
  if cache_key not in _SAMPLERS:
    if len(_SAMPLERS) >= 4:
      _SAMPLERS.pop(next(iter(_SAMPLERS))).close()
    _SAMPLERS[cache_key] = Sampler(_scene_of(bank), backend, contact_budget=budget)
  return _SAMPLERS[cache_key]


class _Parent(NamedTuple):
  """The parent world as refinement restarts it (see :func:`_parent_of`)."""

  frames: np.ndarray  # f32[T, nq] its decoded qpos
  path: kinematic.StoredPath
  qpos0: np.ndarray  # f32[nq] state at f0
  qvel0: np.ndarray  # f32[nv]
  metrics0: np.ndarray  # its metrics up to f0
  qpos_object: np.ndarray  # bool[O, nq]
  dof_object: np.ndarray  # bool[O, nv]
  asked: np.ndarray  # bool[O] objects active from t_min


def _parent_of(bank, plan: RefinePlan, sampler) -> _Parent:
  scene, model = sampler.scene, sampler.scene.model
  fps, f0 = bank.record_fps, plan.first_frame
  frame_time = 1.0 / fps
  frames = bank.qpos_store.frames(plan.row)
  path = kinematic.stored_path(model, frames, scene.body_ids, sampler.n_frames + 2, frame_time)
  object_names = tuple(scene.object_names)
  qm, vm = object_coordinates(model, object_names)
  # Added and removed objects are active from t_min: an added one is simulated,
  # a removed one parked, its ghost (stored path) still tested.
  asked = np.array([o in plan.objects or o in plan.added or o in plan.removed for o in object_names])
  qvel0 = np.where(vm[asked].any(axis=0), kinematic.central_velocity(model, path, f0, frame_time), path.qvel[f0])
  cfg = scene.config
  metrics0 = kinematic.prefix_metrics(
      path, f0, frame_time, model.opt.timestep, np.asarray(model.opt.gravity), cfg.rest.linear_speed,
      cfg.rest.angular_speed, cfg.perturb.linear_threshold,
      max(1, int(round(cfg.perturb.collision_gap * fps))))
  return _Parent(frames, path, path.qpos[f0], qvel0, metrics0, qm, vm, asked)


def run_plan(bank, plan: RefinePlan, progress=None, start_wall: float | None = None):
  """Runs a :class:`RefinePlan`: (the new worlds as a bank, :class:`RefineStats`)."""
  start_wall = time.perf_counter() if start_wall is None else start_wall
  sampler = sampler_for(bank, plan.backend)
  runner = runners.runner_for(sampler, plan.playback, plan.compiled_loop)
  scene, params = sampler.scene, sampler.params
  model = scene.model
  spf, f0, n_frames, n_samples, chunk = params.steps_per_frame, plan.first_frame, sampler.n_frames, \
      plan.n_samples, plan.chunk
  parent = _parent_of(bank, plan, sampler)
  object_names = tuple(scene.object_names)
  parked = plan.removed + plan.gone
  extras = runner.loop_extras(scene, parent.path, parked)
  inter = interactions.interaction_params(
      model, scene.body_ids, scene.body_names, scene.objects, object_names, plan.bounds,
      plan.margin, (spf + 1) * model.opt.timestep, scene.config.perturb.alpha)
  params = params if not parked else params._replace(perturbable=jnp.asarray(
      np.asarray(params.perturbable) & ~np.isin(np.asarray(scene.body_names),
                                                 [b for o in parked for b in scene.objects[o]])))
  ctrl = controls.scene_table(scene, n_frames * spf)
  keys, _, step_keys = world_keys(plan.key, np.arange(n_samples, dtype=np.int64))
  start_qpos, start_qvel = _start_states(scene, parent.qpos0, parent.qvel0, parent.qpos_object,
                                         parent.dof_object, object_names, plan.added, plan.removed, keys)
  # Actuator activations at t_min: the same in every world (they follow the controls).
  act0 = controls.activation_at(model, ctrl, f0 * spf)[None] if model.na else None
  stats = RefineStats(backend=sampler.backend_label, first_frame=f0)
  outputs = []
  for lo in range(0, n_samples, chunk):
    n = min(chunk, n_samples - lo)
    pad = np.concatenate([np.arange(lo, lo + n), np.full(chunk - n, lo)])
    running0 = np.arange(chunk) < n
    carry = jax.vmap(world_lib.init_carry, in_axes=(None, 0))(len(scene.body_names), jnp.asarray(running0))
    carry = carry._replace(
        step=jnp.full(chunk, f0 * spf, jnp.int32),
        metrics=jnp.broadcast_to(jnp.asarray(parent.metrics0), carry.metrics.shape),
        prev_com=jnp.broadcast_to(jnp.asarray(parent.path.com[f0]), carry.prev_com.shape),
        init_quat=jnp.broadcast_to(jnp.asarray(parent.path.quat[0]), carry.init_quat.shape))
    inp = refine_loop.RefineInputs(
        params=params, inter=inter, path=parent.path, step_targets=extras.step_targets, first_frame=f0,
        qpos0=start_qpos[pad], qvel0=start_qvel[pad], active0=np.tile(parent.asked, (chunk, 1)), carry0=carry,
        qpos_object=parent.qpos_object, dof_object=parent.dof_object, step_keys=step_keys[pad],
        running0=running0, n_frames=n_frames, body_ids=scene.body_ids, models=extras.models,
        free_bodies=extras.free_bodies, ctrl=ctrl, act0=None if act0 is None else np.repeat(act0, chunk, axis=0))
    base = stats.world_steps
    most_steps = (n_frames - f0) * spf  # one world from t_min to the end time

    def report(steps, finished, _base=base, _lo=lo, _n=n):
      # Worlds step in lockstep and mostly finish together: report world-steps
      # as world-equivalents so the bar moves while they run.
      if progress is not None:
        done = _lo + min(_n, max(finished, steps / most_steps))
        progress(Progress("refining", done, n_samples, _base + steps))

    out = runner.run(inp, progress=report).first(n)
    outputs.append(out)
    stats.world_steps += int(out.chunk.steps.sum())
    stats.run_seconds += out.chunk.run_seconds
    stats.compile_seconds += out.chunk.compile_seconds
  stats.max_perturbation_ratio = np.concatenate([o.max_perturbation_ratio for o in outputs])
  stats.inactive_perturbations = np.concatenate([o.inactive_perturbations for o in outputs])
  if progress is not None:
    progress(Progress("refining", n_samples, n_samples, stats.world_steps))
    progress(Progress("compressing", 0, n_samples, stats.world_steps))
  codec_start = time.perf_counter()
  new = _assemble(bank, plan, sampler, parent, keys, outputs)
  stats.codec_seconds = time.perf_counter() - codec_start
  if progress is not None:
    progress(Progress("compressing", n_samples, n_samples, stats.world_steps))
  stats.wall_seconds = time.perf_counter() - start_wall
  return new, stats


def _assemble(bank, plan: RefinePlan, sampler, parent: _Parent, keys, outputs) -> bank_lib.Bank:
  """The refined worlds as a bank (same scene, config and digest as ``bank``)."""
  f0, row = plan.first_frame, plan.row
  object_names = tuple(sampler.scene.object_names)
  chunks = [o.chunk for o in outputs]
  cat = lambda name: np.concatenate([getattr(o, name) for o in outputs])
  count = f0 + np.concatenate([c.frame_count for c in chunks]).astype(np.int32)
  status = np.concatenate([c.status for c in chunks])
  new_qpos = np.concatenate([c.qpos for c in chunks])
  # A refined world at rest before the parent's end holds its last frame to the
  # parent's length: then untouched objects' coded channels are the parent's own.
  count = np.where((status == world_lib.AT_REST) & (count < parent.path.n_parent),
                   np.minimum(parent.path.n_parent, f0 + new_qpos.shape[1]), count).astype(np.int32)
  w = len(count)
  active = cat("active")
  activated = cat("activated")
  body_obj = np.array([object_names.index(next(o for o, bs in bank.objects.items() if b in bs))
                       for b in bank.body_names])
  body_active = active[:, body_obj]  # [W, B]

  path = parent.path
  qpos = np.concatenate([np.broadcast_to(path.qpos[:f0], (w, f0, path.qpos.shape[1])), new_qpos], axis=1)
  keep_qpos = (~active).astype(np.float32) @ parent.qpos_object.astype(np.float32) > 0.5
  store = bank.qpos_store.refined(qpos, count, row, parent.frames, keep_qpos)

  # Inactive bodies keep the parent's polylines; a removed object keeps the
  # parent's metrics too (what it did while it was there).
  removed_body = np.isin(np.asarray(bank.body_names), [b for o in plan.removed for b in bank.objects[o]])
  rows = rows_lib.rows_from_chunks(
      chunks, sampler.query_stride, sampler.scene.config.codec.e_com, first_frame=f0, frame_count=count,
      parent=rows_lib.ParentRow(com=np.asarray(bank.com[row]), metrics=np.asarray(bank.metrics[row]),
                                com_kept=~body_active, metrics_kept=~body_active | removed_body))
  first_id = plan.first_id
  t0 = f0 / bank.record_fps
  lineage = {}
  for i in range(w):
    lineage[str(first_id + i)] = {
        "parent": plan.world, "t_min": t0, "objects": list(plan.objects),
        "active": [o for o, a in zip(object_names, active[i]) if a and o not in plan.removed],
        "activated_at": {o: int(f) / bank.record_fps for o, f in zip(object_names, activated[i])
                         if f >= 0 and o not in plan.removed},
    }
    if plan.added:
      lineage[str(first_id + i)]["added"] = {o: t0 for o in plan.added}
    if plan.removed:
      lineage[str(first_id + i)]["removed"] = {o: t0 for o in plan.removed}
  return dataclasses.replace(
      bank, world_ids=np.arange(first_id, first_id + w, dtype=np.int64),
      keys=np.asarray(jax.random.key_data(keys)), **rows._asdict(),
      parent_world=np.full(w, plan.world, np.int64), refine_time=np.full(w, t0, np.float32),
      qpos_store=store, lineage=lineage, next_id=first_id + w,
      scene_version=np.full(w, plan.scene_version, np.int16), _model=None)


def _start_states(scene, parent_qpos, parent_qvel, qm, vm, object_names, added, removed, keys):
  """(f32[N, nq], f32[N, nv]) each refined world's state at t_min: the
  parent's, added objects at their configured (randomized) initial state,
  removed ones parked at rest."""
  n = len(keys)
  qpos = np.tile(np.asarray(parent_qpos, np.float32), (n, 1))
  qvel = np.tile(np.asarray(parent_qvel, np.float32), (n, 1))
  if added:
    q_init, v_init = jax.vmap(scene.initial_state)(keys)
    q_init, v_init = np.asarray(q_init), np.asarray(v_init)
    for o in added:
      i = object_names.index(o)
      qpos[:, qm[i]] = q_init[:, qm[i]]
      qvel[:, vm[i]] = v_init[:, vm[i]]
  if removed:
    parked = parked_qpos(scene.model, removed).astype(np.float32)
    for o in removed:
      i = object_names.index(o)
      free = qm[i] & parked_columns(scene.model, [o])
      qpos[:, free] = parked[free]
      qvel[:, vm[i]] = 0.0
  return qpos, qvel


def refine(bank, world: int, objects=(), *, frustum=None, t_min: float | None = None, n_samples: int,
           key: jax.Array | None = None, backend: str | None = None, chunk_size: int | None = None,
           margin: float = DEFAULT_MARGIN, playback: str = "step", loop: str = "auto", progress=None,
           scene=None, add=(), remove=()):
  """Resamples the marked objects of one world from t_min on (paper §5).

  Args:
    bank: the bank holding the parent world.
    world: the parent's world id.
    objects: object or group names (a list, or one comma-separated string);
      may be empty when objects are added or removed.
    frustum: a :class:`mwbx.queries.Frustum` (e.g. ``camera.frustum(box)``):
      t_min is the first time any of the objects' COM is inside it; or
    t_min: the restart time in seconds (rounded down to a recorded frame).
    n_samples: refined worlds to make.
    key: run key; refined world i draws from ``fold_in(key, i)``. None: a fresh
      random key, so repeating a refinement gives new worlds.
    backend: ``auto`` | ``native`` | ``mjx`` (default: the config's).
    chunk_size: worlds per lockstep batch.
    margin: contact margin of the interaction test, m (larger is safer).
    playback: native backend only: ``step`` (default) puts inactive objects
      on their stored path before every physics step (S one-step rollout
      calls per frame); ``frame`` only at every frame boundary (one call per
      frame, a few per cent cheaper; inside a frame they move freely from the
      stored state, touching nothing, and report their stored motion). The
      MJX backend always does it every step.
    loop: native backend, ``playback="step"``: ``auto`` | ``compiled`` (each
      refined world in compiled calls, the fast path) | ``lockstep``
      (``mujoco.rollout`` a step at a time).
    progress: optional callback taking a :class:`mwbx.progress.Progress`.
    scene: a later version of the bank's scene (a :class:`mwbx.Scene`, a
      :class:`mwbx.config.Config` or a config file path) holding the objects
      to ``add``, appended after the bank's own (:mod:`mwbx.bank.versions`);
      the bank moves to it first, every world kept.
    add: objects (of ``scene``) inserted into the active set at t_min, at
      their configured initial state (randomized per refined world).
    remove: objects taken out at t_min: parked, colliding with nothing; their
      ghosts stay, so the objects they used to touch are resimulated.

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
    >>> bank = mwbx.refine(bank, 4, scene="configs/refrigerator_toy_block.yaml", add="block", t_min=0.0,
    ...                    n_samples=16)
    >>> bank = mwbx.refine(bank, 4, remove="bucket_top", t_min=1.0, n_samples=16)
  """
  return run_refinement(bank, world, objects, frustum=frustum, t_min=t_min, n_samples=n_samples, key=key,
                        backend=backend, chunk_size=chunk_size, margin=margin, playback=playback, loop=loop,
                        progress=progress, scene=scene, add=add, remove=remove).bank


class Refinement(NamedTuple):
  """What one refinement made (:func:`run_refinement`; what ``mwbx refine`` reports).

  Attributes:
    bank: the bank with the refined worlds appended (in ``scene``'s version if given).
    new: the refined worlds alone (ids from the bank's ``next_world_id`` on).
    stats: timing and perturbation audit.
    plan: the refinement as resolved (objects, t_min, frame, key, …).
    scene_version: the scene version the bank moved to for ``scene=``; None:
      it stayed in its own.
  """

  bank: bank_lib.Bank
  new: bank_lib.Bank
  stats: RefineStats
  plan: RefinePlan
  scene_version: int | None


def run_refinement(bank, world: int, objects=(), *, frustum=None, t_min: float | None = None, n_samples: int,
                   key: jax.Array | None = None, backend: str | None = None, chunk_size: int | None = None,
                   margin: float = DEFAULT_MARGIN, playback: str = "step", loop: str = "auto", progress=None,
                   scene=None, add=(), remove=()) -> Refinement:
  """:func:`refine`, returning the new worlds and stats beside the grown bank
  (arguments as :func:`refine`)."""
  start_wall = time.perf_counter()
  moved = None
  if scene is not None:
    before = bank.digest
    bank = bank.with_scene(as_scene(scene), progress)
    moved = len(bank.versions) if bank.digest != before else None
  plan = plan_refinement(bank, world, objects, frustum=frustum, t_min=t_min, n_samples=n_samples, key=key,
                         backend=backend, chunk_size=chunk_size, margin=margin, playback=playback, loop=loop,
                         add=add, remove=remove)
  new, stats = run_plan(bank, plan, progress, start_wall)
  return Refinement(bank=bank.append(new), new=new, stats=stats, plan=plan, scene_version=moved)


def as_scene(scene):
  """A :class:`mwbx.Scene` from a Scene, a Config or a config file path."""
  from mwbx.config import Config, load_config
  from mwbx.scene import Scene
  if isinstance(scene, Scene):
    return scene
  if isinstance(scene, Config):
    return Scene(scene)
  return Scene(load_config(scene))
