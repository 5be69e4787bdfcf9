"""Refined worlds on the native backend, each in compiled calls (paper §5:
refinement cheaper than sampling).

The lockstep loop (:func:`loop.run_native`) steps every refined world of a
batch through ``mujoco.rollout`` one physics step at a time, with a jitted
kernel per frame: its cost per step is Python and dispatch, more than the
physics of the few objects that move. Here, as in sampling's
:mod:`mwbx.batch_sim.compiled_world`, a numba function (no GIL) steps ONE refined
world with MuJoCo's C ``mj_step`` frame after frame and runs the same
per-frame work on it:

1. objects inactive before the frame are put on their stored state (decoded
   ``qpos[f]``, chord ``qvel[f]``);
2. the frame's S physics steps in a model where objects inactive during the
   frame collide with nothing (:class:`stored_motion.ContactFreeModels`):
   their trees asleep where MuJoCo's island sleep allows it (``mj_step``
   skips them; what is recorded of them is the stored frame), else put back
   on the stored path before every step after the first (``playback="step"``);
3. the observations (MuJoCo's sensors, or the states of free bodies), with
   inactive bodies reporting their stored motion (COM along the chord, chord
   velocities, no contact acceleration);
4. the bookkeeping (:func:`host_bookkeeping.frame_update`) with only active
   bodies perturbable, and the plausibility audit;
5. the interaction test (:func:`interactions.activate_host`, the numba twin
   of :func:`interactions.activate`).

When the active set grows, the call returns so that the host can hand it the
contact-free model of the new inactive set, and the world goes on from where
it was (its ``MjData`` is kept). A thread per core pulls worlds from a shared
counter (:meth:`NativeBackend.run_per_world`). World i still depends only on
the parent, t_min, the objects and ``(key, i)``.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from typing import NamedTuple

import jax
import mujoco
import numpy as np

from mwbx.batch_sim import free_bodies, host_bookkeeping, host_loops, mujoco_c, world
from mwbx.batch_sim.backend import ChunkResult, fill_tail
from mwbx.batch_sim import compiled_world
from mwbx.batch_sim.compiled_world import WorldInputs, physics_step
from mwbx.batch_sim.host_bookkeeping import ChunkBuffers
from mwbx.batch_sim.compiled_world import monotonic_seconds as _now
from mwbx.host_jit import borrowed, held, host_jit
from mwbx.refinement import interactions
from mwbx.refinement.loop import RefineOutput, start_active
from mwbx.scene import ANG_ACC, ANG_VEL, COM_POS, LIN_ACC, LIN_VEL, QUAT, SENSOR_WIDTH


_get_state = mujoco_c.mj_getState
_kinematics = mujoco_c.mj_kinematics
_update_sleep = mujoco_c.mj_updateSleep
_FULLPHYSICS = mujoco_c.STATE_FULLPHYSICS
_TREE_AWAKE = mujoco_c.TREE_AWAKE

# What a call of run_refined_world ended with.
FINISHED = 0
ACTIVATED = 1  # the active set grew: call again with the new inactive set's model


class ParentMotion(NamedTuple):
  """The parent's stored motion: where the refined worlds start and the path
  inactive objects play back (:class:`stored_motion.StoredPath`, as f32 host arrays).

  Attributes:
    first_frame: f0, the parent's frame the refined worlds start from.
    qpos: f32[F, nq] decoded frames (m, rad; free-joint quaternions w, x, y, z).
    qvel: f32[F, nv] chord velocity from frame f to f + 1 (m/s, rad/s).
    step_targets: f32[F · S, nq] playback ``qpos`` of each physics step.
    com: f32[F, B, 3] tracked bodies' centres of mass, m.
    quat: f32[F, B, 4] tracked bodies' inertial-frame orientations (w, x, y, z).
    lin_vel: f32[F, B, 3] COM chord velocity from frame f to f + 1, m/s.
    ang_vel: f32[F, B, 3] chord angular velocity (world frame), rad/s.
  """

  first_frame: int
  qpos: np.ndarray
  qvel: np.ndarray
  step_targets: np.ndarray
  com: np.ndarray
  quat: np.ndarray
  lin_vel: np.ndarray
  ang_vel: np.ndarray


class Members(NamedTuple):
  """What belongs to each object (its ``qpos`` coordinates, dofs or trees)
  as lists: object o's are ``ids[adr[o]:adr[o + 1]]`` (per-frame loops walk
  an object's few members, not a mask over the whole model)."""

  adr: np.ndarray
  ids: np.ndarray


def members(mask: np.ndarray) -> Members:
  """:class:`Members` of ``mask: bool[O, n]``."""
  mask = np.asarray(mask, bool)
  return Members(adr=np.concatenate([[0], np.cumsum(mask.sum(axis=1))]).astype(np.int64),
                 ids=np.nonzero(mask)[1].astype(np.int64))


class RefineObjects(NamedTuple):
  """The scene's objects as the refined worlds see them (read only).

  Attributes:
    qpos: :class:`Members`, the ``qpos`` coordinates of each object.
    dofs: :class:`Members`, the dofs of each object.
    perturbable: bool[B] the scene's perturbable tracked bodies (only those
      of active objects are perturbed).
    flex_perturbable: bool[F] the scene's perturbable flexes (alike).
    flex_object: i64[F] the object of each flex.
    interaction: :class:`interactions.HostInteraction` of the interaction test.
    trees: :class:`Members`, the kinematic trees of each object.
    tree_dofadr: i64[ntree], tree_dofnum: i64[ntree] each tree's dofs.
    sleep_inactive: inactive objects are held asleep (their trees put to
      sleep where they are, the stored path written only into what is
      recorded), not moved along the stored path every step: the models
      (:class:`stored_motion.ContactFreeModels` with ``sleeps``) enable sleeping.
  """

  qpos: Members
  dofs: Members
  perturbable: np.ndarray
  flex_perturbable: np.ndarray
  flex_object: np.ndarray
  interaction: interactions.HostInteraction
  trees: Members
  tree_dofadr: np.ndarray
  tree_dofnum: np.ndarray
  sleep_inactive: bool


class RefinedWorlds(NamedTuple):
  """Per-world refinement state and audit of a chunk, updated in place; row i
  belongs to world i and is written only by the thread running it.

  Attributes:
    frame_of: i64[C] the next frame of each world.
    active: bool[C, O] objects simulated in the coming frame.
    prev_inactive: bool[C, O] objects inactive in the last frame.
    activated: i32[C, O] frame each object became active, -1: never.
    audit_ratio: f64[C] largest ``‖dv‖ / (α‖Δv‖)`` (or angular alike) of
      the perturbations applied.
    audit_stray: i64[C] perturbations applied to bodies not perturbable.
    asleep: i64[C] frames x inactive objects whose trees were asleep.
  """

  frame_of: np.ndarray
  active: np.ndarray
  prev_inactive: np.ndarray
  activated: np.ndarray
  audit_ratio: np.ndarray
  audit_stray: np.ndarray
  asleep: np.ndarray


@host_jit
def _put_on(data_qpos, data_qvel, o, objects, qpos_target, qvel_target):
  """Sets object ``o``'s coordinates and velocities to the targets."""
  q, v = objects.qpos, objects.dofs
  for i in range(q.adr[o], q.adr[o + 1]):
    data_qpos[q.ids[i]] = qpos_target[q.ids[i]]
  for i in range(v.adr[o], v.adr[o + 1]):
    data_qvel[v.ids[i]] = qvel_target[v.ids[i]]


@host_jit
def _put_on_path(data_qpos, data_qvel, chosen, objects, qpos_target, qvel_target):
  """Sets the coordinates of the ``chosen`` objects (bool[O]) to the targets."""
  for o in range(chosen.size):
    if chosen[o]:
      _put_on(data_qpos, data_qvel, o, objects, qpos_target, qvel_target)


@host_jit
def _awake(tree_asleep, o, trees):
  """Whether a tree of object ``o`` is awake."""
  for i in range(trees.adr[o], trees.adr[o + 1]):
    if tree_asleep[trees.ids[i]] < 0:
      return True
  return False


@host_jit
def _hold_inactive_asleep(data, active, prev_inactive, objects, qpos_target, qvel_target):
  """At a frame start (``sleep_inactive``): objects active since the last
  frame start from their stored state (``qpos_target``, ``qvel_target``)
  awake; inactive objects not yet asleep are put on their stored state and
  to sleep there, each tree its own sleeping island (velocity zero).
  Returns how many inactive objects are asleep.

  MuJoCo wakes a sleeping body whose pose no longer matches its ``qpos``, so
  the bodies' poses are computed (``mj_kinematics``) before their trees sleep;
  those asleep stay where they fell asleep (moving them would wake them).
  """
  trees = objects.trees
  n_objects = active.size
  changed = False
  for o in range(n_objects):
    if not (prev_inactive[o] and active[o]):
      continue
    _put_on(data.qpos, data.qvel, o, objects, qpos_target, qvel_target)
    for i in range(trees.adr[o], trees.adr[o + 1]):
      if data.tree_asleep[trees.ids[i]] >= 0:
        data.tree_asleep[trees.ids[i]] = _TREE_AWAKE  # a tree of its own island: wakes alone
        changed = True
  if changed:
    _update_sleep(data.model_adr, data.data_adr)
  falling = False
  for o in range(n_objects):
    if not active[o] and _awake(data.tree_asleep, o, trees):
      falling = True
      _put_on(data.qpos, data.qvel, o, objects, qpos_target, qvel_target)  # its velocities are zeroed below
  if falling:
    _kinematics(data.model_adr, data.data_adr)
    for o in range(n_objects):
      if active[o]:
        continue
      for i in range(trees.adr[o], trees.adr[o + 1]):
        t = trees.ids[i]
        if data.tree_asleep[t] < 0:
          data.tree_asleep[t] = t
          for a in range(objects.tree_dofadr[t], objects.tree_dofadr[t] + objects.tree_dofnum[t]):
            data.qvel[a] = 0.0
    _update_sleep(data.model_adr, data.data_adr)
  asleep = 0
  for o in range(n_objects):
    if not active[o] and not _awake(data.tree_asleep, o, trees):
      asleep += 1
  return asleep


@host_jit
def _stored_motion(sensordata_row, active, body_object, frame, path_com, path_quat, path_lin_vel, path_ang_vel):
  """Inactive bodies' sensor blocks (f32[S, B·W], in place) from the stored
  path: COM along the chord f → f + 1, the frame's orientation and chord
  velocities, no contact acceleration (twin of ``loop._with_stored_motion``)."""
  n_steps = sensordata_row.shape[0]
  for b in range(body_object.size):
    if active[body_object[b]]:
      continue
    o = b * SENSOR_WIDTH
    for s in range(n_steps):
      a_frac = np.float32(s) / np.float32(n_steps)
      for a in range(3):
        sensordata_row[s, o + COM_POS + a] = path_com[frame, b, a] + a_frac * (
            path_com[frame + 1, b, a] - path_com[frame, b, a])
        sensordata_row[s, o + LIN_VEL + a] = path_lin_vel[frame, b, a]
        sensordata_row[s, o + ANG_VEL + a] = path_ang_vel[frame, b, a]
        sensordata_row[s, o + LIN_ACC + a] = 0.0  # the sensor reads a - g: free motion
        sensordata_row[s, o + ANG_ACC + a] = 0.0
      for a in range(4):
        sensordata_row[s, o + QUAT + a] = path_quat[frame, b, a]


@host_jit
def _audit(sensordata_row, wrench_row, tracked, p, dt, flex_delta):
  """(largest ``‖dv‖ / (α‖Δv‖)`` or angular alike, perturbations on bodies
  not perturbable) of one frame's next wrenches (f64[S, nbody, 6]); a flex's
  bodies are held to its velocity change (``flex_delta`` f64[3] scratch)."""
  worst = 0.0
  stray = 0
  alpha = p.perturb.alpha
  n_bodies = tracked.size
  for s in range(wrench_row.shape[0]):
    for b in range(n_bodies):
      w = wrench_row[s, tracked[b]]
      if w[0] == 0.0 and w[1] == 0.0 and w[2] == 0.0 and w[3] == 0.0 and w[4] == 0.0 and w[5] == 0.0:
        continue
      flex = -1
      for f in range(p.flex_perturbable.size):
        if p.flex_weight[f, b] != 0.0:
          flex = f
      if not (p.perturbable[b] or (flex >= 0 and p.flex_perturbable[flex])):
        stray += 1
      o = b * SENSOR_WIDTH
      q = sensordata_row[s, o + QUAT:o + QUAT + 4]
      norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
      r00, r01, r02, r10, r11, r12, r20, r21, r22 = host_loops.rotation_matrix(
          q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)
      dv = math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) * dt / p.mass[b]
      # dw = R · diag(1/I) · Rᵀ · torque · dt (inverse of the impulse wrench)
      bx = (r00 * w[3] + r10 * w[4] + r20 * w[5]) / p.inertia[b, 0]
      by = (r01 * w[3] + r11 * w[4] + r21 * w[5]) / p.inertia[b, 1]
      bz = (r02 * w[3] + r12 * w[4] + r22 * w[5]) / p.inertia[b, 2]
      dw = math.sqrt(bx * bx + by * by + bz * bz) * dt
      if flex >= 0:  # the flex's velocity change: its bodies' mass-weighted mean
        flex_delta[:] = 0.0
        for i in range(n_bodies):
          for a in range(3):
            flex_delta[a] += p.flex_weight[flex, i] * dt * float(sensordata_row[s, i * SENSOR_WIDTH + LIN_ACC + a])
        delta_v = math.sqrt(flex_delta[0] ** 2 + flex_delta[1] ** 2 + flex_delta[2] ** 2)
        delta_w = 0.0
      else:
        delta_v = dt * math.sqrt(float(sensordata_row[s, o + LIN_ACC]) ** 2
                                 + float(sensordata_row[s, o + LIN_ACC + 1]) ** 2
                                 + float(sensordata_row[s, o + LIN_ACC + 2]) ** 2)
        delta_w = dt * math.sqrt(float(sensordata_row[s, o + ANG_ACC]) ** 2
                                 + float(sensordata_row[s, o + ANG_ACC + 1]) ** 2
                                 + float(sensordata_row[s, o + ANG_ACC + 2]) ** 2)
      if dv > 0.0:
        worst = max(worst, dv / max(alpha * delta_v, 1e-30))
      if dw > 0.0:
        worst = max(worst, dw / max(alpha * delta_w, 1e-30))
  return worst, stray


@host_jit
def run_refined_world(row, data, inputs, parent, objects, buffers, refined, running, events, world_events):
  """Runs refined world ``row`` until it finishes or its active set grows.

  Args:
    row: chunk row of the world.
    data: :class:`mujoco_c.MjDataViews` of this thread's ``MjData``, its
      ``model_adr`` the contact-free model of the world's current inactive set.
    inputs: :class:`compiled_world.WorldInputs` (``ctrl_table`` from step 0).
    parent: :class:`ParentMotion`.
    objects: :class:`RefineObjects`.
    buffers: :class:`host_bookkeeping.ChunkBuffers` as in sampling (recording
      from f0: ``qpos_buf[row, f - f0]``); ``buffers.params.perturbable`` and
      ``flex_perturbable`` are this thread's own bool[B] and bool[F],
      rewritten here for the world's active objects.
    refined: :class:`RefinedWorlds` (row ``row`` updated).
    running: bool[C] as in sampling (out).
    events: :class:`compiled_world.StepEventInputs`; world_events: the
      world's :class:`compiled_world.WorldEvents`, kept across calls.

  Returns:
    (FINISHED or ACTIVATED, seconds inside ``mj_step``).
  """
  # The arguments without reference counting from here on (the caller holds them; host_jit.borrowed).
  data, inputs, parent, objects, b, refined, running, events, world_events = borrowed(
      (data, inputs, parent, objects, buffers, refined, running, events, world_events))
  p, inter = b.params, objects.interaction
  free, timestep = inputs.free, inputs.timestep
  active, prev_inactive = refined.active, refined.prev_inactive
  frame_of = refined.frame_of
  n_steps = b.wrench_full.shape[1]
  nstate = b.states.shape[1]
  nq = b.qpos_buf.shape[2]
  n_bodies = b.tracked_ids.size
  n_objects = active.shape[1]
  owned = (np.full(1, row, np.int64), np.empty((1, nstate)), np.empty((1, n_steps, nstate)),
           np.zeros((1, n_steps, 0 if free else data.sensordata.size)), np.empty((n_bodies, 3)),
           np.empty(n_bodies), np.empty(n_objects, np.bool_), np.empty(n_objects, np.bool_), np.zeros(2, np.int64),
           np.empty(3))
  # this world's scratch, held to the end
  rows, before, after, sensors, com_sim, speed_sim, inactive, nxt, ts, flex_delta = borrowed(owned)
  physics = 0.0
  for i in range(n_bodies):
    p.perturbable[i] = objects.perturbable[i] and active[row, inter.body_object[i]]
  for f in range(objects.flex_perturbable.size):
    p.flex_perturbable[f] = objects.flex_perturbable[f] and active[row, objects.flex_object[f]]
  nv = data.qvel.size
  while running[row] and frame_of[row] < inputs.n_frames:
    frame = frame_of[row]
    for o in range(n_objects):
      inactive[o] = not active[row, o]
    if objects.sleep_inactive:
      refined.asleep[row] += _hold_inactive_asleep(data, active[row], prev_inactive[row], objects,
                                                   parent.qpos[frame], parent.qvel[frame])
    else:
      _put_on_path(data.qpos, data.qvel, prev_inactive[row], objects, parent.qpos[frame], parent.qvel[frame])
    _get_state(data.model_adr, data.data_adr, before[0].ctypes.data, _FULLPHYSICS)
    if objects.sleep_inactive:  # asleep where they were put: what is recorded is the stored frame
      _put_on_path(before[0, 1:1 + nq], before[0, 1 + nq:1 + nq + nv], inactive, objects, parent.qpos[frame],
                   parent.qvel[frame])
    start = _now(ts)
    for s in range(n_steps):
      if s > 0 and not objects.sleep_inactive:
        _put_on_path(data.qpos, data.qvel, inactive, objects, parent.step_targets[frame * n_steps + s],
                     parent.qvel[frame])
      physics_step(data, b.wrench_full[row, s], inputs.ctrl_table, frame * n_steps + s, after[0, s], free,
                   sensors[0, s])
      if events.on:  # (inside the physics timing: a few per cent of a step)
        compiled_world.step_events(data, events, world_events, frame * n_steps + s, timestep)
    physics += _now(ts) - start
    host_loops.absorb_rows(rows, before, after, sensors, timestep, 1 + nq, b.sensordata, b.warmstart, b.states)
    if free:
      host_loops.observe_free_bodies(rows, before, after, timestep, inputs.gravity, 1, 1 + nq,
                                     inputs.free_bodies, b.sensordata)
    _stored_motion(b.sensordata[row], active[row], inter.body_object, frame, parent.com, parent.quat,
                   parent.lin_vel, parent.ang_vel)
    host_bookkeeping.frame_update(rows, b, before, 1, frame - parent.first_frame, running)
    worst, stray = _audit(b.sensordata[row], b.wrench_full[row], b.tracked_ids, p, timestep, flex_delta)
    refined.audit_ratio[row] = max(refined.audit_ratio[row], worst)
    refined.audit_stray[row] += stray
    # The interaction test for the next frame, on the last step's observations.
    last = b.sensordata[row, n_steps - 1]
    for i in range(n_bodies):
      o = i * SENSOR_WIDTH
      for a in range(3):
        com_sim[i, a] = last[o + COM_POS + a]
      speed_sim[i] = math.sqrt(float(last[o + LIN_VEL]) ** 2 + float(last[o + LIN_VEL + 1]) ** 2
                               + float(last[o + LIN_VEL + 2]) ** 2)
    interactions.activate_host(active[row], com_sim, speed_sim, parent.com[frame + 1], parent.com[frame + 2],
                               inter, nxt)
    grew = False
    for o in range(n_objects):
      prev_inactive[row, o] = not active[row, o]
      if running[row] and nxt[o] and not active[row, o]:
        active[row, o] = True
        refined.activated[row, o] = frame + 1
        grew = True
    frame_of[row] = frame + 1
    if grew:
      held(owned)
      return ACTIVATED, physics
  held(owned)
  return FINISHED, physics


def run_compiled(backend, inp, progress=None):
  """Refined worlds on the native backend, each world in compiled calls
  (``playback="step"``); same inputs and output as :func:`loop.run_native`.

  Args:
    backend: the :class:`~mwbx.batch_sim.native_backend.NativeBackend`.
    inp: :class:`loop.RefineInputs` (``models`` and ``step_targets`` required).
    progress: optional callback(world_steps_done, worlds_finished).
  """
  m = backend.model
  params, path = inp.params, inp.path
  c, spf, f0 = len(inp.qpos0), params.steps_per_frame, inp.first_frame
  n_out = inp.n_frames - f0
  body_ids = np.asarray(inp.body_ids, np.int64)
  n_bodies, n_objects = len(body_ids), inp.active0.shape[1]
  free, bodies = free_bodies.host_arrays(inp.free_bodies)
  p = host_bookkeeping.host_params(params)
  carry = host_bookkeeping.init_carry(n_bodies, inp.running0)
  carry0 = inp.carry0
  for name in ("step", "metrics", "prev_com", "init_quat"):
    getattr(carry, name)[...] = np.asarray(getattr(carry0, name))
  running = np.asarray(inp.running0).copy()
  active = np.array(start_active(inp), bool)
  refined = RefinedWorlds(
      frame_of=np.full(c, f0, np.int64), active=active, prev_inactive=~np.asarray(inp.active0, bool),
      activated=np.where(active, f0, -1).astype(np.int32), audit_ratio=np.zeros(c),
      audit_stray=np.zeros(c, np.int64), asleep=np.zeros(c, np.int64))
  buffers = ChunkBuffers(
      params=p, key_data=np.asarray(jax.random.key_data(inp.step_keys), np.uint32), tracked_ids=body_ids,
      states=np.zeros((c, backend.nstate)), warmstart=np.zeros((c, m.nv)),
      sensordata=np.zeros((c, spf, m.nsensordata), np.float32), wrench_full=np.zeros((c, spf, m.nbody, 6)),
      qpos_buf=np.zeros((c, n_out, m.nq), np.float32), com_buf=np.zeros((c, n_out, n_bodies, 3), np.float32),
      carry=carry)
  ctrl = np.zeros((1, 0)) if inp.ctrl is None else np.ascontiguousarray(inp.ctrl, np.float64)  # width 0: none
  inputs = WorldInputs(ctrl_table=ctrl, n_frames=inp.n_frames, timestep=m.opt.timestep,
                       gravity=np.asarray(m.opt.gravity, np.float64), free=free, free_bodies=bodies)
  f32 = lambda x: np.ascontiguousarray(np.asarray(x, np.float32))
  parent = ParentMotion(
      first_frame=f0, qpos=f32(path.qpos), qvel=f32(path.qvel), step_targets=f32(inp.step_targets),
      com=f32(path.com), quat=f32(path.quat), lin_vel=f32(path.lin_vel), ang_vel=f32(path.ang_vel))
  interaction = interactions.host_interaction(inp.inter)
  objects = RefineObjects(
      qpos=members(inp.qpos_object), dofs=members(inp.dof_object), perturbable=p.perturbable.copy(),
      flex_perturbable=p.flex_perturbable.copy(),
      flex_object=np.array([interaction.body_object[np.flatnonzero(w)[0]] for w in p.flex_weight], np.int64),
      interaction=interaction, trees=members(inp.models.tree_object),
      tree_dofadr=m.tree_dofadr.astype(np.int64), tree_dofnum=m.tree_dofnum.astype(np.int64),
      sleep_inactive=inp.models.sleeps)
  models_lock = threading.Lock()
  thread_buffers = threading.local()

  def model_for(row):
    with models_lock:
      return inp.models(~active[row:row + 1])[0]

  # Contacts found at every step; an actor moves while a tree of it is awake (inactive objects sleep).
  events = (backend.step_events(inp.event_objects)._replace(sleep=True) if inp.event_objects is not None
            else compiled_world.step_event_inputs(m, None, spf))
  found = compiled_world.event_buffers(c, events)

  def call(row, model, data, flags, world_events):
    if not hasattr(thread_buffers, "b"):  # each thread rewrites its own perturbable masks
      thread_buffers.b = buffers._replace(params=p._replace(
          perturbable=objects.perturbable.copy(), flex_perturbable=objects.flex_perturbable.copy()))
    return run_refined_world(row, mujoco_c.data_views(model, data), inputs, parent, objects, thread_buffers.b,
                             refined, flags, events, world_events)

  # Where inactive objects sleep, MuJoCo computes the poses of static geoms
  # only while nothing sleeps (they never move): once per world, before any
  # tree is put to sleep, with sleeping off.
  awake_model = None
  if objects.sleep_inactive:
    awake_model = copy.copy(m)  # mj_copyModel
    awake_model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)

  def work(row, data):
    mujoco.mj_resetData(m, data)
    data.qpos[:] = inp.qpos0[row]
    data.qvel[:] = inp.qvel0[row]
    if inp.act0 is not None:
      data.act[:] = inp.act0[row]
    data.time = f0 * spf * m.opt.timestep
    if awake_model is not None:
      mujoco.mj_kinematics(awake_model, data)
    physics = 0.0
    world_events = compiled_world.new_world_events(events, found, row)
    while True:
      code, seconds = call(row, model_for(row), data, running, world_events)
      physics += seconds
      if code == FINISHED:
        if events.on:
          found.count[row] = compiled_world.finish_events(events, world_events,
                                                          (f0 + int(carry.frame_count[row]) - 1) * spf)
        return physics

  base = inp.models(np.zeros((1, n_objects), bool))[0]
  t0 = time.perf_counter()
  call(0, base, mujoco.MjData(base), np.zeros(c, bool), compiled_world.new_world_events(events, found, 0))  # compiles
  compile_seconds = time.perf_counter() - t0

  def poll():
    if progress is not None:
      progress(int((carry.step - f0 * spf)[inp.running0].sum()), int((~running & inp.running0).sum()))

  t0 = time.perf_counter()
  _, _, sim_errors = backend.run_per_world(np.flatnonzero(inp.running0), work, base, running, carry.status, poll)
  run_seconds = time.perf_counter() - t0
  frame_count = carry.frame_count.astype(np.int32)
  steps = np.where(inp.running0, carry.step - f0 * spf, 0).astype(np.int32)
  chunk = ChunkResult(
      qpos=fill_tail(buffers.qpos_buf, frame_count), com=fill_tail(buffers.com_buf, frame_count),
      frame_count=frame_count, status=carry.status.astype(np.int32),
      metrics=world.finalize_metrics(carry).astype(np.float32),
      perturbations=carry.perturbations.astype(np.int32), steps=steps, compile_seconds=compile_seconds,
      run_seconds=run_seconds, errors=tuple(sim_errors))
  if events.on:
    chunk = chunk._replace(event_rows=found.rows, event_strength=found.strength, event_count=found.count)
  return RefineOutput(chunk=chunk, active=active, activated=refined.activated,
                      max_perturbation_ratio=refined.audit_ratio.astype(np.float32),
                      inactive_perturbations=refined.audit_stray, asleep_object_frames=refined.asleep)
