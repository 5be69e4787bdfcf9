"""Greedy error-bounded segment fit (paper Fig. 4), as jitted JAX kernels.

Each kernel fits ONE path and is ``jax.vmap``-ped over many paths (all worlds x
channels of a kind) at the edge.

Model of a segment that starts at frame ``s`` with the *decoded* value ``p_s``
(the previous segment's quantized end, so errors never accumulate) and lasts
``L`` frames, at ``tau = 0..L`` frames into the segment:

- linear channels (free-joint translation, hinge/slide scalars):
  ``x(tau) = p_s + tau * v * step + flag * quad * tau**2`` on the vertical
  coordinate only; ``v`` is an integer vector (units ``step`` per frame), ``quad``
  one global constant (gravity * h**2 / 2), ``flag`` one bit per segment;
- rotations: ``q(tau) = exp(tau * w * step) (x) q_s`` with ``w`` an integer
  angular velocity in the log map (units ``step`` radians per frame).

Instead of least squares followed by quantization, the fit keeps, per
coordinate, the interval of velocities that keep every frame seen so far within
the bound (each frame adds one linear constraint on ``v``), and extends the
segment while that interval still holds an allowed velocity. This is the
greedy algorithm of Fig. 4 made exact for quantized coefficients, O(1) per
frame. Allowed velocities are ``pred + r * 2**m``: ``pred`` is the previous
segment's velocity (plus the gravity increment after a ballistic segment) and
the lattice spacing ``2**m`` shrinks as the segment grows, so a short segment
costs few bits (its velocity needs little precision) and a long one can still
be fitted finely; the stream stores the small integer ``r``.

For rotations the bound on the rotation angle is enforced through
``angle(exp(a), exp(b)) <= |a - b|`` (the exponential map of SO(3) does not
expand distances), with a box of half-width ``e_rot / sqrt(3)`` inside that ball.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

# Velocities are kept in int32; windows are clipped to this magnitude first.
_INT_CAP = 2.0**30


class LinearFit(NamedTuple):
  """Segments of linear-channel paths; entries are meaningful where ``ends``.

  ends: bool[N, T], frame f closes a segment.
  vel: i32[N, T, D], integer velocity of the segment closing at f.
  flag: bool[N, T], vertical quadratic term on for that segment.
  """

  ends: jax.Array
  vel: jax.Array
  flag: jax.Array


class RotationFit(NamedTuple):
  """Segments of rotation paths; ``ends: bool[N, T]``, ``vel: i32[N, T, 3]``."""

  ends: jax.Array
  vel: jax.Array


def quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
  """Hamilton product of (w, x, y, z) quaternions, f32[..., 4]."""
  aw, ax, ay, az = jnp.moveaxis(a, -1, 0)
  bw, bx, by, bz = jnp.moveaxis(b, -1, 0)
  return jnp.stack([
      aw * bw - ax * bx - ay * by - az * bz,
      aw * bx + ax * bw + ay * bz - az * by,
      aw * by - ax * bz + ay * bw + az * bx,
      aw * bz + ax * by - ay * bx + az * bw,
  ], axis=-1)


def quat_exp(omega: jax.Array) -> jax.Array:
  """Unit quaternion of rotation vector ``omega: f32[..., 3]`` (radians)."""
  theta = jnp.linalg.norm(omega, axis=-1, keepdims=True)
  safe = jnp.where(theta > 1e-12, theta, 1.0)
  factor = jnp.where(theta > 1e-12, jnp.sin(0.5 * theta) / safe, 0.5)
  return jnp.concatenate([jnp.cos(0.5 * theta), factor * omega], axis=-1)


def rel_log(q: jax.Array, q_start: jax.Array) -> jax.Array:
  """Rotation vector of ``q (x) q_start^-1``, angle in [0, pi]; f32[3]."""
  conj = q_start * jnp.array([1.0, -1.0, -1.0, -1.0], q_start.dtype)
  rel = quat_mul(q, conj)
  rel = jnp.where(rel[0] < 0, -rel, rel)  # q and -q are the same rotation
  s = jnp.linalg.norm(rel[1:])
  angle = 2.0 * jnp.arctan2(s, rel[0])
  factor = jnp.where(s > 1e-12, angle / jnp.where(s > 1e-12, s, 1.0),
                     2.0 / jnp.maximum(rel[0], 1e-12))
  return factor * rel[1:]


# Segments are cut at this length so integer products stay within int32.
MAX_SEGMENT = 4096

# Half-widths (per axis, in units of the ball radius) of the boxes that the
# rotation fit tracks side by side; every row has norm <= 1, so each box lies in
# the error ball. The cube first, then one long axis, then two.
ROTATION_BOXES = np.array([
    [0.577, 0.577, 0.577],
    [0.900, 0.305, 0.305],
    [0.305, 0.900, 0.305],
    [0.305, 0.305, 0.900],
    [0.680, 0.680, 0.270],
    [0.680, 0.270, 0.680],
    [0.270, 0.680, 0.680],
], np.float32)

# Rotation segments up to this many frames are also checked frame by frame
# against the ball itself (the log-map deviations of the segment are kept).
EXACT_SPAN = 32


def lattice_exponent(length, coarse):
  """Velocity lattice of a segment: spacing ``2**m`` fine steps, m = max(0, coarse -
  floor(log2 length)), so the displacement quantum over the segment stays about
  ``bound * 2**-lattice_shift`` whatever its length."""
  length = jnp.maximum(length, 1).astype(jnp.int32)
  return jnp.maximum(0, coarse - (31 - jax.lax.clz(length)))


def gravity_increment(flag, length, g_fp):
  """Vertical velocity gained over a ballistic segment, fine steps (integer)."""
  return jnp.where(flag, (length * g_fp + 128) >> 8, 0).astype(jnp.int32)


def _pick(lo, hi, pred, m):
  """The integer velocity ``pred + r * 2**m`` inside [lo, hi] with the smallest |r|.

  Returns (velocity i32, r i32, non-empty bool), per coordinate. The window is
  split into integer and fractional parts before ``pred`` is subtracted, so a
  large ``pred`` (after an impact) costs no float32 precision.
  """
  lo = jnp.clip(lo, -_INT_CAP, _INT_CAP)
  hi = jnp.clip(hi, -_INT_CAP, _INT_CAP)
  lo_floor, hi_floor = jnp.floor(lo), jnp.floor(hi)
  below = lo_floor.astype(jnp.int32) - pred
  above = hi_floor.astype(jnp.int32) - pred
  # ceil((below + frac) / 2**m) for frac in [0, 1), and floor((above + frac) / 2**m).
  r_lo = jnp.where(lo > lo_floor, (below >> m) + 1, -((-below) >> m))
  r_hi = above >> m
  r = jnp.clip(0, r_lo, r_hi)
  return pred + r * jnp.left_shift(jnp.int32(1), m), r, r_lo <= r_hi


def _fit_linear_path(x, n, e, step, quad, coarse, g_fp, gravity: bool) -> LinearFit:
  """Fit one linear-channel path.

  Args:
    x: f32[T, D] positions relative to x[0] (metres or joint units).
    n: i32, number of valid frames (frames >= n are padding).
    e: f32, bound used for the fit (same units as x).
    step: f32, finest velocity quantum (units of x per frame).
    quad: f32, vertical quadratic coefficient (units of x per frame**2).
    coarse: i32, lattice exponent of a 1-frame segment (see ``lattice_exponent``).
    g_fp: i32, gravity velocity increment per frame, fine steps * 256.
    gravity: static; if True the last coordinate may switch on ``quad``.
  """
  num_t, dim = x.shape
  # Windows: one per coordinate, plus the vertical one with the quadratic term on.
  dims = list(range(dim)) + ([dim - 1] if gravity else [])
  coef = jnp.array([0.0] * dim + ([1.0] if gravity else []), x.dtype) * quad
  dims = jnp.array(dims)

  def constraint(x_t, p_s, tau):
    r = x_t[dims] - p_s[dims] - coef * tau * tau
    inv = 1.0 / (tau * step)
    return (r - e) * inv, (r + e) * inv

  def feasible(ok):
    if gravity:
      return jnp.all(ok[:dim - 1]) & (ok[dim - 1] | ok[dim])
    return jnp.all(ok)

  def choose(lo, hi, pred, length):
    v, r, ok = _pick(lo, hi, pred[dims], lattice_exponent(length, coarse))
    if not gravity:
      return v, jnp.array(False)
    use_quad = ok[dim] & (~ok[dim - 1] | (jnp.abs(r[dim]) < jnp.abs(r[dim - 1])))
    vz = jnp.where(use_quad, v[dim], v[dim - 1])
    return jnp.concatenate([v[:dim - 1], vz[None]]), use_quad

  def next_pred(vel, flag, length):
    if not gravity:
      return vel
    return vel.at[dim - 1].add(gravity_increment(flag, length, g_fp))

  def start_value(acc):
    # The decoded start from exact integer sums (float32 sums would drift over
    # many segments): sum of L * v (fine steps) and of flag * L**2.
    acc_lin, acc_quad = acc
    p = acc_lin.astype(x.dtype) * step
    if gravity:
      p = p.at[dim - 1].add(acc_quad.astype(x.dtype) * quad)
    return p

  def advance(acc, vel, flag, length):
    acc_lin, acc_quad = acc
    return (acc_lin + length * vel, acc_quad + jnp.where(flag, length * length, 0))

  def body(carry, inp):
    t_s, acc, lo, hi, pred = carry
    t, x_t = inp
    tau_i = t - t_s
    tau = tau_i.astype(x.dtype)
    clo, chi = constraint(x_t, start_value(acc), tau)
    nlo, nhi = jnp.maximum(lo, clo), jnp.minimum(hi, chi)
    ok = _pick(nlo, nhi, pred[dims], lattice_exponent(tau_i, coarse))[2]
    cont = feasible(ok) & (tau_i <= MAX_SEGMENT)
    valid = t < n
    end = valid & ~cont
    # The segment [t_s, t - 1] closes; the next one starts at its decoded end.
    length = tau_i - 1
    vel, flag = choose(lo, hi, pred, length)
    acc_end = advance(acc, vel, flag, length)
    rlo, rhi = constraint(x_t, start_value(acc_end), jnp.asarray(1.0, x.dtype))
    closed = (t - 1, acc_end, rlo, rhi, next_pred(vel, flag, length))
    extended = (t_s, acc, nlo, nhi, pred)
    new = jax.tree.map(lambda c, e_, o: jnp.where(end, c, jnp.where(valid, e_, o)),
                       closed, extended, carry)
    return new, (end, vel, flag)

  n_win = dims.shape[0]
  init = (jnp.int32(0), (jnp.zeros(dim, jnp.int32), jnp.int32(0)),
          jnp.full(n_win, -jnp.inf, x.dtype), jnp.full(n_win, jnp.inf, x.dtype),
          jnp.zeros(dim, jnp.int32))
  ts = jnp.arange(1, num_t, dtype=jnp.int32)
  carry, (ends, vel, flag) = jax.lax.scan(body, init, (ts, x[1:]))
  t_s, _, lo, hi, pred = carry
  last_vel, last_flag = choose(lo, hi, pred, n - 1 - t_s)
  # ys[i] describes the segment closing at frame i; append the final segment.
  ends = jnp.concatenate([ends, jnp.zeros(1, bool)])
  vel = jnp.concatenate([vel, jnp.zeros((1, dim), jnp.int32)])
  flag = jnp.concatenate([flag, jnp.zeros(1, bool)])
  last = jnp.maximum(n - 1, 0)
  has_last = n >= 2
  ends = ends.at[last].set(jnp.where(has_last, True, ends[last]))
  vel = vel.at[last].set(jnp.where(has_last, last_vel, vel[last]))
  flag = flag.at[last].set(jnp.where(has_last, last_flag, flag[last]))
  return LinearFit(ends, vel, flag)


def _pick_near(lo, hi, pred, target, m):
  """Like ``_pick`` but the lattice point ``pred + r * 2**m`` nearest ``target``."""
  spacing = jnp.left_shift(jnp.int32(1), m)
  r_t = jnp.round((jnp.clip(target, -_INT_CAP, _INT_CAP) - pred) / spacing).astype(jnp.int32)
  v, r, ok = _pick(lo, hi, pred + r_t * spacing, m)
  return v, r + r_t, ok


def _fit_rotation_path(q, n, e, step, coarse) -> RotationFit:
  """Fit one rotation path.

  Args:
    q: f32[T, 4] unit quaternions (w, x, y, z); signs may flip between frames.
    n: i32 valid frames.
    e: f32 radius of the ball that bounds the log-map error (radians).
    step: f32 finest angular velocity quantum (radians per frame).
    coarse: i32 lattice exponent of a 1-frame segment.
  """
  boxes = jnp.concatenate([jnp.asarray(ROTATION_BOXES, q.dtype) * e,
                           jnp.full((1, 3), e, q.dtype)])  # last: the ball's bounding box
  n_box = boxes.shape[0]
  span = EXACT_SPAN

  def windows(omega, tau):
    inv = 1.0 / (tau * step)
    return (omega - boxes) * inv, (omega + boxes) * inv  # [K+1, 3] each

  def inside_ball(w, logs, tau):
    """Every frame 1..tau of the segment within the ball (``logs[i]``: frame i + 1)."""
    taus = jnp.arange(1, span + 1, dtype=q.dtype)[:, None]
    dev = taus * w.astype(q.dtype) * step - logs
    inside = jnp.sum(dev * dev, axis=-1) <= e * e
    return jnp.all(inside | (jnp.arange(1, span + 1) > tau))

  def best(lo, hi, pred, logs, tau):
    """(velocity, feasible) for a segment of ``tau`` frames, the one with the
    smallest residual among: each box's pick, and (segments up to ``span``
    frames) three lattice points of the ball's bounding box that pass the
    frame-by-frame check, those nearest the prediction, the window centre and the
    least-squares velocity."""
    m = lattice_exponent(tau, coarse)
    w_box, r_box, ok_box = _pick(lo[:-1], hi[:-1], pred[None], m)
    taus = jnp.arange(1, span + 1, dtype=q.dtype)[:, None]
    in_segment = jnp.arange(1, span + 1)[:, None] <= tau
    w_ls = jnp.sum(jnp.where(in_segment, taus * logs, 0.0), axis=0) / (
        jnp.sum(jnp.where(in_segment, taus * taus, 0.0)) * step)
    targets = jnp.stack([pred.astype(q.dtype), 0.5 * (lo[-1] + hi[-1]), w_ls])
    w_ball, r_ball, ok_ball = jax.vmap(lambda tg: _pick_near(lo[-1], hi[-1], pred, tg, m))(targets)
    checked = jax.vmap(lambda w: inside_ball(w, logs, tau))(w_ball) & (tau <= span)
    cand = jnp.concatenate([w_box, w_ball])
    good = jnp.concatenate([jnp.all(ok_box, axis=-1), jnp.all(ok_ball, axis=-1) & checked])
    cost = jnp.sum(jnp.abs(jnp.concatenate([r_box, r_ball])), axis=-1)
    cost = jnp.where(good, cost, jnp.iinfo(jnp.int32).max)
    return cand[jnp.argmin(cost)], jnp.any(good)

  def end_value(q_s, w, length):
    q_e = quat_mul(quat_exp(length.astype(q.dtype) * w.astype(q.dtype) * step), q_s)
    return q_e / jnp.linalg.norm(q_e)

  def body(carry, inp):
    t_s, q_s, lo, hi, pred, logs, w_prev = carry
    t, q_t = inp
    tau_i = t - t_s
    omega = rel_log(q_t, q_s)
    clo, chi = windows(omega, tau_i.astype(q.dtype))
    nlo, nhi = jnp.maximum(lo, clo), jnp.minimum(hi, chi)
    nlogs = logs.at[jnp.minimum(tau_i, span) - 1].set(
        jnp.where(tau_i <= span, omega, logs[span - 1]))
    w_cur, ok = best(nlo, nhi, pred, nlogs, tau_i)
    cont = ok & (tau_i <= MAX_SEGMENT)
    valid = t < n
    end = valid & ~cont
    # The segment [t_s, t - 1] closes with the velocity found for it last frame.
    length = tau_i - 1
    q_e = end_value(q_s, w_prev, length)
    omega1 = rel_log(q_t, q_e)
    rlo, rhi = windows(omega1, jnp.asarray(1.0, q.dtype))
    rlogs = jnp.zeros_like(logs).at[0].set(omega1)
    w_one = best(rlo, rhi, w_prev, rlogs, jnp.int32(1))[0]
    closed = (t - 1, q_e, rlo, rhi, w_prev, rlogs, w_one)
    extended = (t_s, q_s, nlo, nhi, pred, nlogs, w_cur)
    new = jax.tree.map(lambda c, e_, o: jnp.where(end, c, jnp.where(valid, e_, o)),
                       closed, extended, carry)
    return new, (end, w_prev)

  init = (jnp.int32(0), q[0], jnp.full((n_box, 3), -jnp.inf, q.dtype),
          jnp.full((n_box, 3), jnp.inf, q.dtype), jnp.zeros(3, jnp.int32),
          jnp.zeros((span, 3), q.dtype), jnp.zeros(3, jnp.int32))
  ts = jnp.arange(1, q.shape[0], dtype=jnp.int32)
  carry, (ends, vel) = jax.lax.scan(body, init, (ts, q[1:]))
  last_w = carry[-1]
  ends = jnp.concatenate([ends, jnp.zeros(1, bool)])
  vel = jnp.concatenate([vel, jnp.zeros((1, 3), jnp.int32)])
  last = jnp.maximum(n - 1, 0)
  has_last = n >= 2
  ends = ends.at[last].set(jnp.where(has_last, True, ends[last]))
  vel = vel.at[last].set(jnp.where(has_last, last_w, vel[last]))
  return RotationFit(ends, vel)


@functools.partial(jax.jit, static_argnames=("gravity",))
def fit_linear_batch(x, n, e, step, quad, coarse, g_fp, gravity: bool) -> LinearFit:
  """Vmapped linear fit. x: f32[N, T, D] relative to x[:, 0]; n: i32[N]; e: f32[N]."""
  fit = functools.partial(_fit_linear_path, gravity=gravity)
  return jax.vmap(fit, in_axes=(0, 0, 0, None, None, None, None))(x, n, e, step, quad, coarse,
                                                                   g_fp)


@jax.jit
def fit_rotation_batch(q, n, e, step, coarse) -> RotationFit:
  """Vmapped rotation fit. q: f32[N, T, 4] (normalized inside); n: i32[N]; e: f32[N]."""
  norm = jnp.linalg.norm(q, axis=-1, keepdims=True)
  q = q / jnp.where(norm > 0, norm, 1.0)
  return jax.vmap(_fit_rotation_path, in_axes=(0, 0, 0, None, None))(q, n, e, step, coarse)
