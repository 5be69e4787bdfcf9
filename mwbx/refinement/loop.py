"""The lockstep loops of refinement, one per backend.

Every world of a refinement starts at the same frame f0 of the same parent,
so the stored path is shared and only the active masks differ per world. Per
frame f (both backends):

1. the active set for the frame comes from :func:`interactions.activate`
   (on the last step's observations and the stored chord f → f + 1);
2. objects inactive before that update are put on their stored state
   (decoded ``qpos[f]``, chord ``qvel[f]``), so a newly activated object
   starts exactly where its stored motion is;
3. the frame's S physics steps run for every object, inactive objects put
   back on the stored path before every step (playback between frames by
   ``mj_integratePos``): on MJX inside the jitted scan, on the native
   backend by S one-step ``mujoco.rollout`` calls (``every_step=False``:
   one call per frame, reset at frame boundaries only). Native rollouts use
   a model in which the world's inactive objects collide with nothing
   (:class:`stored_motion.ContactFreeModels`): they are overwritten anyway, an
   active object never touches one (it would have been activated), and
   their contacts with the scene were most of the cost of stepping them;
4. the bookkeeping kernel runs with only active bodies perturbable.

Frames are recorded at the frame start, after step 2: an inactive object's
recorded frame is its stored frame, bit for bit.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mwbx.batch_sim import free_bodies as free_bodies_lib
from mwbx.batch_sim import mjx_events
from mwbx.batch_sim import world
from mwbx.batch_sim.backend import ChunkResult, fill_tail
from mwbx.refinement import interactions, stored_motion


class RefineInputs(NamedTuple):
  """One lockstep batch of refined worlds.

  Attributes:
    params: bookkeeping constants; inter: interaction-test constants.
    path: the parent's stored path (at least n_frames + 2 frames).
    step_targets: f32[F·S, nq] per-step playback qpos (MJX loop only, else None).
    first_frame: f0, the frame at t_min.
    qpos0: f32[C, nq]; qvel0: f32[C, nv] state at f0.
    active0: bool[C, O] objects refined (asked for).
    carry0: bookkeeping at f0 (leading axis C).
    qpos_object: bool[O, nq]; dof_object: bool[O, nv] coordinates of each object.
    step_keys: key[C] per-world step key roots.
    running0: bool[C] false for padding slots.
    n_frames: end_frame + 1.
    body_ids: i32[B] tracked body ids.
    models: rollout models by inactive objects (native loop only, else None).
    free_bodies: native loop only: the tracked bodies' state addresses when
      they are all free bodies; the sensor block then comes from the states
      and ``models`` step with sensors disabled (:mod:`free_bodies`).
    ctrl: f64[n_frames · S, nu] actuator control of each step from step 0
      (:mod:`mwbx.controls`; width 0: none).
    act0: f64[C, na] actuator activations at f0 (None: the model has none).
    event_objects: the scene's object names where contact events are found
      at every step (the compiled native loop and the MJX scan; None: not there).
  """

  params: world.WorldParams
  inter: interactions.InteractionParams
  path: stored_motion.StoredPath
  step_targets: np.ndarray | None
  first_frame: int
  qpos0: np.ndarray
  qvel0: np.ndarray
  active0: np.ndarray
  carry0: world.WorldCarry
  qpos_object: np.ndarray
  dof_object: np.ndarray
  step_keys: jax.Array
  running0: np.ndarray
  n_frames: int
  body_ids: np.ndarray
  models: stored_motion.ContactFreeModels | None = None
  free_bodies: free_bodies_lib.FreeBodies | None = None
  ctrl: np.ndarray | None = None
  act0: np.ndarray | None = None
  event_objects: tuple[str, ...] | None = None


class RefineOutput(NamedTuple):
  """What a batch produced (host arrays).

  Attributes:
    chunk: the batch as a :class:`~mwbx.batch_sim.backend.ChunkResult`, its
      frames counted from f0: ``qpos`` f32[C, F - f0, nq], ``com``
      f32[C, F - f0, B, 3] (tails repeat the last), ``frame_count`` frames
      recorded from f0 on, ``steps`` physics steps simulated from f0;
      ``contact_overflow`` on MJX only.
    active: bool[C, O] final active sets.
    activated: i32[C, O] frame each object became active (-1: never).
    max_perturbation_ratio: f32[C] largest ‖perturbation‖ / (α‖Δv‖) applied.
    inactive_perturbations: i64[C] perturbations drawn for inactive bodies (0).
    asleep_object_frames: i64[C] frames x inactive objects held asleep
      (MuJoCo's island sleep, the compiled native loop; 0 elsewhere).
  """

  chunk: ChunkResult
  active: np.ndarray
  activated: np.ndarray
  max_perturbation_ratio: np.ndarray
  inactive_perturbations: np.ndarray
  asleep_object_frames: np.ndarray

  def first(self, n: int) -> RefineOutput:
    """The output of the first ``n`` worlds (a padded batch without its padding)."""
    return RefineOutput(self.chunk.first(n), *(x[:n] for x in self[1:]))


def _activate_batch(active, com_sim, speed_sim, com_now, com_next, inter):
  return jax.vmap(interactions.activate, in_axes=(0, 0, 0, None, None, None))(
      active, com_sim, speed_sim, com_now, com_next, inter)


_activate_jit = jax.jit(_activate_batch)


def _with_stored_motion(obs, active, frame, stored, params, inter):
  """A batch frame's observations with inactive bodies reporting their stored
  motion (COM along the chord, chord velocities, no contact acceleration), so
  their metrics, rest detection and impact counts follow the stored path.

  Args:
    obs: observations, leading axes [W, S].
    active: bool[W, O] objects simulated during the frame.
    frame: i32 frame index f.
    stored: (com f32[F, B, 3], quat f32[F, B, 4], lin_vel f32[F, B, 3],
      ang_vel f32[F, B, 3]) of the stored path.
  """
  com, quat, lin_vel, ang_vel = stored
  spf = obs.com_pos.shape[1]
  a = (jnp.arange(spf, dtype=jnp.float32) / spf)[:, None, None]
  chord = com[frame][None] + a * (com[frame + 1] - com[frame])[None]  # [S, B, 3]
  m = ~_body_mask(active, inter)[:, None, :, None]
  pick = lambda stored_value, sim: jnp.where(m, jnp.broadcast_to(stored_value, sim.shape), sim)
  return world.Observation(
      com_pos=pick(chord, obs.com_pos), quat=pick(quat[frame], obs.quat), lin_vel=pick(lin_vel[frame], obs.lin_vel),
      ang_vel=pick(ang_vel[frame], obs.ang_vel), lin_acc=pick(params.gravity, obs.lin_acc),
      ang_acc=pick(jnp.zeros(3, jnp.float32), obs.ang_acc))


def _audit(obs, out, active, params, inter):
  """Per world: the largest ``‖dv‖ / (α‖Δv‖)`` (≤ 1 is the plausibility bound;
  angular alike) and how many perturbations went to inactive bodies (must be 0)."""
  delta_v, delta_w, _, _ = jax.vmap(world.frame_impacts, in_axes=(0, None))(obs, params)
  delta_v, delta_w = world.perturbation_bounds(delta_v, delta_w, params)  # bodies, then flexes
  alpha = params.perturb.alpha
  def ratio(d, delta):
    mag, lim = jnp.linalg.norm(d, axis=-1), alpha * jnp.linalg.norm(delta, axis=-1)
    return jnp.where(mag > 0, mag / jnp.maximum(lim, 1e-30), 0.0)
  worst = jnp.maximum(ratio(out.dv, delta_v), ratio(out.dw, delta_w)).max(axis=(1, 2))
  applied = jnp.any(out.dv != 0, -1) | jnp.any(out.dw != 0, -1)  # [W, S, B]
  mask = _body_mask(active, inter)
  if params.flex_weight.shape[0]:
    mask = jnp.concatenate([mask, world.flex_mask(mask, params)], axis=-1)
  stray = jnp.sum(applied & ~mask[:, None, :], axis=(1, 2))
  return worst, stray


def _body_mask(active: jax.Array, inter: interactions.InteractionParams) -> jax.Array:
  """bool[W, B] bodies of active objects."""
  return (active.astype(jnp.float32) @ inter.body_object.T) > 0.5


def start_active(inp: RefineInputs):
  """(active for frame f0, host speeds) from the stored path at f0."""
  p, f0 = inp.path, inp.first_frame
  c = len(inp.qpos0)
  frame_time = inp.params.dt * inp.params.steps_per_frame
  speed = np.linalg.norm(p.com[f0 + 1] - p.com[f0], axis=-1) / frame_time
  com = np.broadcast_to(p.com[f0], (c,) + p.com[f0].shape)
  return _activate_jit(jnp.asarray(inp.active0), jnp.asarray(com), jnp.broadcast_to(speed, (c, len(speed))),
                         jnp.asarray(p.com[f0]), jnp.asarray(p.com[f0 + 1]), inp.inter)


def _finish(inp, carry, qpos_buf, com_buf, active, activated, compile_seconds, run_seconds, audit,
            contact_overflow=None, events=None):
  frame_count = np.asarray(carry.frame_count)
  steps = np.asarray(carry.step) - inp.first_frame * inp.params.steps_per_frame
  chunk = ChunkResult(
      qpos=fill_tail(qpos_buf, frame_count), com=fill_tail(com_buf, frame_count), frame_count=frame_count,
      status=np.asarray(carry.status), metrics=world.finalize_metrics(carry),
      perturbations=np.asarray(carry.perturbations), steps=np.where(inp.running0, steps, 0).astype(np.int32),
      compile_seconds=compile_seconds, run_seconds=run_seconds, contact_overflow=contact_overflow)
  if events is not None:  # (rows, strength, count) found at every step
    chunk = chunk._replace(event_rows=events[0], event_strength=events[1], event_count=events[2])
  return RefineOutput(chunk=chunk, active=np.asarray(active), activated=activated,
                      max_perturbation_ratio=np.asarray(audit[0]), inactive_perturbations=np.asarray(audit[1]),
                      asleep_object_frames=np.zeros(len(np.asarray(audit[1])), np.int64))


_KERNELS: dict = {}


def _native_kernel(params: world.WorldParams, n_sensor: int):
  """The jitted per-frame kernel of the native loop (cached per params)."""
  cache_key = (id(params), n_sensor)
  if cache_key not in _KERNELS:
    def kernel(carry, sensordata, keys, active, frame, stored, inter):
      obs = jax.vmap(jax.vmap(lambda s: world.Observation.from_sensordata(s, params.gravity)))(
          sensordata[..., :n_sensor])
      obs = _with_stored_motion(obs, active, frame, stored, params, inter)
      com_now, com_next = stored[0][frame + 1], stored[0][frame + 2]
      carry, out = world.frame_update(carry, obs, keys, params, _body_mask(active, inter))
      speed = jnp.linalg.norm(obs.lin_vel[:, -1], axis=-1)
      nxt = _activate_batch(active, obs.com_pos[:, -1], speed, com_now, com_next, inter)
      worst, stray = _audit(obs, out, active, params, inter)
      # One array back to the host: each output fetched costs a transfer and a sync.
      n = carry.step.shape[0]
      columns = (out.wrench, obs.com_pos[:, 0], nxt, out.record, out.running, worst, stray)
      return carry, jnp.concatenate([x.reshape(n, -1).astype(jnp.float32) for x in columns], axis=1)
    _KERNELS[cache_key] = (params, jax.jit(kernel))
  return _KERNELS[cache_key][1]


def _unpack(packed: np.ndarray, spf: int, n_bodies: int, n_objects: int):
  """The native kernel's f32[C, K] output as (wrench f32[C, S, B, 6],
  com f32[C, B, 3], next active bool[C, O], record bool[C], running bool[C],
  worst ratio f32[C], stray perturbations i64[C])."""
  c = len(packed)
  ends = np.cumsum([spf * n_bodies * 6, n_bodies * 3, n_objects, 1, 1, 1, 1])
  wrench, com, nxt, record, running, worst, stray = np.split(packed, ends[:-1], axis=1)
  return (wrench.reshape(c, spf, n_bodies, 6), com.reshape(c, n_bodies, 3), nxt > 0.5, record[:, 0] > 0.5,
          running[:, 0] > 0.5, worst[:, 0], stray[:, 0].astype(np.int64))


def _steps_on_path(backend, states, wrench, warmstart, models, qmask, vmask, targets, qvel, sensors=True,
                   ctrl=None):
  """One frame as S one-step rollouts, inactive objects put on the stored
  path before each step after the first (``every_step`` playback).

  Args:
    states: f64[n, nstate] at the frame start (already on the path).
    wrench: f64[n, S, nbody * 6]; warmstart: f64[n, nv]; models: one per world.
    qmask: bool[n, nq]; vmask: bool[n, nv] coordinates of the objects
      inactive during the frame.
    targets: f32[S, nq] stored qpos at the frame's steps; qvel: f32[nv] the
      frame's chord velocity.
    sensors: as in :meth:`NativeBackend.step`.
    ctrl: optional f64[S, nu] actuator controls of the frame's steps.

  Returns:
    as :meth:`NativeBackend.step`.
  """
  m = backend.model
  qadr, vadr = slice(1, 1 + m.nq), slice(1 + m.nq, 1 + m.nq + m.nv)
  n, spf = wrench.shape[:2]
  out_states = np.empty((n, spf, backend.nstate))
  out_sensors = np.empty((n, spf, m.nsensordata if sensors else 0))
  current = states
  for j in range(spf):
    if j > 0:
      # `current` is the last call's own output (already copied out): reset in place.
      np.copyto(current[:, qadr], targets[j], where=qmask)
      np.copyto(current[:, vadr], qvel, where=vmask)
    after, step_sensors = backend.step(current, wrench[:, j:j + 1], warmstart, models, sensors=sensors,
                                       ctrl=None if ctrl is None else ctrl[j:j + 1])
    warmstart = (after[:, 0, vadr] - current[:, vadr]) / m.opt.timestep
    out_states[:, j] = after[:, 0]
    out_sensors[:, j] = step_sensors[:, 0]
    current = after[:, 0]
  return out_states, out_sensors


def run_native(backend, inp: RefineInputs, progress=None, every_step: bool = True) -> RefineOutput:
  """Refined worlds on the native backend (``mujoco.rollout`` per frame).

  ``every_step``: put inactive objects on the stored path before every
  physics step (S one-step rollout calls per frame); False: at every frame
  boundary only (one call per frame). Either way the rollout models of a
  world are :class:`stored_motion.ContactFreeModels` for its inactive objects.
  """
  m = backend.model
  params, inter, path = inp.params, inp.inter, inp.path
  c, spf, f0 = len(inp.qpos0), params.steps_per_frame, inp.first_frame
  nq, nv = m.nq, m.nv
  qadr, vadr = slice(1, 1 + nq), slice(1 + nq, 1 + nq + nv)
  n_sensor = len(inter.radius) * world.SENSOR_WIDTH
  body_ids = np.asarray(inp.body_ids)
  n_objects = inp.active0.shape[1]
  targets = None if inp.step_targets is None else inp.step_targets.reshape(-1, spf, nq)  # [F, S, nq]

  kernel = _native_kernel(params, n_sensor)
  use_sensors = inp.free_bodies is None  # else the sensor block comes from the states
  states = backend.initial_states(inp.qpos0, inp.qvel0, inp.act0)
  states[:, 0] = f0 * spf * m.opt.timestep
  warmstart = np.zeros((c, nv))
  wrench_full = np.zeros((c, spf, m.nbody, 6))
  sensordata = np.zeros((c, spf, m.nsensordata), np.float32)
  n_out = inp.n_frames - f0
  qpos_buf = np.zeros((c, n_out, nq), np.float32)
  com_buf = np.zeros((c, n_out, len(body_ids), 3), np.float32)
  qpos_object = inp.qpos_object.astype(np.float32)
  dof_object = inp.dof_object.astype(np.float32)

  t0 = time.perf_counter()
  active = start_active(inp)
  stored = tuple(jnp.asarray(x) for x in (path.com, path.quat, path.lin_vel, path.ang_vel))
  jax.block_until_ready(kernel(inp.carry0, sensordata, inp.step_keys, np.asarray(active), np.int32(f0),
                               stored, jax.device_put(inter)))
  compile_seconds = time.perf_counter() - t0

  t0 = time.perf_counter()
  carry = inp.carry0
  inter = jax.device_put(inter)
  running = np.asarray(inp.running0).copy()
  active = np.asarray(active)  # kept on the host between frames
  prev_inactive = ~np.asarray(inp.active0)
  activated = np.where(active, f0, -1).astype(np.int32)
  audit_ratio, audit_stray = np.zeros(c, np.float32), np.zeros(c, np.int64)
  masks = lambda inactive: ((inactive.astype(np.float32) @ qpos_object) > 0.5,
                            (inactive.astype(np.float32) @ dof_object) > 0.5)
  frame = f0
  while running.any():
    qmask, vmask = masks(prev_inactive)
    np.copyto(states[:, qadr], path.qpos[frame], where=qmask)
    np.copyto(states[:, vadr], path.qvel[frame], where=vmask)
    idx = np.flatnonzero(running)
    before = states[idx]
    inactive = ~active[idx]
    models = inp.models(inactive)
    wrench_in = wrench_full[idx].reshape(len(idx), spf, -1)
    ctrl = None if inp.ctrl is None else inp.ctrl[frame * spf:(frame + 1) * spf]
    if every_step:
      qmask, vmask = masks(inactive)
      after, sensors = _steps_on_path(backend, before, wrench_in, warmstart[idx], models, qmask, vmask,
                                      targets[frame], path.qvel[frame], sensors=use_sensors, ctrl=ctrl)
    else:
      after, sensors = backend.step(before, wrench_in, warmstart[idx], models, sensors=use_sensors,
                                    ctrl=ctrl)
    # Inactive objects' observations are replaced by their stored motion in
    # the kernel, so observing them from un-reset states is harmless.
    backend.absorb_frame(idx, before, after, sensors, sensordata, warmstart, states, inp.free_bodies)

    carry, packed = kernel(carry, sensordata, inp.step_keys, active, np.int32(frame), stored, inter)
    wrench, com, nxt, record, still, worst, stray = _unpack(np.asarray(packed), spf, len(body_ids), n_objects)
    audit_ratio = np.maximum(audit_ratio, worst)
    audit_stray += stray
    if record.any():
      rec = np.flatnonzero(record)
      qpos_buf[rec, frame - f0] = before[np.searchsorted(idx, rec), qadr]
      com_buf[rec, frame - f0] = com[rec]
    wrench_full[:, :, body_ids] = wrench
    running = still
    nxt = np.where(running[:, None], nxt, active)
    activated = np.where((activated < 0) & nxt, frame + 1, activated)
    prev_inactive = ~active
    active = nxt
    frame += 1
    if progress is not None and frame % 16 == 0:
      progress(int((np.asarray(carry.step) - f0 * spf).sum()), int((~running & inp.running0).sum()))
  run_seconds = time.perf_counter() - t0
  return _finish(inp, carry, qpos_buf, com_buf, active, activated, compile_seconds, run_seconds,
                 (audit_ratio, audit_stray))


def run_mjx(backend, inp: RefineInputs, progress=None, frames_per_block: int = 30) -> RefineOutput:
  """Refined worlds on the MJX backend: blocks of frames as one jitted loop
  (:func:`mwbx.batch_sim.mjx_backend.frame_block`), inactive objects put on
  the stored path before every physics step."""
  from mwbx.batch_sim.mjx_backend import FRAMES_PER_BLOCK  # lazy: imports mujoco.mjx (seconds)
  m = backend.model
  params, inter, path = inp.params, inp.inter, inp.path
  c, spf, f0 = len(inp.qpos0), params.steps_per_frame, inp.first_frame
  n_out = inp.n_frames - f0
  block = min(frames_per_block or FRAMES_PER_BLOCK, n_out)
  consts = (jnp.asarray(inp.step_targets), jnp.asarray(path.qvel), jnp.asarray(path.com),
            jnp.asarray(inp.qpos_object, jnp.float32), jnp.asarray(inp.dof_object, jnp.float32), inter,
            tuple(jnp.asarray(x) for x in (path.com, path.quat, path.lin_vel, path.ang_vel)),
            None if inp.ctrl is None or inp.ctrl.shape[1] == 0 else jnp.asarray(inp.ctrl, jnp.float32))
  events = backend.event_inputs(inp.event_objects) if inp.event_objects is not None else None
  run = _mjx_block(backend, params, np.asarray(inp.body_ids), block, len(inter.radius) * world.SENSOR_WIDTH, events)
  d = backend.make_data(jnp.asarray(inp.qpos0), jnp.asarray(inp.qvel0),
                        None if inp.act0 is None else jnp.asarray(inp.act0))
  d = d.replace(time=jnp.full((c,), f0 * spf * m.opt.timestep, d.time.dtype))
  t0 = time.perf_counter()
  active = start_active(inp)
  wrench = jnp.zeros((c, spf, len(inp.body_ids), 6), jnp.float32)
  tracks = None if events is None else mjx_events.new_tracks(c, events)
  state = (d, inp.carry0, wrench, inp.step_keys, active, jnp.asarray(~np.asarray(inp.active0)),
           jnp.int32(f0), jnp.zeros(c, bool), tracks)
  # Committed like the block's outputs, so later blocks reuse the first compile.
  state, consts = jax.device_put((state, consts), jax.devices()[0])
  state, first = run(state, consts, jnp.int32(min(block, n_out)))  # compiled on first use
  jax.block_until_ready(state)
  compile_seconds = time.perf_counter() - t0

  qpos_buf = np.zeros((c, n_out, m.nq), np.float32)
  com_buf = np.zeros((c, n_out, len(inp.body_ids), 3), np.float32)
  activated = np.where(np.asarray(active), f0, -1).astype(np.int32)
  audit_ratio, audit_stray = np.zeros(c, np.float32), np.zeros(c, np.int64)
  t0 = time.perf_counter()
  start, pending = 0, first
  while start < n_out:
    if pending is None:
      state, pending = run(state, consts, jnp.int32(min(block, n_out - start)))
    (record, qpos, com, nxt, (worst, stray)), pending = pending, None
    record, qpos, com, nxt = (np.asarray(x) for x in (record, qpos, com, nxt))
    audit_ratio = np.maximum(audit_ratio, np.asarray(worst).max(axis=0))
    audit_stray += np.asarray(stray).sum(axis=0)
    stop = min(start + block, n_out)
    f, w = np.nonzero(record[:stop - start])
    qpos_buf[w, start + f] = qpos[f, w]
    com_buf[w, start + f] = com[f, w]
    for i in range(stop - start):
      activated = np.where((activated < 0) & nxt[i], f0 + start + i + 1, activated)
    start = stop
    status = np.asarray(state[1].status)
    if progress is not None:
      progress(int((np.asarray(state[1].step) - f0 * spf).sum()), int((status != world.RUNNING).sum()))
    if (status != world.RUNNING).all():
      break
  jax.block_until_ready(state)
  run_seconds = time.perf_counter() - t0
  found = None
  if events is not None:  # a world ends at its last frame's first step
    last_ticks = (f0 + np.asarray(state[1].frame_count).astype(np.int64) - 1) * spf
    found = mjx_events.finish_tracks(state[8], last_ticks, events.n_actors)
  return _finish(inp, state[1], qpos_buf, com_buf, state[4], activated, compile_seconds, run_seconds,
                 (audit_ratio, audit_stray), contact_overflow=np.asarray(state[7]), events=found)


_BLOCKS: dict = {}


def _mjx_block(backend, params: world.WorldParams, body_ids: np.ndarray, block: int, n_sensor: int, events=None):
  """``run(state, consts, count)`` for up to ``block`` refined frames on MJX
  (cached); ``events``: contact episodes found at every step
  (:mod:`mwbx.batch_sim.mjx_events`, the state's last entry)."""
  from mwbx.batch_sim.mjx_backend import frame_block, hold_finished, scatter_wrench  # lazy: mujoco.mjx
  cache_key = (id(backend), id(params), block, n_sensor, events is not None)
  if cache_key in _BLOCKS:
    return _BLOCKS[cache_key][2]
  spf = params.steps_per_frame
  nbody = backend.model.nbody
  ids = jnp.asarray(body_ids)

  def put_on_path(d, inactive, frame, j, consts):
    targets, qvel_path, _, qpos_object, dof_object, _, _, _ = consts
    qm = (inactive.astype(jnp.float32) @ qpos_object) > 0.5
    vm = (inactive.astype(jnp.float32) @ dof_object) > 0.5
    return d.replace(qpos=jnp.where(qm, targets[frame * spf + j], d.qpos),
                     qvel=jnp.where(vm, qvel_path[frame], d.qvel))

  def frame_fn(consts, state):  # one refined frame: see mjx_backend.frame_block
    com_path, inter = consts[2], consts[5]
    d, carry, wrench, keys, active, prev_inactive, frame, overflow, tracks = state
    d = put_on_path(d, prev_inactive, frame, 0, consts)
    qpos = d.qpos
    running = carry.status == world.RUNNING

    def physics_step(stepping, inputs):
      d, tracks = stepping
      j, xfrc_tracked = inputs
      d = jax.lax.cond(j > 0, lambda x: put_on_path(x, ~active, frame, j, consts), lambda x: x, d)
      ctrl_table = consts[7]
      if ctrl_table is not None:  # f32[N, nu], row k: step k's control, the same for every world
        row = jnp.minimum(frame * spf + j, ctrl_table.shape[0] - 1)
        d = d.replace(ctrl=jnp.broadcast_to(ctrl_table[row], d.ctrl.shape).astype(d.ctrl.dtype))
      d = backend.step(d, scatter_wrench(xfrc_tracked, nbody, ids))
      if events is not None:  # tick: the step's index from the world's start
        tracks = mjx_events.track_step(tracks, d, backend.impl, events, carry.step + j, running, params.dt)
      return (d, tracks), (d.sensordata, backend.overflow(d))

    (d_next, tracks), (sensordata, step_overflow) = jax.lax.scan(
        physics_step, (d, tracks), (jnp.arange(spf), jnp.swapaxes(wrench, 0, 1)))
    # Over the contact budget in a step of a running world (mjx_backend.MjxBackend.overflow).
    overflow = overflow | (step_overflow.any(axis=0) & (carry.status == world.RUNNING))
    sensordata = jnp.swapaxes(sensordata, 0, 1)[..., :n_sensor]
    obs = jax.vmap(jax.vmap(lambda s: world.Observation.from_sensordata(s, params.gravity)))(sensordata)
    obs = _with_stored_motion(obs, active, frame, consts[6], params, inter)
    carry, out = world.frame_update(carry, obs, keys, params, _body_mask(active, inter))
    speed = jnp.linalg.norm(obs.lin_vel[:, -1], axis=-1)
    nxt = _activate_batch(active, obs.com_pos[:, -1], speed, com_path[frame + 1], com_path[frame + 2], inter)
    nxt = jnp.where(out.running[:, None], nxt, active)
    d = hold_finished(out.running, d_next, d)
    audit = _audit(obs, out, active, params, inter)
    return ((d, carry, out.wrench, keys, nxt, ~active, frame + 1, overflow, tracks),
            (out.record, qpos, obs.com_pos[:, 0], nxt, audit))

  fn = frame_block(frame_fn, block)
  _BLOCKS[cache_key] = (backend, params, fn)
  return fn
