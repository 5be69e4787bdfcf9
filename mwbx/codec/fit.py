"""Greedy error-bounded segment fit (paper Fig. 4), as jitted JAX kernels.

Every operation acts on one path at a time. The linear kernel is written for
ONE path and ``jax.vmap``-ped over many (all worlds x channels of a kind) at the
edge; the rotation kernel carries the path axis last instead, so that XLA's CPU
loops run across paths (see :func:`_fit_rotation_paths`).

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
expand distances): every frame's log-map deviation must lie in the ball of
radius ``e_rot``. Per-coordinate windows only describe a box, and the largest
box inside that ball (half-width ``e_rot / sqrt(3)``) holds 37 % of it. So the
fit keeps the cube's windows (always safe) and, for segments of up to
``EXACT_SPAN`` frames, also tests a few lattice points of the ball's bounding
box against the ball frame by frame; it takes the allowed velocity with the
smallest residual. The decoder never needs to know which test admitted it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mwbx import rotations

# Velocities are kept in int32; windows are clipped to this magnitude first.
INT_CAP = 2.0**30


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


# Segments are cut at this length so integer products stay within int32.
MAX_SEGMENT = 4096

# Rotation segments of up to EXACT_SPAN frames are also tested frame by frame
# against the error ball (their log-map deviations are kept); longer ones must
# stay inside the cube of half-width e_rot / sqrt(3). 8 frames kept most of the
# gain of 32 on the shipped scenes at a quarter of the cost.
EXACT_SPAN = 8
CUBE = float(1.0 / np.sqrt(3.0)) * (1.0 - 2.0**-20)


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
  lo = jnp.clip(lo, -INT_CAP, INT_CAP)
  hi = jnp.clip(hi, -INT_CAP, INT_CAP)
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
  r_t = jnp.round((jnp.clip(target, -INT_CAP, INT_CAP) - pred) / spacing).astype(jnp.int32)
  v, r, ok = _pick(lo, hi, pred + r_t * spacing, m)
  return v, r + r_t, ok


def rel_log(q: jax.Array, q_start: jax.Array) -> jax.Array:
  """Rotation vector of ``q (x) q_start^-1`` (angle in [0, pi]), components first:
  f32[4, N] -> f32[3, N]."""
  conj = q_start * jnp.array([1.0, -1.0, -1.0, -1.0], q_start.dtype)[:, None]
  rel = rotations.quat_multiply(q, conj, axis=0)
  rel = jnp.where(rel[0] < 0, -rel, rel)  # q and -q are the same rotation
  s = jnp.sqrt(jnp.sum(rel[1:] * rel[1:], axis=0))
  angle = 2.0 * jnp.arctan2(s, rel[0])
  factor = jnp.where(s > 1e-12, angle / jnp.where(s > 1e-12, s, 1.0),
                     2.0 / jnp.maximum(rel[0], 1e-12))
  return factor * rel[1:]


def _fit_rotation_paths(q, n, e, step, coarse):
  """Fit many rotation paths, the path axis last.

  This kernel is written for a batch with the path axis LAST rather than for one
  path under ``vmap``: vmap puts the path axis first, which leaves the inner
  loops of the per-frame ball test 3 (or span x 3) long; with the paths last
  XLA's CPU loops run across paths (the same fit, 256 paths x 512 frames: 16 ms
  against 44-68 ms under vmap, measured). Every operation is still per path.

  Args:
    q: f32[T, 4, N] unit quaternions (w, x, y, z); signs may flip between frames.
    n: i32[N] valid frames.
    e: f32[N] radius of the ball that bounds the log-map error (radians).
    step: f32 finest angular velocity quantum (radians per frame).
    coarse: i32 lattice exponent of a 1-frame segment.

  Returns:
    (ends: bool[T - 1, N], vel: i32[T - 1, 3, N], last_w: i32[3, N]); entry i of
    ends and vel describes the segment closing at frame i; last_w is the
    velocity of the final segment (closing at frame n - 1).
  """
  span = EXACT_SPAN
  dtype = q.dtype
  num = q.shape[-1]
  # Velocity windows (lo, hi: f32[2, 3, N]): the cube, the ball's bounding box.
  half = jnp.asarray([[CUBE], [1.0]], dtype)[:, :, None] * e
  frame_of_row = jnp.arange(1, span + 1)[:, None, None]  # row i holds frame i + 1
  taus = frame_of_row.astype(dtype)
  int_max = jnp.iinfo(jnp.int32).max

  def windows(omega, tau):
    inv = 1.0 / (tau * step)
    return (omega - half) * inv, (omega + half) * inv

  def inside_ball(w, logs, tau_i):
    """bool[N]: frames 1..tau of the segment all within the ball."""
    rate = w.astype(dtype) * step
    d2 = sum((taus[:, 0] * rate[k] - logs[:, k]) ** 2 for k in range(3))  # [span, N]
    outside = (d2 > e * e) & (frame_of_row[:, 0] <= tau_i)
    return ~jnp.any(outside, axis=0)

  def best(lo, hi, pred, logs, sums, tau_i):
    """(velocity i32[3, N], feasible bool[N]) for segments of ``tau_i`` frames:
    the smallest residual among the cube's pick and (segments up to ``span``
    frames) the lattice points of the ball's bounding box nearest the
    prediction, the window centre and the least-squares velocity, those whose
    every frame lies within the ball."""
    m = lattice_exponent(tau_i, coarse)
    w, r, ok = _pick(lo[0], hi[0], pred, m)
    feasible = jnp.all(ok, axis=0)
    cost = jnp.where(feasible, jnp.sum(jnp.abs(r), axis=0), int_max)
    short = tau_i <= span
    least_squares = sums[0] / (jnp.maximum(sums[1], 1.0) * step)
    for target in (pred.astype(dtype), 0.5 * (lo[1] + hi[1]), least_squares):
      w_c, r_c, ok_c = _pick_near(lo[1], hi[1], pred, target, m)
      good = jnp.all(ok_c, axis=0) & short & inside_ball(w_c, logs, tau_i)
      c = jnp.where(good, jnp.sum(jnp.abs(r_c), axis=0), int_max)
      better = c < cost
      w, cost = jnp.where(better, w_c, w), jnp.where(better, c, cost)
      feasible = feasible | good
    return w, feasible

  def end_value(q_s, w, length):
    q_e = rotations.quat_multiply(rotations.quat_exp(length.astype(dtype) * w.astype(dtype) * step), q_s, axis=0)
    return q_e / jnp.sqrt(jnp.sum(q_e * q_e, axis=0))

  def body(carry, inp):
    t_s, q_s, lo, hi, pred, logs, sums, w_prev = carry
    t, q_t = inp
    tau_i = t - t_s
    tau = tau_i.astype(dtype)
    omega = rel_log(q_t, q_s)
    clo, chi = windows(omega, tau)
    nlo, nhi = jnp.maximum(lo, clo), jnp.minimum(hi, chi)
    nlogs = jnp.where(frame_of_row == tau_i, omega, logs)
    nsums = (sums[0] + tau * omega, sums[1] + tau * tau)
    w_cur, ok = best(nlo, nhi, pred, nlogs, nsums, tau_i)
    cont = ok & (tau_i <= MAX_SEGMENT)
    valid = t < n
    end = valid & ~cont
    # The segment [t_s, t - 1] closes with the velocity found for it last frame.
    length = tau_i - 1
    q_e = end_value(q_s, w_prev, length)
    omega1 = rel_log(q_t, q_e)
    one = jnp.ones(num, dtype)
    rlo, rhi = windows(omega1, one)
    rlogs = jnp.where(frame_of_row == 1, omega1, 0.0)
    # A 1-frame segment: the cube always holds a lattice point (its width is
    # more than the coarsest spacing, the bound per frame).
    w_one = _pick(rlo[0], rhi[0], w_prev, lattice_exponent(jnp.ones(num, jnp.int32), coarse))[0]
    closed = (jnp.broadcast_to(t - 1, (num,)), q_e, rlo, rhi, w_prev, rlogs, (omega1, one), w_one)
    extended = (t_s, q_s, nlo, nhi, pred, nlogs, nsums, w_cur)
    new = jax.tree.map(lambda c, e_, o: jnp.where(end, c, jnp.where(valid, e_, o)),
                       closed, extended, carry)
    return new, (end, w_prev)

  zeros3 = jnp.zeros((3, num), jnp.int32)
  init = (jnp.zeros(num, jnp.int32), q[0], jnp.full((2, 3, num), -jnp.inf, dtype),
          jnp.full((2, 3, num), jnp.inf, dtype), zeros3, jnp.zeros((span, 3, num), dtype),
          (jnp.zeros((3, num), dtype), jnp.zeros(num, dtype)), zeros3)
  ts = jnp.arange(1, q.shape[0], dtype=jnp.int32)
  carry, (ends, vel) = jax.lax.scan(body, init, (ts, q[1:]))
  return ends, vel, carry[-1]


@functools.partial(jax.jit, static_argnames=("gravity",))
def fit_linear_batch(x, n, e, step, quad, coarse, g_fp, gravity: bool) -> LinearFit:
  """Vmapped linear fit. x: f32[N, T, D] relative to x[:, 0]; n: i32[N]; e: f32[N]."""
  fit = functools.partial(_fit_linear_path, gravity=gravity)
  return jax.vmap(fit, in_axes=(0, 0, 0, None, None, None, None))(x, n, e, step, quad, coarse,
                                                                   g_fp)


@jax.jit
def fit_rotation_batch(q, n, e, step, coarse) -> RotationFit:
  """Rotation fit of many paths. q: f32[N, T, 4] (normalized inside); n: i32[N]; e: f32[N]."""
  norm = jnp.linalg.norm(q, axis=-1, keepdims=True)
  q = q / jnp.where(norm > 0, norm, 1.0)
  num, num_t = q.shape[:2]
  ends, vel, last_w = _fit_rotation_paths(jnp.transpose(q, (1, 2, 0)), n, e, step, coarse)
  ends = jnp.concatenate([ends.T, jnp.zeros((num, 1), bool)], axis=1)
  vel = jnp.concatenate([jnp.transpose(vel, (2, 0, 1)), jnp.zeros((num, 1, 3), jnp.int32)], axis=1)
  # The final segment closes at frame n - 1 (paths of 2 frames or more).
  last = (jnp.arange(num_t)[None] == jnp.maximum(n - 1, 0)[:, None]) & (n >= 2)[:, None]
  return RotationFit(ends | last, jnp.where(last[..., None], last_w.T[:, None], vel))
