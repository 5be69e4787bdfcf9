"""A refinement plan (:class:`RefinePlan`) and how it runs (:func:`run_plan`).

:func:`mwbx.refinement.plan_refinement` resolves and checks a refinement
against its bank once; :func:`run_plan` restarts the parent at t_min, runs
the refined worlds in lockstep batches on the sampler's backend (through its
:mod:`~mwbx.refinement.runners` entry points) and assembles them into bank
rows by the road sampling takes (:func:`mwbx.batch_sim.rows.rows_from_chunks`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import bank as bank_lib
from mwbx.bank.versions import parked_columns, parked_qpos
from mwbx import controls
from mwbx.batch_sim import rows as rows_lib
from mwbx.batch_sim import world as world_lib
from mwbx.batch_sim.sampler import SampleStats, world_keys
from mwbx.codec import CodecBounds
from mwbx.events import detect as events_lib
from mwbx.events.record import EventRecord
from mwbx import scene as scene_lib
from mwbx.joints import DOF_WIDTH, QPOS_WIDTH
from mwbx.progress import Progress
from mwbx.refinement import interactions, stored_motion
from mwbx.refinement import loop as refine_loop
from mwbx.refinement import runners


def object_coordinates(model: mujoco.MjModel, object_names) -> tuple[np.ndarray, np.ndarray]:
  """(bool[O, nq], bool[O, nv]) coordinates of each object's joints."""
  qm = np.zeros((len(object_names), model.nq), bool)
  vm = np.zeros((len(object_names), model.nv), bool)
  objects = scene_lib.find_objects(model, "refine")  # a flex's vertex bodies, or a root body's tree
  for o, name in enumerate(object_names):
    bodies = set(objects[name])
    for j in range(model.njnt):
      if int(model.jnt_bodyid[j]) in bodies:
        t = int(model.jnt_type[j])
        qm[o, model.jnt_qposadr[j]:model.jnt_qposadr[j] + QPOS_WIDTH[t]] = True
        vm[o, model.jnt_dofadr[j]:model.jnt_dofadr[j] + DOF_WIDTH[t]] = True
  return qm, vm


@dataclasses.dataclass
class RefineStats(SampleStats):
  """Timing of a refinement run, plus per refined world the largest applied
  ``‖perturbation‖ / (α‖Δv‖)`` (at most 1), the perturbations drawn for
  inactive bodies (always 0) and the frames × inactive objects held asleep;
  ``first_frame`` is the frame at t_min."""

  first_frame: int = 0
  max_perturbation_ratio: np.ndarray | None = None
  inactive_perturbations: np.ndarray | None = None
  asleep_object_frames: np.ndarray | None = None


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
    bounds: the codec's error bounds (e_pos m, e_rot rad, e_scalar).
    contact_budget: the MJX contact budget the bank was sampled with (None: none).
    events: find the new worlds' contact events (False: the new bank has
      none; a caller keeping a few of many, as ``solve`` does, finds theirs).
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
  bounds: CodecBounds
  contact_budget: dict | None
  events: bool = True


class _Parent(NamedTuple):
  """The parent world as refinement restarts it (see :func:`_parent_of`)."""

  frames: np.ndarray  # f32[T, nq] its decoded qpos
  path: stored_motion.StoredPath
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
  frames = bank.qpos_store.row_frames(plan.row)
  path = stored_motion.stored_path(model, frames, scene.body_ids, sampler.n_frames + 2, frame_time)
  object_names = tuple(scene.object_names)
  qm, vm = object_coordinates(model, object_names)
  # Added and removed objects are active from t_min: an added one is simulated,
  # a removed one parked, its ghost (stored path) still tested.
  asked = np.array([o in plan.objects or o in plan.added or o in plan.removed for o in object_names])
  qvel0 = np.where(vm[asked].any(axis=0), stored_motion.central_velocity(model, path, f0, frame_time), path.qvel[f0])
  cfg = scene.config
  metrics0 = stored_motion.prefix_metrics(
      path, f0, frame_time, model.opt.timestep, np.asarray(model.opt.gravity), cfg.rest.linear_speed,
      cfg.rest.angular_speed, cfg.perturb.linear_threshold,
      max(1, int(round(cfg.perturb.collision_gap * fps))))
  return _Parent(frames, path, path.qpos[f0], qvel0, metrics0, qm, vm, asked)


def run_plan(bank, plan: RefinePlan, sampler, progress=None, start_wall: float | None = None):
  """Runs a :class:`RefinePlan` of ``bank`` on ``sampler`` (the bank scene's,
  :func:`mwbx.refinement.sampler_for`).

  Returns:
    (the new worlds as a bank, :class:`RefineStats`).
  """
  start_wall = time.perf_counter() if start_wall is None else start_wall
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
  params = params if not parked else params._replace(
      perturbable=jnp.asarray(np.asarray(params.perturbable) & ~np.isin(
          np.asarray(scene.body_names), [b for o in parked for b in scene.objects[o]])),
      flex_perturbable=jnp.asarray(np.asarray(params.flex_perturbable) & ~np.isin(scene.flex_objects, parked)))
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
        free_bodies=extras.free_bodies, ctrl=ctrl, act0=None if act0 is None else np.repeat(act0, chunk, axis=0),
        event_objects=object_names if plan.events and bank.events is not None else None)
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
    stats.sim_errors.extend((plan.first_id + lo + row, message) for row, message in out.chunk.errors if row < n)
    stats.world_steps += int(out.chunk.steps.sum())
    stats.run_seconds += out.chunk.run_seconds
    stats.compile_seconds += out.chunk.compile_seconds
  stats.max_perturbation_ratio = np.concatenate([o.max_perturbation_ratio for o in outputs])
  stats.inactive_perturbations = np.concatenate([o.inactive_perturbations for o in outputs])
  stats.asleep_object_frames = np.concatenate([o.asleep_object_frames for o in outputs])
  if progress is not None:
    progress(Progress("refining", n_samples, n_samples, stats.world_steps))
    progress(Progress("compressing", 0, n_samples, stats.world_steps))
  codec_start = time.perf_counter()
  new = _assemble(bank, plan, sampler, parent, keys, outputs, stats)
  stats.codec_seconds = time.perf_counter() - codec_start - stats.events_seconds
  if progress is not None:
    progress(Progress("compressing", n_samples, n_samples, stats.world_steps))
  stats.wall_seconds = time.perf_counter() - start_wall
  return new, stats


def _assemble(bank, plan: RefinePlan, sampler, parent: _Parent, keys, outputs, stats) -> bank_lib.Bank:
  """The refined worlds as a bank (same scene, config and digest as ``bank``);
  the time finding their contact events goes to ``stats.events_seconds``."""
  f0, row = plan.first_frame, plan.row
  object_names = tuple(sampler.scene.object_names)
  chunks = [o.chunk for o in outputs]
  cat = lambda name: np.concatenate([getattr(o, name) for o in outputs])
  count = f0 + np.concatenate([c.frame_count for c in chunks]).astype(np.int32)
  status = np.concatenate([c.status for c in chunks])
  new_qpos = chunks[0].qpos if len(chunks) == 1 else np.concatenate([c.qpos for c in chunks])
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

  keep_qpos = (~active).astype(np.float32) @ parent.qpos_object.astype(np.float32) > 0.5
  store = bank.qpos_store.refined(new_qpos, f0, count, row, parent.frames, keep_qpos)
  # Removed objects count as active: their stored contacts after t_min are not theirs any more.
  touched = active | np.isin(np.asarray(object_names), plan.removed)[None, :]
  events_start = time.perf_counter()
  stepped = _stepped_episodes(outputs, f0, count, sampler.params.steps_per_frame)
  events, event_actors = (refined_events(bank, row, f0, store, sampler, active=touched, stepped=stepped,
                                         activated=activated, frame_count=count) if plan.events else (None, ()))
  stats.events_seconds = time.perf_counter() - events_start

  # Inactive bodies keep the parent's polylines; a removed object keeps the
  # parent's metrics too (what it did while it was there).
  removed_body = np.isin(np.asarray(bank.body_names), [b for o in plan.removed for b in bank.objects[o]])
  rows = rows_lib.rows_from_chunks(
      chunks, sampler.query_stride, sampler.scene.config.codec.com_step(), first_frame=f0, frame_count=count,
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
      scene_version=np.full(w, plan.scene_version, np.int16), events=events, event_actors=event_actors,
      _model=None)


def _stepped_episodes(outputs, first_frame: int, frame_count: np.ndarray, spf: int) -> list | None:
  """Per refined world, f64[n, 6] the episodes its loop found at every step
  (one on at the world's own end goes on to ``frame_count``'s, where the
  world is held to its parent's length); None for a world whose loop found
  none or overflowed, or for every world where the loop does not find them."""
  chunks = [o.chunk for o in outputs]
  if any(c.event_count is None for c in chunks):
    return None
  out = []
  for c in chunks:
    for w, n in enumerate(c.event_count.tolist()):
      if n > c.event_rows.shape[1]:
        out.append(None)
        continue
      rows = np.concatenate([c.event_rows[w, :n], c.event_strength[w, :n]], axis=1).astype(np.float64)
      own_end = (first_frame + int(c.frame_count[w]) - 1) * spf
      rows[rows[:, 3] == own_end, 3] = (int(frame_count[len(out)]) - 1) * spf
      out.append(rows)
  return out


def refined_events(bank, row: int, first_frame: int, store, sampler, active=None, stepped=None, activated=None,
                   frame_count=None):
  """(EventRecord, actor names, in physics steps) of refined worlds of the
  world at ``row``: the parent's episodes before ``first_frame`` (their
  simulation is the parent's up to there), their own after: found at every
  step by the loop (``stepped``), else on their stored frames from there
  (:meth:`Sampler.events_of_frames`: a frame's resolution, no strength);
  (None, ()) for a bank without events.

  Args:
    bank: the bank holding the parent. row: the parent's row.
    first_frame: the frame the refinement restarts at.
    store: the refined worlds' stored qpos (any of the refinement's worlds,
      in any order). sampler: the bank scene's.
    active: optional bool[W, n_objects] the objects each refined world
      moved itself (store order): its own episodes are those with one of
      them on a side, from when it became active (``activated``: i32[W,
      n_objects] frames, -1: from ``first_frame``); the other pairs follow
      the parent's stored paths, so their episodes are the parent's.
    stepped: optional, per world, f64[n, 6] episodes ``(a, b, first, last,
      peak force, impulse)`` the loop found at every step from
      ``first_frame`` on, or None where it did not (found on frames).
    frame_count: optional i[W] the worlds' frame counts (else their frames
      are decoded to count them).
  """
  if bank.events is None:
    return None, ()
  actors = sampler.event_actors.names
  spf = sampler.params.steps_per_frame
  if tuple(bank.event_actors) != actors:  # a later scene version: other actors, found afresh
    return sampler.events_of_frames(store.frames_of_rows(None)), actors
  n, start = store.n_worlds, first_frame * spf
  parent = _episodes(bank.events.in_ticks(spf), row)
  moved_from = np.full((n, len(actors)), np.inf)  # the tick each actor's own simulation starts (static: never)
  if active is not None:
    began = first_frame if activated is None else np.where(np.asarray(activated) >= 0, activated, first_frame)
    moved_from[:, :np.shape(active)[1]] = np.where(active, np.asarray(began) * spf, np.inf)
  stepped = [None] * n if stepped is None else stepped
  # Before first_frame a refined world is its parent's simulation (whatever the
  # codec made of the refined objects' frames there): the parent's episodes.
  on_frames = [i for i in range(n) if stepped[i] is None]
  frames = store.frames_of_rows(np.array(on_frames, np.int64)) if on_frames else []
  after = sampler.events_of_frames(
      [f[first_frame:] for f in frames], first_frame=first_frame,
      active=None if active is None else np.isfinite(moved_from[on_frames])) if on_frames else None
  if frame_count is None:  # (decoded only to be counted)
    frame_count = [len(f) for f in store.frames_of_rows(None)]
  parent_end = (int(bank.frame_count[row]) - 1) * spf
  worlds = []
  for i in range(n):
    found = stepped[i] if stepped[i] is not None else _episodes(after, on_frames.index(i))
    if active is not None:
      found = _with_parent_pairs(parent, found, moved_from[i], start, parent_end, (int(frame_count[i]) - 1) * spf)
    worlds.append(events_lib.spliced(parent, found, start))
  return EventRecord.from_worlds([w[:, :4] for w in worlds], [w[:, 4:] for w in worlds], ticks_per_frame=spf), actors


def _episodes(record: EventRecord, row: int) -> np.ndarray:
  """f64[n, 6] one world's episodes with their strengths: ``(a, b, first, last, peak force, impulse)``."""
  lo, hi = record.offsets[row], record.offsets[row + 1]
  return np.concatenate([record.rows[lo:hi], record.strength[lo:hi]], axis=1).astype(np.float64)


def _with_parent_pairs(parent: np.ndarray, found: np.ndarray, moved_from: np.ndarray, start: int, parent_end: int,
                       end: int) -> np.ndarray:
  """A refined world's episodes from tick ``start`` on: a pair's own from the
  tick the first of its actors moved itself (``moved_from``: f64[n_actors],
  inf: never), the parent's before (its stored paths are the parent's; the
  last frame is held where the world outlasts its parent); an episode going
  on across that tick is one.

  Args:
    parent: f64[n, 6] the parent's episodes (:func:`_episodes`).
    found: f64[m, 6] found on the refined world from ``start``.
    parent_end, end: the parent's and the refined world's last ticks.
  """
  own = lambda rows: np.minimum(moved_from[rows[:, 0].astype(np.int64)], moved_from[rows[:, 1].astype(np.int64)])
  k = own(found)
  found = found[np.isfinite(k) & (found[:, 3] >= k)].copy()
  found[:, 2] = np.maximum(found[:, 2], own(found))
  k = own(parent)
  kept = parent[(parent[:, 3] >= start) & (parent[:, 2] < k)].copy()
  k = own(kept)
  # An episode going on at start continues the parent's (events_lib.spliced joins them):
  # its strength, the whole episode's, is counted once.
  kept[kept[:, 2] < start, 4:] = 0.0
  kept[:, 2] = np.maximum(kept[:, 2], start)
  never = np.isinf(k)
  kept[never & (kept[:, 3] == parent_end), 3] = max(parent_end, end)  # on at the parent's end: on while held
  kept[:, 3] = np.minimum(kept[:, 3], np.where(never, end, k - 1))
  kept = kept[kept[:, 2] <= kept[:, 3]]
  rows = np.concatenate([found, kept])
  # The parent's touch going on when an actor starts to move itself, and the world's own from then: one episode.
  return events_lib.joined(rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))])


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
