"""The bookkeeping of ONE world: perturbations, metrics, rest and
instability detection, and when to record a frame.

Physics runs in frames of S = steps_per_frame steps. Both backends step a
whole frame, then call :func:`post_frame` with the S observations of the
tracked bodies; it is written for one world and vmapped over the batch. It
never touches MuJoCo types.

Step k takes state s_k to s_{k+1}. Its observation describes s_k (positions,
orientations, velocities) and the accelerations that turned s_k into s_{k+1},
so impacts are detected on the very step they happen. The perturbation drawn
for an impact at step k is applied as a wrench during step k + S, one frame
later (8 ms at 120 fps, far below what a viewer notices): that lets a frame's
physics steps run with no bookkeeping between them (one ``mujoco.rollout``
call, or one stretch of ``mj_step`` calls), and both backends share the same
semantics.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mwbx import perturb, rotations
from mwbx.scene import SENSOR_OFFSET, SENSOR_WIDTH, SENSORS

METRIC_NAMES = (
    "angular_travel",     # rad: integral of angular speed
    "rest_time",          # s: last time the body moved faster than the rest speeds
    "collisions",         # count: impacts (rising edges of the perturbation threshold)
    "orientation_error",  # rad: angle between final and initial orientation
    "path_length",        # m: length travelled by the COM
    "max_height",         # m: highest COM z
)
# Column of each metric in the metric table (METRIC_NAMES order); the numba
# twin and refinement's prefix metrics index with these.
ANGULAR_TRAVEL, REST_TIME, COLLISIONS, ORIENTATION_ERROR, PATH_LENGTH, MAX_HEIGHT = (
    METRIC_NAMES.index(name) for name in (
        "angular_travel", "rest_time", "collisions", "orientation_error", "path_length",
        "max_height"))

# Status codes: errors as data, never exceptions inside the loop.
RUNNING = 0
AT_REST = 1
END_TIME = 2
UNSTABLE = 3
# MuJoCo raised mju_error (e.g. its stack overflowed) while stepping the world:
# set by the native backend, which stops that world and goes on with the others.
SIM_ERROR = 4


class Observation(NamedTuple):
  """What the backend reports of ONE world's tracked bodies at one step.

  Attributes:
    com_pos: f32[B, 3] centre of mass, m, world frame.
    quat: f32[B, 4] inertial-frame orientation (w, x, y, z).
    lin_vel: f32[B, 3] COM velocity, m/s.
    ang_vel: f32[B, 3] angular velocity, rad/s, world frame.
    lin_acc: f32[B, 3] COM acceleration over the step, m/s² (free fall: gravity).
    ang_acc: f32[B, 3] angular acceleration over the step, rad/s².
  """

  com_pos: jax.Array
  quat: jax.Array
  lin_vel: jax.Array
  ang_vel: jax.Array
  lin_acc: jax.Array
  ang_acc: jax.Array

  @classmethod
  def from_sensordata(cls, sensordata: jax.Array, gravity: jax.Array) -> "Observation":
    """Splits ``f32[B * SENSOR_WIDTH]`` sensor data (mwbx.scene.SENSORS order).

    MuJoCo's linear acceleration sensor reports the proper acceleration
    ``a - gravity`` (free fall reads zero, like an accelerometer); ``lin_acc``
    is ``a``.
    """
    s = sensordata.reshape(-1, SENSOR_WIDTH).astype(jnp.float32)
    part = {name: s[:, SENSOR_OFFSET[name]:SENSOR_OFFSET[name] + width] for name, _, width in SENSORS}
    return cls(part["com_pos"], part["quat"], part["lin_vel"], part["ang_vel"],
               part["lin_acc"] + gravity, part["ang_acc"])


class WorldParams(NamedTuple):
  """Static-shaped constants of a scene, shared by all worlds.

  Attributes:
    gravity: f32[3] m/s².
    mass: f32[B] kg.
    inertia: f32[B, 3] principal moments, kg·m².
    perturbable: bool[B].
    flex_weight: f32[F, B] each flex's mass fractions over the tracked
      bodies (F may be 0): a flex is perturbed as a whole (:func:`frame_update`).
    flex_perturbable: bool[F].
    perturb: thresholds, α, lobe exponent.
    enabled: perturbations on (False: plain simulation).
    rest_linear_speed, rest_angular_speed: m/s, rad/s.
    rest_steps: steps all bodies must stay below the rest speeds.
    max_speed: m/s; faster means unstable.
    collision_gap_steps: impacts closer than this many steps are one collision.
    steps_per_frame: physics steps per recorded frame.
    end_frame: last frame index (end time · record fps).
  """

  gravity: jax.Array
  mass: jax.Array
  inertia: jax.Array
  perturbable: jax.Array
  flex_weight: jax.Array
  flex_perturbable: jax.Array
  perturb: perturb.PerturbParams
  enabled: bool
  dt: float
  rest_linear_speed: float
  rest_angular_speed: float
  rest_steps: int
  max_speed: float
  collision_gap_steps: int
  steps_per_frame: int
  end_frame: int


class WorldCarry(NamedTuple):
  """Per-world state of the bookkeeping (leading axis W once vmapped).

  Attributes:
    step: i32 index k of the first physics step of the next frame.
    status: i32 RUNNING, AT_REST, END_TIME or UNSTABLE.
    frame_count: i32 frames recorded so far.
    still_steps: i32 consecutive steps with every body below the rest speeds.
    since_impact: i32[B] steps since the body's last impact.
    perturbations: i32 body perturbations applied.
    metrics: f32[B, M] accumulators in METRIC_NAMES order.
    prev_com: f32[B, 3] COM at the previous step.
    init_quat: f32[B, 4] orientation at step 0.
  """

  step: jax.Array
  status: jax.Array
  frame_count: jax.Array
  still_steps: jax.Array
  since_impact: jax.Array
  perturbations: jax.Array
  metrics: jax.Array
  prev_com: jax.Array
  init_quat: jax.Array


def init_carry(n_bodies: int, active: bool | jax.Array = True) -> WorldCarry:
  """Bookkeeping for a world about to take step 0 (``active=False``: a padding slot)."""
  b = n_bodies
  return WorldCarry(
      step=jnp.int32(0),
      status=jnp.where(active, RUNNING, END_TIME).astype(jnp.int32),
      frame_count=jnp.int32(0),
      still_steps=jnp.int32(0),
      since_impact=jnp.full(b, 1 << 30, jnp.int32),
      perturbations=jnp.int32(0),
      metrics=jnp.zeros((b, len(METRIC_NAMES)), jnp.float32).at[:, MAX_HEIGHT].set(-jnp.inf),
      prev_com=jnp.zeros((b, 3), jnp.float32),
      init_quat=jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0], jnp.float32), (b, 1)),
  )


class FrameOutput(NamedTuple):
  """Per world: the wrenches for the next frame and what to record now.

  Attributes:
    wrench: f32[S, B, 6] force and torque at each tracked COM for each step
      of the next frame.
    record: bool, store the frame's first state s_k (frame k / S) now.
    running: bool, the world needs the next frame.
    dv: f32[S, B + F, 3] linear velocity perturbations applied next frame
      (bodies, then flexes), m/s.
    dw: f32[S, B + F, 3] angular velocity perturbations alike, rad/s.
    linear_impact: bool[S, B] steps whose ‖Δv‖/dt exceeded C_v.
    angular_impact: bool[S, B] steps whose ‖Δω‖/dt exceeded C_ω.
  """

  wrench: jax.Array
  record: jax.Array
  running: jax.Array
  dv: jax.Array
  dw: jax.Array
  linear_impact: jax.Array
  angular_impact: jax.Array


def frame_impacts(obs: Observation, params: WorldParams):
  """Contact-induced velocity changes and impact flags of ONE world's frame.

  Args:
    obs: observations with leading axis S.

  Returns:
    (delta_v f32[S, B, 3], delta_w f32[S, B, 3], linear_impact bool[S, B],
     angular_impact bool[S, B]).
  """
  delta_v, delta_w = perturb.velocity_change(obs.lin_acc, obs.ang_acc, params.gravity, params.dt)
  linear_impact = jnp.linalg.norm(delta_v, axis=-1) > params.perturb.linear_threshold * params.dt
  angular_impact = jnp.linalg.norm(delta_w, axis=-1) > params.perturb.angular_threshold * params.dt
  return delta_v, delta_w, linear_impact, angular_impact


def post_frame(carry: WorldCarry, obs: Observation, impacts, dv: jax.Array, dw: jax.Array,
               wrench: jax.Array, params: WorldParams):
  """Bookkeeping of ONE world after the S physics steps of one frame.

  Args:
    carry: the world's bookkeeping before the frame.
    obs: observations of the frame's steps, leading axis S (see module doc).
    impacts: (linear bool[S, B], angular bool[S, B]) from :func:`frame_impacts`.
    dv: f32[S, B + F, 3] sampled linear perturbations (bodies, then flexes), m/s.
    dw: f32[S, B + F, 3] sampled angular perturbations, rad/s.
    wrench: f32[S, B, 6] the wrenches applying them (perturb.impulse_wrench;
      a flex's spread over its bodies).
    params: scene constants.

  Returns:
    (new carry, :class:`FrameOutput`).
  """
  k0 = carry.step
  running = carry.status == RUNNING
  dt = params.dt
  gap_steps = params.collision_gap_steps
  first_finite = _finite(jax.tree.map(lambda x: x[0], obs))
  record = running & first_finite
  linear_impact, angular_impact = impacts

  def one_step(state, inputs):
    still_steps, since_impact, metrics, prev_com, init_quat, healthy = state
    j, o, impact = inputs
    k = k0 + j
    finite = _finite(o)
    speed = jnp.linalg.norm(o.lin_vel, axis=-1)
    spin = jnp.linalg.norm(o.ang_vel, axis=-1)
    healthy = healthy & finite & ~jnp.any(speed > params.max_speed)
    moving = (speed >= params.rest_linear_speed) | (spin >= params.rest_angular_speed)
    com = jnp.where(healthy, o.com_pos, prev_com)
    init_quat = jnp.where(k == 0, o.quat, init_quat)
    new_metrics = jnp.stack([
        metrics[:, 0] + spin * dt,
        jnp.where(moving, k * dt, metrics[:, 1]),
        metrics[:, 2] + (impact & (since_impact > gap_steps)),
        rotations.rotation_angle(init_quat, o.quat),
        metrics[:, 4] + jnp.where(k > 0, jnp.linalg.norm(com - prev_com, axis=-1), 0.0),
        jnp.maximum(metrics[:, 5], com[:, 2]),
    ], axis=-1)
    # The last frame is recorded at its first step; later steps of it are not
    # part of the world (its simulation ends there).
    keep = healthy & running & ((k0 // params.steps_per_frame < params.end_frame) | (j == 0))
    state = (
        jnp.where(jnp.any(moving), 0, still_steps + 1),
        jnp.where(keep, jnp.where(impact, 0, since_impact + 1), since_impact),
        jnp.where(keep, new_metrics, metrics),
        jnp.where(keep, com, prev_com),
        init_quat,
        healthy,
    )
    return state, None

  n_steps = obs.com_pos.shape[0]
  state0 = (carry.still_steps, carry.since_impact, carry.metrics, carry.prev_com, carry.init_quat,
            jnp.bool_(True))
  state, _ = jax.lax.scan(
      one_step, state0, (jnp.arange(n_steps), obs, linear_impact | angular_impact), unroll=True)
  still_steps, since_impact, metrics, prev_com, init_quat, healthy = state

  frame = k0 // params.steps_per_frame
  at_rest = still_steps >= params.rest_steps
  status = jnp.where(~healthy, UNSTABLE, jnp.where(
      at_rest, AT_REST, jnp.where(frame >= params.end_frame, END_TIME, RUNNING)))
  status = jnp.where(running, status, carry.status)
  keep_going = running & (status == RUNNING)

  apply = keep_going & params.enabled
  dv = jnp.where(apply, dv, 0.0)
  dw = jnp.where(apply, dw, 0.0)
  wrench = jnp.where(apply, wrench, 0.0)
  n_applied = jnp.sum((jnp.any(dv != 0, -1) | jnp.any(dw != 0, -1)).astype(jnp.int32))

  new_carry = WorldCarry(
      step=jnp.where(running, k0 + n_steps, k0),
      status=status,
      frame_count=carry.frame_count + record,
      still_steps=jnp.where(running, still_steps, carry.still_steps),
      since_impact=since_impact,
      perturbations=carry.perturbations + n_applied,
      metrics=metrics,
      prev_com=prev_com,
      init_quat=init_quat,
  )
  return new_carry, FrameOutput(wrench=wrench, record=record, running=keep_going, dv=dv, dw=dw,
                                linear_impact=linear_impact, angular_impact=angular_impact)


def flex_velocity_change(delta_v: jax.Array, params: WorldParams) -> jax.Array:
  """f32[..., F, 3] each flex's contact-induced velocity change, m/s: the
  mass-weighted mean of its bodies' ``delta_v`` (f32[..., B, 3]).

  This is the velocity change of the flex's centre of mass: forces between its
  own vertices (edges, elasticity, self contacts) cancel in the sum, so only
  what the rest of the scene does to the flex remains.
  """
  return jnp.einsum("fb,...bc->...fc", params.flex_weight, delta_v)


def perturbation_bounds(delta_v: jax.Array, delta_w: jax.Array, params: WorldParams):
  """The velocity changes that bound each perturbation, bodies then flexes:
  (f32[..., B + F, 3], f32[..., B + F, 3]); a flex has no angular part."""
  if not params.flex_weight.shape[0]:
    return delta_v, delta_w
  flex_dv = flex_velocity_change(delta_v, params)
  return (jnp.concatenate([delta_v, flex_dv], axis=-2),
          jnp.concatenate([delta_w, jnp.zeros_like(flex_dv)], axis=-2))


def flex_mask(body_mask: jax.Array, params: WorldParams) -> jax.Array:
  """bool[W, F] flexes with a body in ``body_mask`` (bool[W, B])."""
  members = (params.flex_weight > 0).astype(jnp.float32)
  return (body_mask.astype(jnp.float32) @ members.T) > 0.5


def frame_update(carry: WorldCarry, obs: Observation, world_keys: jax.Array, params: WorldParams,
                 perturbable: jax.Array | None = None):
  """:func:`post_frame` for a batch, with perturbations drawn only at impacts.

  A flex is perturbed as a whole: at a step where any of its bodies has a
  linear impact (the flex struck something), one perturbation is drawn about
  the flex's velocity change (:func:`flex_velocity_change`) exactly as for a
  body (its randomness that of "body" B + f, bounded by α times that change),
  and every body of the flex gets that same velocity change.

  Args:
    carry: bookkeeping of W worlds (leading axis W).
    obs: observations, leading axes [W, S].
    world_keys: key[W] step key roots.
    params: scene constants.
    perturbable: optional bool[W, B] per-world mask ANDed with
      ``params.perturbable`` (refinement: only active objects are perturbed).

  Returns:
    (new carry, :class:`FrameOutput` with leading axis W; its ``dv`` and
    ``dw`` over bodies then flexes, f32[W, S, B + F, 3]).
  """
  delta_v, delta_w, linear_impact, angular_impact = jax.vmap(frame_impacts, in_axes=(0, None))(obs, params)
  running = (carry.status == RUNNING)[:, None, None]
  wanted = (params.perturbable & params.enabled) & running
  if perturbable is not None:
    wanted = wanted & perturbable[:, None, :]
  n_worlds, n_steps, n_bodies = linear_impact.shape
  n_flex = params.flex_weight.shape[0]
  mass, inertia, quat = params.mass, params.inertia, obs.quat
  bound_v, bound_w = perturbation_bounds(delta_v, delta_w, params)
  linear_wanted, angular_wanted = linear_impact & wanted, angular_impact & wanted
  if n_flex:
    flex_wanted = (params.flex_perturbable & params.enabled) & running
    if perturbable is not None:
      flex_wanted = flex_wanted & flex_mask(perturbable, params)[:, None, :]
    flex_impact = flex_mask(linear_impact.reshape(-1, n_bodies), params).reshape(n_worlds, n_steps, n_flex)
    linear_wanted = jnp.concatenate([linear_wanted, flex_impact & flex_wanted], axis=-1)
    angular_wanted = jnp.concatenate([angular_wanted, jnp.zeros_like(flex_impact)], axis=-1)
    # A flex's wrench is computed per unit mass, then given to each body by its mass.
    mass = jnp.concatenate([mass, jnp.ones(n_flex, mass.dtype)])
    inertia = jnp.concatenate([inertia, jnp.ones((n_flex, 3), inertia.dtype)])
    identity = jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0, 0.0], quat.dtype), (n_worlds, n_steps, n_flex, 4))
    quat = jnp.concatenate([quat, identity], axis=-2)
  n_perturbed = n_bodies + n_flex
  dv, dw, wrench = perturb.batch_perturbations(
      world_keys, carry.step, bound_v, bound_w, linear_wanted, angular_wanted,
      params.perturb, cap=max(64, n_worlds * n_steps * n_perturbed // 16),
      inertial=(mass, inertia, quat, params.dt))
  if n_flex:
    member_mass = (params.flex_weight > 0) * params.mass[None, :]  # [F, B]
    spread = jnp.einsum("fb,wsfc->wsbc", member_mass, wrench[:, :, n_bodies:, :3])
    wrench = wrench[:, :, :n_bodies].at[..., :3].add(spread)
  return jax.vmap(post_frame, in_axes=(0, 0, 0, 0, 0, 0, None))(
      carry, obs, (linear_impact, angular_impact), dv, dw, wrench, params)


def _finite(o: Observation) -> jax.Array:
  return (jnp.all(jnp.isfinite(o.com_pos)) & jnp.all(jnp.isfinite(o.lin_vel))
          & jnp.all(jnp.isfinite(o.ang_vel)) & jnp.all(jnp.isfinite(o.quat)))


def world_params(scene, steps_per_frame: int, end_frame: int) -> WorldParams:
  """Scene constants for :func:`post_frame` from a :class:`mwbx.scene.Scene`."""
  cfg = scene.config
  m = scene.model
  return WorldParams(
      gravity=jnp.asarray(m.opt.gravity, jnp.float32),
      mass=jnp.asarray(m.body_mass[scene.body_ids], jnp.float32),
      inertia=jnp.asarray(m.body_inertia[scene.body_ids], jnp.float32),
      perturbable=jnp.asarray(scene.perturbable),
      flex_weight=jnp.asarray(scene.flex_weight, jnp.float32),
      flex_perturbable=jnp.asarray(scene.flex_perturbable),
      perturb=perturb.PerturbParams(
          alpha=cfg.perturb.alpha, lobe_exponent=cfg.perturb.lobe_exponent,
          linear_threshold=cfg.perturb.linear_threshold, angular_threshold=cfg.perturb.angular_threshold),
      enabled=cfg.perturb.enabled,
      dt=float(m.opt.timestep),
      rest_linear_speed=cfg.rest.linear_speed,
      rest_angular_speed=cfg.rest.angular_speed,
      rest_steps=max(1, int(round(cfg.rest.duration / m.opt.timestep))),
      max_speed=cfg.sim.max_speed,
      collision_gap_steps=int(round(cfg.perturb.collision_gap / m.opt.timestep)),
      steps_per_frame=steps_per_frame,
      end_frame=end_frame,
  )


def finalize_metrics(carry: WorldCarry) -> np.ndarray:
  """f32[W, B, M] metric table (max_height of a world that never ran: 0)."""
  metrics = np.array(carry.metrics)
  metrics[..., 5] = np.where(np.isfinite(metrics[..., 5]), metrics[..., 5], 0.0)
  return metrics
