"""The bookkeeping of :mod:`mwbx.batch_sim.world`, compiled for the host.

The native backend steps worlds on CPU threads, and after each frame it needs
each world's bookkeeping for the frame just stepped:
perturbations, metrics, rest and instability, and the frame to record. As the
jitted, vmapped :func:`world.frame_update` that cost about 1 ms per frame of
256 worlds (dispatch, and every world of the chunk whether it still runs or
not), 10–25 % on top of the physics. Here the same arithmetic is one numba loop
over the worlds that ran, in float64 from the float32 sensors: about 0.4 ms
(quickstart, 4 bodies) and 0.6 ms (pachinko, 8 bodies) per frame of 256
worlds, and less as worlds finish.

:func:`world.frame_update` stays the definition (MJX and refinement use it);
the tests run both on the same observations and compare them. The uniforms of
a perturbation are drawn exactly as :func:`mwbx.perturb.sparse.body_step_uniforms`
draws them (threefry-2x32 as in ``jax.random``, checked bit for bit), so the
two give the same perturbations up to float rounding.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mwbx.batch_sim import host_loops, world
from mwbx.batch_sim.world import (ANGULAR_TRAVEL, COLLISIONS, MAX_HEIGHT, ORIENTATION_ERROR, PATH_LENGTH,
                                   REST_TIME)
from mwbx.host_jit import borrowed, held, host_jit
from mwbx.scene import ANG_ACC, ANG_VEL, COM_POS, LIN_ACC, LIN_VEL, QUAT, SENSOR_WIDTH

_MASK32 = np.uint64(0xFFFFFFFF)


def host_params(params: world.WorldParams) -> world.WorldParams:
  """``params`` with host values numba can read: float64 / bool numpy arrays,
  Python scalars of fixed types (one compiled loop whatever the config wrote)."""
  f64 = lambda x: np.ascontiguousarray(np.asarray(x, np.float64))
  return params._replace(
      gravity=f64(params.gravity), mass=f64(params.mass), inertia=f64(params.inertia),
      perturbable=np.ascontiguousarray(np.asarray(params.perturbable, np.bool_)),
      flex_weight=f64(params.flex_weight).reshape(-1, len(params.mass)),
      flex_perturbable=np.ascontiguousarray(np.asarray(params.flex_perturbable, np.bool_)),
      perturb=params.perturb._make(float(x) for x in params.perturb),
      enabled=bool(params.enabled), dt=float(params.dt),
      rest_linear_speed=float(params.rest_linear_speed), rest_angular_speed=float(params.rest_angular_speed),
      rest_steps=int(params.rest_steps), max_speed=float(params.max_speed),
      collision_gap_steps=int(params.collision_gap_steps), steps_per_frame=int(params.steps_per_frame),
      end_frame=int(params.end_frame))


def init_carry(n_bodies: int, active: np.ndarray) -> world.WorldCarry:
  """:func:`world.init_carry` for C worlds as writable host arrays (float64 accumulators)."""
  c = len(active)
  metrics = np.zeros((c, n_bodies, len(world.METRIC_NAMES)))
  metrics[:, :, 5] = -np.inf
  return world.WorldCarry(
      step=np.zeros(c, np.int64),
      status=np.where(np.asarray(active), world.RUNNING, world.END_TIME).astype(np.int64),
      frame_count=np.zeros(c, np.int64),
      still_steps=np.zeros(c, np.int64),
      since_impact=np.full((c, n_bodies), 1 << 30, np.int64),
      perturbations=np.zeros(c, np.int64),
      metrics=metrics,
      prev_com=np.zeros((c, n_bodies, 3)),
      init_quat=np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (c, n_bodies, 1)),
  )


class ChunkBuffers(NamedTuple):
  """Host arrays of a chunk of C worlds; row i belongs to world i and is
  written only by the thread running it.

  Attributes:
    params: :func:`host_params` of the scene's
      :class:`world.WorldParams` (f64 arrays, Python scalars).
    key_data: u32[C, 2] per-world step key roots (``jax.random.key_data``).
    tracked_ids: i64[B] MuJoCo body id of each tracked body.
    states: f64[C, nstate] full physics state after each world's last frame.
    warmstart: f64[C, nv] accelerations of each world's last step (m/s², rad/s²).
    sensordata: f32[C, S, nsensordata] sensor blocks of the last frame's steps
      (:data:`mwbx.scene.SENSORS` units; NaN where MuJoCo reset the world).
    wrench_full: f64[C, S, nbody, 6] ``xfrc_applied`` of each world's next
      frame: force N, torque N·m.
    qpos_buf: f32[C, T, nq] recorded ``qpos`` of each frame.
    com_buf: f32[C, T, B, 3] recorded COM of each tracked body, m.
    carry: :class:`world.WorldCarry` of host arrays
      (:func:`init_carry`), updated.
  """

  params: world.WorldParams
  key_data: np.ndarray
  tracked_ids: np.ndarray
  states: np.ndarray
  warmstart: np.ndarray
  sensordata: np.ndarray
  wrench_full: np.ndarray
  qpos_buf: np.ndarray
  com_buf: np.ndarray
  carry: world.WorldCarry


# --- jax.random, bit for bit -------------------------------------------------

@host_jit
def _rotl32(x, r):
  return ((x << np.uint64(r)) | (x >> np.uint64(32 - r))) & _MASK32


@host_jit
def threefry2x32(key0, key1, x0, x1):
  """The Threefry-2x32 block (20 rounds) of ``jax.random``, on uint32 values held in uint64."""
  k0 = np.uint64(key0)
  k1 = np.uint64(key1)
  k2 = k0 ^ k1 ^ np.uint64(0x1BD11BDA)
  ks = (k0, k1, k2)
  a = (np.uint64(x0) + k0) & _MASK32
  b = (np.uint64(x1) + k1) & _MASK32
  for block in range(5):
    for i in range(4):
      r = (13, 15, 26, 6)[i] if block % 2 == 0 else (17, 29, 16, 24)[i]
      a = (a + b) & _MASK32
      b = _rotl32(b, r) ^ a
    a = (a + ks[(block + 1) % 3]) & _MASK32
    b = (b + ks[(block + 2) % 3] + np.uint64(block + 1)) & _MASK32
  return a, b


@host_jit
def fold_in(key0, key1, data):
  """``jax.random.fold_in`` of a threefry key (two uint32 words) with a uint32."""
  return threefry2x32(key0, key1, np.uint64(0), np.uint64(data) & _MASK32)


@host_jit
def body_step_uniforms(key0, key1, step, body, out):
  """``mwbx.perturb.sparse.body_step_uniforms``: six float32 uniforms into ``out``."""
  k0, k1 = fold_in(key0, key1, step)
  k0, k1 = fold_in(k0, k1, body)
  for i in range(out.size):
    a, b = threefry2x32(k0, k1, np.uint64(0), np.uint64(i))
    out[i] = ((a ^ b) >> np.uint64(9)) * (1.0 / 8388608.0)  # mantissa bits / 2^23, exact


# --- one body at one step ----------------------------------------------------

@host_jit
def _norm3(x, y, z):
  return math.sqrt(x * x + y * y + z * z)


@host_jit
def _perturbation(u0, u1, u2, dx, dy, dz, alpha, exponent, out):
  """``perturb.perturbation_from_uniforms`` about ``(dx, dy, dz)`` into ``out`` (f64[3]).

  Scalar arithmetic only: this runs at every impact, and array temporaries
  would each be a heap allocation.
  """
  norm = _norm3(dx, dy, dz)
  ax, ay, az = 1.0, 0.0, 0.0
  if norm > 0:
    ax, ay, az = dx / norm, dy / norm, dz / norm
  cos_theta = u0 ** (1.0 / (exponent + 1.0))
  sin_theta = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
  phi = 2.0 * math.pi * u1
  # orthonormal_basis: cross with the world axis least aligned with the axis
  # (the first of equals, as argmin picks it).
  abs_x, abs_y, abs_z = abs(ax), abs(ay), abs(az)
  if abs_x <= abs_y and abs_x <= abs_z:
    e1x, e1y, e1z = 0.0, az, -ay  # axis x (1, 0, 0)
  elif abs_y <= abs_z:
    e1x, e1y, e1z = -az, 0.0, ax  # axis x (0, 1, 0)
  else:
    e1x, e1y, e1z = ay, -ax, 0.0  # axis x (0, 0, 1)
  n1 = _norm3(e1x, e1y, e1z)
  e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
  e2x, e2y, e2z = ay * e1z - az * e1y, az * e1x - ax * e1z, ax * e1y - ay * e1x
  c, s = math.cos(phi), math.sin(phi)
  px = cos_theta * ax + sin_theta * (c * e1x + s * e2x)
  py = cos_theta * ay + sin_theta * (c * e1y + s * e2y)
  pz = cos_theta * az + sin_theta * (c * e1z + s * e2z)
  scale = (2.0 * u2 - 1.0) * alpha * norm / _norm3(px, py, pz)
  out[0] = scale * px
  out[1] = scale * py
  out[2] = scale * pz


@host_jit
def _impulse_wrench(dv, dw, mass, inertia, quat, dt, out):
  """``perturb.impulse_wrench`` into ``out`` (f64[6]): force, torque in the world frame."""
  norm = math.sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3])
  w, x, y, z = quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm
  r00, r01, r02, r10, r11, r12, r20, r21, r22 = host_loops.rotation_matrix(w, x, y, z)
  # I_world · dw = R · diag(inertia) · Rᵀ · dw
  bx = (r00 * dw[0] + r10 * dw[1] + r20 * dw[2]) * inertia[0]
  by = (r01 * dw[0] + r11 * dw[1] + r21 * dw[2]) * inertia[1]
  bz = (r02 * dw[0] + r12 * dw[1] + r22 * dw[2]) * inertia[2]
  for i in range(3):
    out[i] = mass * dv[i] / dt
  out[3] = (r00 * bx + r01 * by + r02 * bz) / dt
  out[4] = (r10 * bx + r11 * by + r12 * bz) / dt
  out[5] = (r20 * bx + r21 * by + r22 * bz) / dt


@host_jit
def _finite_step(sensors, n_bodies):
  """``world._finite`` of one step: COM, orientation and velocities of every body finite."""
  for b in range(n_bodies):
    for i in range(13):
      if not np.isfinite(sensors[b * SENSOR_WIDTH + i]):
        return False
  return True


# --- one frame of a batch ----------------------------------------------------

class FrameImpacts(NamedTuple):
  """One world's contact velocity changes over a frame's S steps (scratch,
  rewritten for each world).

  Attributes:
    delta_v: f64[S, B, 3] linear, m/s.
    delta_w: f64[S, B, 3] angular, rad/s.
    impact_v, impact_w: bool[S, B] over the perturbation thresholds.
  """

  delta_v: np.ndarray
  delta_w: np.ndarray
  impact_v: np.ndarray
  impact_w: np.ndarray


class WrenchScratch(NamedTuple):
  """Per-impact scratch of :func:`_next_wrenches`: uniforms f64[6], the drawn
  dv f64[3] and dw f64[3], a quaternion f64[4], a wrench f64[6], a flex's
  velocity change f64[3]."""

  u: np.ndarray
  dv: np.ndarray
  dw: np.ndarray
  quat: np.ndarray
  wrench: np.ndarray
  flex_delta: np.ndarray


@host_jit
def _contact_impacts(obs, n_bodies, p, impacts):
  """The velocity changes contacts made in each step of one world's frame, and
  which are impacts (over the perturbation thresholds).

  Args:
    obs: f32[S, B * SENSOR_WIDTH] the world's sensors of the frame's steps.
    n_bodies: B tracked bodies.
    p: :func:`host_params`.
    impacts: :class:`FrameImpacts` out.
  """
  dt = p.dt
  delta_v, delta_w = impacts.delta_v, impacts.delta_w
  for j in range(obs.shape[0]):
    for b in range(n_bodies):
      o = b * SENSOR_WIDTH
      for a in range(3):
        # The sensor reads a - gravity: the velocity change contacts made.
        delta_v[j, b, a] = dt * obs[j, o + LIN_ACC + a]
        delta_w[j, b, a] = dt * obs[j, o + ANG_ACC + a]
      impacts.impact_v[j, b] = (_norm3(delta_v[j, b, 0], delta_v[j, b, 1], delta_v[j, b, 2])
                                > p.perturb.linear_threshold * dt)
      impacts.impact_w[j, b] = (_norm3(delta_w[j, b, 0], delta_w[j, b, 1], delta_w[j, b, 2])
                                > p.perturb.angular_threshold * dt)


@host_jit
def _step_bookkeeping(obs, r, k0, was_running, n_bodies, p, carry, impacts):
  """Health, rest and metrics of world ``r`` through the frame's steps.

  Updates ``carry``'s metrics, initial orientations, steps since an impact and
  previous COM of row ``r`` for every step that is part of the world.

  Returns:
    (healthy: every step finite and under ``max_speed``, still: steps in a
    row with every body below the rest speeds, counted on from the carry).
  """
  dt = p.dt
  healthy = True
  still = carry.still_steps[r]
  for j in range(obs.shape[0]):
    k = k0 + j
    healthy = healthy and _finite_step(obs[j], n_bodies)
    for b in range(n_bodies):
      o = b * SENSOR_WIDTH
      if _norm3(obs[j, o + LIN_VEL], obs[j, o + LIN_VEL + 1], obs[j, o + LIN_VEL + 2]) > p.max_speed:
        healthy = False
    # The last frame is recorded at its first step; later steps of it are
    # not part of the world (its simulation ends there).
    keep = healthy and was_running and (k0 // p.steps_per_frame < p.end_frame or j == 0)
    any_moving = False
    for b in range(n_bodies):
      o = b * SENSOR_WIDTH
      speed = _norm3(obs[j, o + LIN_VEL], obs[j, o + LIN_VEL + 1], obs[j, o + LIN_VEL + 2])
      spin = _norm3(obs[j, o + ANG_VEL], obs[j, o + ANG_VEL + 1], obs[j, o + ANG_VEL + 2])
      moving = speed >= p.rest_linear_speed or spin >= p.rest_angular_speed
      any_moving = any_moving or moving
      if k == 0:
        for a in range(4):
          carry.init_quat[r, b, a] = obs[j, o + QUAT + a]
      if not keep:
        continue
      m = carry.metrics[r, b]
      impact = impacts.impact_v[j, b] or impacts.impact_w[j, b]
      m[ANGULAR_TRAVEL] += spin * dt
      if moving:
        # k·dt rounded as float32 arithmetic rounds it (the product of two
        # float32 values is exact in float64): rest times are the same
        # discrete values on every backend.
        m[REST_TIME] = np.float32(float(np.float32(k)) * float(np.float32(dt)))
      if impact and carry.since_impact[r, b] > p.collision_gap_steps:
        m[COLLISIONS] += 1.0
      dot = 0.0
      for a in range(4):
        dot += carry.init_quat[r, b, a] * obs[j, o + QUAT + a]
      m[ORIENTATION_ERROR] = 2.0 * math.acos(min(abs(dot), 1.0))
      if k > 0:
        m[PATH_LENGTH] += _norm3(obs[j, o + COM_POS] - carry.prev_com[r, b, 0],
                                 obs[j, o + COM_POS + 1] - carry.prev_com[r, b, 1],
                                 obs[j, o + COM_POS + 2] - carry.prev_com[r, b, 2])
      m[MAX_HEIGHT] = max(m[MAX_HEIGHT], obs[j, o + COM_POS + 2])
      carry.since_impact[r, b] = 0 if impact else carry.since_impact[r, b] + 1
      for a in range(3):
        carry.prev_com[r, b, a] = obs[j, o + COM_POS + a]
    still = 0 if any_moving else still + 1
  return healthy, still


@host_jit
def _frame_status(status, was_running, healthy, still, k0, p):
  """A world's status after the frame it started at step ``k0`` (a world that
  was not running keeps ``status``)."""
  if not was_running:
    return status
  if not healthy:
    return world.UNSTABLE
  if still >= p.rest_steps:
    return world.AT_REST
  if k0 // p.steps_per_frame >= p.end_frame:
    return world.END_TIME
  return world.RUNNING


@host_jit
def flex_velocity_change(delta_v, weight, out):
  """``world.flex_velocity_change`` of one flex at one step: the mass-weighted
  mean (``weight`` f64[B]) of the bodies' ``delta_v`` (f64[B, 3]) into ``out``."""
  out[:] = 0.0
  for b in range(weight.size):
    if weight[b] != 0.0:
      for a in range(3):
        out[a] += weight[b] * delta_v[b, a]


@host_jit
def _next_wrenches(r, obs, k0, keep_going, key_data, p, tracked, impacts, wrench_full, scratch):
  """The perturbation impulses of world ``r``'s impacts, as ``xfrc_applied``
  wrenches of its next frame's steps (zero where none): each perturbable
  body's, then each flex's as a whole where one of its bodies was struck
  (``world.frame_update``).

  Returns the number of nonzero perturbations applied.
  """
  u, dv, dw, quat, wrench = scratch.u, scratch.dv, scratch.dw, scratch.quat, scratch.wrench
  delta_v, delta_w = impacts.delta_v, impacts.delta_w
  n_bodies = tracked.size
  perturbing = keep_going and p.enabled
  n_applied = 0
  for j in range(obs.shape[0]):
    for b in range(n_bodies):
      for a in range(6):
        wrench_full[r, j, tracked[b], a] = 0.0
      if not (perturbing and p.perturbable[b] and (impacts.impact_v[j, b] or impacts.impact_w[j, b])):
        continue
      body_step_uniforms(key_data[r, 0], key_data[r, 1], k0 + j, b, u)
      dv[:] = 0.0
      dw[:] = 0.0
      if impacts.impact_v[j, b]:
        _perturbation(u[0], u[1], u[2], delta_v[j, b, 0], delta_v[j, b, 1], delta_v[j, b, 2],
                      p.perturb.alpha, p.perturb.lobe_exponent, dv)
      if impacts.impact_w[j, b]:
        _perturbation(u[3], u[4], u[5], delta_w[j, b, 0], delta_w[j, b, 1], delta_w[j, b, 2],
                      p.perturb.alpha, p.perturb.lobe_exponent, dw)
      if (dv[0] != 0.0 or dv[1] != 0.0 or dv[2] != 0.0 or dw[0] != 0.0 or dw[1] != 0.0
          or dw[2] != 0.0):
        n_applied += 1
      for a in range(4):
        quat[a] = obs[j, b * SENSOR_WIDTH + 3 + a]
      _impulse_wrench(dv, dw, p.mass[b], p.inertia[b], quat, p.dt, wrench)
      for a in range(6):
        wrench_full[r, j, tracked[b], a] = wrench[a]
    for f in range(p.flex_perturbable.size):
      if not (perturbing and p.flex_perturbable[f]):
        continue
      struck = False  # any of its bodies over the linear threshold
      for b in range(n_bodies):
        struck = struck or (p.flex_weight[f, b] != 0.0 and impacts.impact_v[j, b])
      if not struck:
        continue
      delta = scratch.flex_delta
      flex_velocity_change(delta_v[j], p.flex_weight[f], delta)
      body_step_uniforms(key_data[r, 0], key_data[r, 1], k0 + j, n_bodies + f, u)
      _perturbation(u[0], u[1], u[2], delta[0], delta[1], delta[2], p.perturb.alpha, p.perturb.lobe_exponent,
                    dv)
      if dv[0] != 0.0 or dv[1] != 0.0 or dv[2] != 0.0:
        n_applied += 1
      # The same velocity change for every body of the flex: m_b · dv / dt each.
      for b in range(n_bodies):
        if p.flex_weight[f, b] != 0.0:
          for a in range(3):
            wrench_full[r, j, tracked[b], a] += p.mass[b] * dv[a] / p.dt
  return n_applied


@host_jit
def frame_update(rows, buffers, before, qpos_start, frame, running):
  """:func:`world.frame_update` for the worlds that ran a frame, and the recording.

  Per world: the frame's contact impacts, its steps' health, rest and
  metrics, its status, the next frame's perturbation wrenches, and the
  frame's ``qpos`` and COM recorded (from the state the frame started at).

  Args:
    rows: i64[n] chunk row of each world that stepped the frame.
    buffers: :class:`ChunkBuffers` of the chunk: reads ``sensordata`` (the
      frame's steps, NaN where MuJoCo reset the world), ``key_data``,
      ``params`` and ``tracked_ids``; updates ``carry``; writes ``qpos_buf``
      and ``com_buf`` at ``frame`` and ``wrench_full`` (the next frame's
      ``xfrc_applied``).
    before: f64[n, nstate] state s_k each world started the frame from.
    qpos_start: index of qpos in a state.
    frame: frame index to record into.
    running: bool[C] out: whether each stepped world needs the next frame.
  """
  rows, buffers, before, running = borrowed((rows, buffers, before, running))  # the caller holds them
  sensordata, key_data, p, carry = buffers.sensordata, buffers.key_data, buffers.params, buffers.carry
  tracked, qpos_buf, com_buf, wrench_full = buffers.tracked_ids, buffers.qpos_buf, buffers.com_buf, buffers.wrench_full
  n_steps = sensordata.shape[1]
  n_bodies = tracked.size
  nq = qpos_buf.shape[2]
  owned = (FrameImpacts(np.empty((n_steps, n_bodies, 3)), np.empty((n_steps, n_bodies, 3)),
                       np.empty((n_steps, n_bodies), np.bool_), np.empty((n_steps, n_bodies), np.bool_)),
           WrenchScratch(np.empty(6), np.empty(3), np.empty(3), np.empty(4), np.empty(6), np.empty(3)))
  impacts, scratch = borrowed(owned)  # handed to a helper per world: no reference counting (held to the end)
  for i in range(rows.size):
    r = rows[i]
    obs = sensordata[r]
    k0 = carry.step[r]
    was_running = carry.status[r] == world.RUNNING
    record = was_running and _finite_step(obs[0], n_bodies)
    _contact_impacts(obs, n_bodies, p, impacts)
    healthy, still = _step_bookkeeping(obs, r, k0, was_running, n_bodies, p, carry, impacts)
    status = _frame_status(carry.status[r], was_running, healthy, still, k0, p)
    keep_going = was_running and status == world.RUNNING
    n_applied = _next_wrenches(r, obs, k0, keep_going, key_data, p, tracked, impacts, wrench_full, scratch)
    if was_running:
      carry.step[r] = k0 + n_steps
      carry.still_steps[r] = still
    carry.status[r] = status
    carry.perturbations[r] += n_applied
    if record:
      carry.frame_count[r] += 1
      for a in range(nq):
        qpos_buf[r, frame, a] = np.float32(before[i, qpos_start + a])
      for b in range(n_bodies):
        for a in range(3):
          com_buf[r, frame, b, a] = obs[0, b * SENSOR_WIDTH + a]
    running[r] = keep_going
  held(owned)
