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

import copy
import dataclasses
import functools
import math
import secrets
import time
from typing import Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import bank as bank_lib
from mwbx import controls
from mwbx.batch_sim import mujoco_c
from mwbx.batch_sim import free_bodies
from mwbx.batch_sim import world as world_lib
from mwbx.bank.versions import parked_columns, parked_qpos
from mwbx.batch_sim.sampler import Sampler, SampleStats, world_keys
from mwbx.codec import polyline
from mwbx.config import Config, config_from_dict, load_config
from mwbx.errors import MwbxError
from mwbx.progress import Progress
from mwbx.joints import DOF_WIDTH, QPOS_WIDTH
from mwbx.refinement import interactions, kinematic
from mwbx.queries import first_entry
from mwbx.scene import Scene, objects_of
from mwbx.refinement import loop as refine_loop
from mwbx.refinement import world_loop

DEFAULT_MARGIN = 0.01  # m, contact margin of the interaction test


def _scene_of(bank):
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
    members = objects_of(name, tuple(bank.objects), bank.groups, field, "refine")
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


def resolve_t_min(bank, world: int, objects: tuple[str, ...], frustum=None, t_min: float | None = None) -> float:
  """t_min in seconds: given, or the first time an object's COM enters ``frustum``."""
  if (frustum is None) == (t_min is None):
    raise MwbxError("refine: give exactly one of frustum (a screen box through a camera) or t_min")
  last = (int(bank.frame_count[bank.row_of(world)]) - 1) / bank.record_fps
  if frustum is not None:
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
  compiled_loop = loop == "compiled" or (loop == "auto" and mujoco_c.available())
  names = resolve_objects(bank, objects, required=not (add or remove))
  added = resolve_objects(bank, add, "add", required=False)
  removed = resolve_objects(bank, remove, "remove", required=False)
  t_min = resolve_t_min(bank, world, names or added or removed, frustum, t_min)
  # Objects already gone at t_min stay out: colliding with nothing even if
  # something activates them.
  gone = _resolve_changes(bank, world, names, added, removed, t_min)
  sampler = sampler_for(bank, backend)
  chunk = int(min(chunk_size or sampler.scene.config.sim.chunk_size, n_samples))
  if sampler.backend_name == "mjx" and (removed or any(not parked_columns(sampler.scene.model, [o]).any()
                                                         for o in gone)):
    raise MwbxError("refine: the MJX backend cannot keep removed objects out of contact yet; use backend='native'")
  return _run(bank, world, names, t_min, n_samples, key, sampler, chunk, margin, playback, compiled_loop,
              progress, start_wall, added, removed, gone)


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


def _removal_model(model: mujoco.MjModel, removed) -> mujoco.MjModel:
  """``model`` with the ``removed`` objects colliding with nothing and
  weightless (gravity compensated), so parked they stay put."""
  if not removed:
    return model
  out = copy.copy(model)  # mj_copyModel
  roots = [model.body(name).id for name in removed]
  bodies = np.isin(model.body_rootid, roots)
  geoms = bodies[model.geom_bodyid]
  out.geom_contype[geoms] = 0
  out.geom_conaffinity[geoms] = 0
  out.body_gravcomp[bodies] = 1.0
  return out


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


def _run(bank, world, names, t_min, n_samples, key, sampler, chunk, margin, playback, compiled_loop, progress,
         start_wall, added=(), removed=(), gone=()):
  scene, params = sampler.scene, sampler.params
  model = scene.model
  fps, spf = bank.record_fps, params.steps_per_frame
  frame_time = 1.0 / fps
  f0 = int(math.floor(t_min * fps + 1e-6))
  n_frames = sampler.n_frames
  if f0 >= n_frames:
    raise MwbxError(f"refine: t_min {t_min:g} s is at or past the end time")
  row = bank.row_of(world)
  parent = bank.qpos_frames(world)
  path = kinematic.stored_path(model, parent, scene.body_ids, n_frames + 2, frame_time)
  mjx = sampler.backend_name == "mjx"
  targets = kinematic.step_targets(model, path, spf, model.opt.timestep) if mjx or playback == "step" else None
  object_names = tuple(scene.object_names)
  qm, vm = object_coordinates(model, object_names)
  # Native: free bodies are observed from their states, so the rollout models
  # (and their contact-free copies) step with sensors disabled.
  bodies = None if mjx else free_bodies.free_bodies(model, scene.body_ids)
  models = None if mjx else kinematic.ContactFreeModels(
      _removal_model(model if bodies is None else sampler.backend.quiet_model, removed + gone), object_names)
  # Added and removed objects are active from t_min: an added one is simulated,
  # a removed one parked, its ghost (stored path) still tested.
  asked = np.array([o in names or o in added or o in removed for o in object_names])
  cfg = scene.config
  inter = interactions.interaction_params(
      model, scene.body_ids, scene.body_names, scene.objects, object_names,
      cfg.codec.bounds(),
      margin, (spf + 1) * model.opt.timestep, cfg.perturb.alpha)

  qpos0 = path.qpos[f0]
  qvel0 = np.where(vm[asked].any(axis=0), kinematic.central_velocity(model, path, f0, frame_time), path.qvel[f0])
  params = params if not (removed or gone) else params._replace(perturbable=jnp.asarray(
      np.asarray(params.perturbable) & ~np.isin(np.asarray(scene.body_names),
                                                 [b for o in removed + gone for b in scene.objects[o]])))
  metrics0 = kinematic.prefix_metrics(
      path, f0, frame_time, model.opt.timestep, np.asarray(model.opt.gravity), cfg.rest.linear_speed,
      cfg.rest.angular_speed, cfg.perturb.linear_threshold,
      max(1, int(round(cfg.perturb.collision_gap * fps))))

  ctrl = controls.scene_table(scene, n_frames * spf)
  ids = np.arange(n_samples, dtype=np.int64)
  keys, _, step_keys = world_keys(key, ids)
  start_qpos, start_qvel = _start_states(scene, qpos0, qvel0, qm, vm, object_names, added, removed, keys)
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
        metrics=jnp.broadcast_to(jnp.asarray(metrics0), carry.metrics.shape),
        prev_com=jnp.broadcast_to(jnp.asarray(path.com[f0]), carry.prev_com.shape),
        init_quat=jnp.broadcast_to(jnp.asarray(path.quat[0]), carry.init_quat.shape))
    inp = refine_loop.RefineInputs(
        params=params, inter=inter, path=path, step_targets=targets, first_frame=f0,
        qpos0=start_qpos[pad], qvel0=start_qvel[pad],
        active0=np.tile(asked, (chunk, 1)), carry0=carry, qpos_object=qm, dof_object=vm,
        step_keys=step_keys[pad], running0=running0, n_frames=n_frames, body_ids=scene.body_ids, models=models,
        free_bodies=bodies, ctrl=ctrl, act0=None if act0 is None else np.repeat(act0, chunk, axis=0))
    if mjx:
      run = refine_loop.run_mjx
    elif playback == "step" and compiled_loop:
      run = world_loop.run_compiled
    else:
      run = functools.partial(refine_loop.run_native, every_step=playback == "step")
    base = stats.world_steps
    most_steps = (n_frames - f0) * spf  # one world from t_min to the end time

    def report(steps, finished, _base=base, _lo=lo, _n=n):
      # Worlds step in lockstep and mostly finish together: report world-steps
      # as world-equivalents so the bar moves while they run.
      if progress is not None:
        done = _lo + min(_n, max(finished, steps / most_steps))
        progress(Progress("refining", done, n_samples, _base + steps))

    out = run(sampler.backend, inp, progress=report)
    out = refine_loop.RefineOutput(*(x[:n] if isinstance(x, np.ndarray) else x for x in out))
    outputs.append(out)
    stats.world_steps += int(out.steps.sum())
    stats.run_seconds += out.run_seconds
    stats.compile_seconds += out.compile_seconds
  stats.max_perturbation_ratio = np.concatenate([o.max_perturbation_ratio for o in outputs])
  stats.inactive_perturbations = np.concatenate([o.inactive_perturbations for o in outputs])
  if progress is not None:
    progress(Progress("refining", n_samples, n_samples, stats.world_steps))
    progress(Progress("compressing", 0, n_samples, stats.world_steps))
  codec_start = time.perf_counter()
  new = _assemble(bank, world, row, names, object_names, f0, path, parent, keys, outputs, qm, sampler, added,
                  removed)
  stats.codec_seconds = time.perf_counter() - codec_start
  if progress is not None:
    progress(Progress("compressing", n_samples, n_samples, stats.world_steps))
  stats.wall_seconds = time.perf_counter() - start_wall
  return new, stats


def _assemble(bank, world, row, names, object_names, f0, path, parent, keys, outputs, qm, sampler, added=(),
              removed=()):
  """The refined worlds as a bank (same scene, config and digest as ``bank``)."""
  cat = lambda name: np.concatenate([getattr(o, name) for o in outputs])
  count = f0 + cat("frame_count").astype(np.int32)
  status = cat("status")
  # A refined world at rest before the parent's end holds its last frame to the
  # parent's length: then untouched objects' coded channels are the parent's own.
  count = np.where((status == world_lib.AT_REST) & (count < path.n_parent),
                   np.minimum(path.n_parent, f0 + cat("qpos").shape[1]), count).astype(np.int32)
  new_qpos, new_com = cat("qpos"), cat("com")
  w = len(count)
  active = cat("active")
  activated = cat("activated")
  body_obj = np.array([object_names.index(next(o for o, bs in bank.objects.items() if b in bs))
                       for b in bank.body_names])
  body_active = active[:, body_obj]  # [W, B]

  qpos = np.concatenate([np.broadcast_to(path.qpos[:f0], (w, f0, path.qpos.shape[1])), new_qpos], axis=1)
  keep_qpos = (~active).astype(np.float32) @ qm.astype(np.float32) > 0.5
  store = bank.qpos_store.refined(qpos, count, row, parent, keep_qpos)

  stride = sampler.query_stride
  n_points = bank.com.shape[1]
  # On the bank's COM grid, like the parent's stored points.
  new_com = polyline.round_to_grid(new_com, sampler.scene.config.codec.com_step())
  com_rate = np.concatenate([np.zeros((w, f0) + new_com.shape[2:], np.float32), new_com], axis=1)
  com = com_rate[:, ::stride][:, :n_points]
  com = np.concatenate([com, np.repeat(com[:, -1:], n_points - com.shape[1], axis=1)], axis=1)
  before = (np.arange(n_points) * stride < f0)
  com[:, before] = bank.com[row][before]
  parent_com = bank.com[row]
  com = np.where(body_active[:, None, :, None], com, parent_com[None])
  com = np.nan_to_num(com)
  com_count = ((count - 1) // stride + 1).astype(np.int32)

  metrics = np.nan_to_num(cat("metrics"), nan=0.0, posinf=0.0, neginf=0.0)
  # A removed object keeps the parent's metrics (what it did while it was there).
  body_kept = ~body_active | np.isin(np.asarray(bank.body_names), [b for o in removed for b in bank.objects[o]])
  metrics = np.where(body_kept[:, :, None], bank.metrics[row][None], metrics)
  flags = np.full(w, bank_lib.FLAG_FINISHED, np.uint8)
  flags[status == world_lib.AT_REST] |= bank_lib.FLAG_AT_REST
  flags[status == world_lib.UNSTABLE] |= bank_lib.FLAG_UNSTABLE
  flags[status == world_lib.SIM_ERROR] |= bank_lib.FLAG_SIM_ERROR  # trapped by the compiled loop
  if all(o.contact_overflow is not None for o in outputs):  # MJX: over its contact budget
    flags[cat("contact_overflow")] |= bank_lib.FLAG_CONTACT_OVERFLOW
  first_id = bank.next_world_id
  t0 = f0 / bank.record_fps
  lineage = {}
  for i in range(w):
    lineage[str(first_id + i)] = {
        "parent": int(world), "t_min": t0, "objects": list(names),
        "active": [o for o, a in zip(object_names, active[i]) if a and o not in removed],
        "activated_at": {o: int(f) / bank.record_fps for o, f in zip(object_names, activated[i])
                         if f >= 0 and o not in removed},
    }
    if added:
      lineage[str(first_id + i)]["added"] = {o: t0 for o in added}
    if removed:
      lineage[str(first_id + i)]["removed"] = {o: t0 for o in removed}
  # An added object puts a world in the bank's current scene version.
  version = len(bank.versions) if added else int(bank.scene_version[row])
  return dataclasses.replace(
      bank, world_ids=np.arange(first_id, first_id + w, dtype=np.int64),
      keys=np.asarray(jax.random.key_data(keys)), flags=flags, frame_count=count, com=com.astype(np.float32),
      com_count=com_count, metrics=metrics.astype(np.float32),
      perturbations=cat("perturbations").astype(np.int32), steps=cat("steps").astype(np.int32),
      parent_world=np.full(w, world, np.int64), refine_time=np.full(w, t0, np.float32),
      qpos_store=store, lineage=lineage, next_id=first_id + w, scene_version=np.full(w, version, np.int16),
      _model=None)



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
  if scene is not None:
    bank = bank.with_scene(as_scene(scene), progress)
  new, _ = refine_run(bank, world, objects, frustum=frustum, t_min=t_min, n_samples=n_samples, key=key,
                      backend=backend, chunk_size=chunk_size, margin=margin, playback=playback, loop=loop,
                      progress=progress, add=add, remove=remove)
  return bank.append(new)


def as_scene(scene):
  """A :class:`mwbx.Scene` from a Scene, a Config or a config file path."""
  if isinstance(scene, Scene):
    return scene
  if isinstance(scene, Config):
    return Scene(scene)
  return Scene(load_config(scene))
