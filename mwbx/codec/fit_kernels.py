"""The greedy segment fit as compiled loops, one path at a time.

The algorithm is :mod:`mwbx.codec.fit`'s (paper Fig. 4, exact for quantized
coefficients; read its docstring for the model): every frame narrows the
interval of velocities that keep all frames of the segment within the bound,
and the segment closes at the first frame that leaves no allowed velocity.
There it is written as jitted JAX over a batch of paths, here as a numba loop
over one path's frames, called path after path: on the CPU a frame costs a few
dozen scalar operations, where each of XLA's per-operation dispatches costs
more than that (256 paths of 2-512 frames on one core: 23 ms for the JAX
translation fit against 7 ms here, 89 ms against 15 ms for rotations).
The encoder fits with these; ``fit.py`` stays as the reference the tests hold
them to.

Arithmetic is float64 (the JAX fit's is float32): a segment's start is the
decoder's own (integer sums times the quantum, as the decoder accumulates it
in float64), so the fit's margin (``encode.FIT_MARGIN``) only covers the
decoder's float32 evaluation. Results do not depend on the batch a path is
fitted in. The encoder still decodes every stream and checks the bound.
"""

from __future__ import annotations

import math

import numpy as np

from mwbx.codec.fit import CUBE, EXACT_SPAN, INT_CAP, MAX_SEGMENT, LinearFit, RotationFit
from mwbx.host_jit import borrowed, held, host_jit

_INT_MAX = np.iinfo(np.int64).max


@host_jit
def lattice_exponent(length, coarse):
  """:func:`mwbx.codec.fit.lattice_exponent` of one segment length."""
  length = max(length, 1)
  floor_log2 = 0
  while length > 1:
    length >>= 1
    floor_log2 += 1
  return max(0, coarse - floor_log2)


@host_jit
def _pick(lo, hi, pred, m):
  """(velocity, r, non-empty) of :func:`mwbx.codec.fit._pick` for one coordinate."""
  lo = min(max(lo, -INT_CAP), INT_CAP)
  hi = min(max(hi, -INT_CAP), INT_CAP)
  lo_floor, hi_floor = math.floor(lo), math.floor(hi)
  below = np.int64(lo_floor) - pred
  above = np.int64(hi_floor) - pred
  r_lo = (below >> m) + 1 if lo > lo_floor else -((-below) >> m)
  r_hi = above >> m
  r = min(max(np.int64(0), r_lo), r_hi)
  return pred + r * (np.int64(1) << m), r, r_lo <= r_hi


@host_jit
def _pick_near(lo, hi, pred, target, m):
  """:func:`_pick` for the lattice point ``pred + r * 2**m`` nearest ``target``."""
  spacing = np.int64(1) << m
  r_t = np.int64(np.rint((min(max(target, -INT_CAP), INT_CAP) - pred) / spacing))
  v, r, ok = _pick(lo, hi, pred + r_t * spacing, m)
  return v, r + r_t, ok


# -- linear channels -------------------------------------------------------------------


@host_jit
def _linear_windows(x_t, start, tau, e, step, quad, gravity, lo, hi):
  """Velocity windows of one frame ``tau`` frames into a segment from ``start``:
  one per coordinate, and with ``gravity`` a second one for the last coordinate
  with the quadratic term on (index ``dim``)."""
  dim = x_t.size
  inv = 1.0 / (tau * step)
  for d in range(dim):
    r = x_t[d] - start[d]
    lo[d], hi[d] = (r - e) * inv, (r + e) * inv
  if gravity:
    r = x_t[dim - 1] - start[dim - 1] - quad * tau * tau
    lo[dim], hi[dim] = (r - e) * inv, (r + e) * inv


@host_jit
def _linear_feasible(lo, hi, pred, m, dim, gravity):
  for d in range(dim - 1 if gravity else dim):
    if not _pick(lo[d], hi[d], pred[d], m)[2]:
      return False
  if gravity:
    return _pick(lo[dim - 1], hi[dim - 1], pred[dim - 1], m)[2] or _pick(lo[dim], hi[dim], pred[dim - 1], m)[2]
  return True


@host_jit
def _linear_choose(lo, hi, pred, length, coarse, dim, gravity, vel):
  """Writes the segment's velocity into ``vel``; returns its gravity flag."""
  m = lattice_exponent(length, coarse)
  for d in range(dim):
    vel[d] = _pick(lo[d], hi[d], pred[d], m)[0]
  if not gravity:
    return False
  v_flat, r_flat, ok_flat = _pick(lo[dim - 1], hi[dim - 1], pred[dim - 1], m)
  v_quad, r_quad, ok_quad = _pick(lo[dim], hi[dim], pred[dim - 1], m)
  use_quad = ok_quad and (not ok_flat or abs(r_quad) < abs(r_flat))
  vel[dim - 1] = v_quad if use_quad else v_flat
  return use_quad


@host_jit
def _linear_start(acc_lin, acc_quad, step, quad, gravity, out):
  """The decoded start of a segment from the exact integer sums before it."""
  for d in range(out.size):
    out[d] = acc_lin[d] * step
  if gravity:
    out[out.size - 1] += acc_quad * quad


@host_jit
def fit_linear_path(x, n, e, step, quad, coarse, g_fp, gravity, ends, vel, flag):
  """Fit one linear-channel path (:func:`mwbx.codec.fit._fit_linear_path`).

  Args:
    x: f32[T, D] positions relative to x[0]; n: valid frames; e: the bound
      used for the fit; step, quad, coarse, g_fp, gravity: as ``fit.py``.
    ends: bool[T] out, frame f closes a segment; vel: i64[T, D] out, the
      integer velocity of the segment closing at f; flag: bool[T] out, its
      vertical quadratic term on.
  """
  num_t, dim = x.shape
  n_win = dim + 1 if gravity else dim
  # The arrays without reference counting from here on (held to the end).
  x, ends, vel, flag = borrowed((x, ends, vel, flag))
  owned = (np.full(n_win, -np.inf), np.full(n_win, np.inf), np.empty(n_win), np.empty(n_win),
           np.zeros(dim, np.int64), np.zeros(dim, np.int64), np.zeros(dim), np.empty(dim), np.empty(dim, np.int64))
  lo, hi, clo, chi, pred, acc_lin, start, x_t, seg_vel = borrowed(owned)
  acc_quad = 0
  t_s = 0
  ends[:] = False
  flag[:] = False
  vel[:, :] = 0
  for t in range(1, min(n, num_t)):
    for d in range(dim):
      x_t[d] = x[t, d]
    tau_i = t - t_s
    _linear_windows(x_t, start, np.float64(tau_i), e, step, quad, gravity, clo, chi)
    for j in range(n_win):
      clo[j], chi[j] = max(lo[j], clo[j]), min(hi[j], chi[j])
    if tau_i <= MAX_SEGMENT and _linear_feasible(clo, chi, pred, lattice_exponent(tau_i, coarse), dim, gravity):
      lo[:], hi[:] = clo, chi
      continue
    # The segment [t_s, t - 1] closes; the next one starts at its decoded end.
    length = tau_i - 1
    seg_flag = _linear_choose(lo, hi, pred, length, coarse, dim, gravity, seg_vel)
    ends[t - 1], flag[t - 1] = True, seg_flag
    for d in range(dim):
      vel[t - 1, d] = seg_vel[d]
      acc_lin[d] += length * seg_vel[d]
      pred[d] = seg_vel[d]
    if seg_flag:
      acc_quad += length * length
      pred[dim - 1] += (length * g_fp + 128) >> 8  # the vertical velocity gained falling
    _linear_start(acc_lin, acc_quad, step, quad, gravity, start)
    _linear_windows(x_t, start, 1.0, e, step, quad, gravity, lo, hi)
    t_s = t - 1
  if n >= 2:
    last = min(n, num_t) - 1
    flag[last] = _linear_choose(lo, hi, pred, last - t_s, coarse, dim, gravity, seg_vel)
    ends[last] = True
    vel[last, :] = seg_vel
  held(owned)


@host_jit
def _fit_linear_paths(x, n, e, step, quad, coarse, g_fp, gravity, ends, vel, flag):
  for p in range(x.shape[0]):
    fit_linear_path(x[p], n[p], e[p], step, quad, coarse, g_fp, gravity, ends[p], vel[p], flag[p])


def fit_linear_batch(x, n, e, step, quad, coarse, g_fp, gravity: bool) -> LinearFit:
  """:func:`mwbx.codec.fit.fit_linear_batch` as compiled loops (numpy in and
  out, velocities i64). x: f32[N, T, D] relative to x[:, 0]; n: i[N]; e: f[N]."""
  x = np.ascontiguousarray(x, np.float32)
  num, num_t, dim = x.shape
  ends, flag = np.zeros((num, num_t), bool), np.zeros((num, num_t), bool)
  vel = np.zeros((num, num_t, dim), np.int64)
  _fit_linear_paths(x, np.asarray(n, np.int64), np.asarray(e, np.float64), float(step), float(quad),
                    int(coarse), int(g_fp), bool(gravity), ends, vel, flag)
  return LinearFit(ends, vel, flag)


# -- rotations -------------------------------------------------------------------------


@host_jit
def _quat_mul(a, b, out):
  """Hamilton product ``a (x) b`` (w, x, y, z) into ``out``."""
  aw, ax, ay, az = a[0], a[1], a[2], a[3]
  bw, bx, by, bz = b[0], b[1], b[2], b[3]
  out[0] = aw * bw - ax * bx - ay * by - az * bz
  out[1] = aw * bx + ax * bw + ay * bz - az * by
  out[2] = aw * by - ax * bz + ay * bw + az * bx
  out[3] = aw * bz + ax * by - ay * bx + az * bw


@host_jit
def _rel_log(q, q_start, out):
  """Rotation vector of ``q (x) q_start^-1`` (angle in [0, pi]) into ``out[3]``
  (:func:`mwbx.codec.fit.rel_log`)."""
  sw, sx, sy, sz = q_start[0], -q_start[1], -q_start[2], -q_start[3]
  rw = q[0] * sw - q[1] * sx - q[2] * sy - q[3] * sz
  rx = q[0] * sx + q[1] * sw + q[2] * sz - q[3] * sy
  ry = q[0] * sy - q[1] * sz + q[2] * sw + q[3] * sx
  rz = q[0] * sz + q[1] * sy - q[2] * sx + q[3] * sw
  if rw < 0:  # q and -q are the same rotation
    rw, rx, ry, rz = -rw, -rx, -ry, -rz
  s = math.sqrt(rx * rx + ry * ry + rz * rz)
  factor = 2.0 * math.atan2(s, rw) / s if s > 1e-12 else 2.0 / max(rw, 1e-12)
  out[0], out[1], out[2] = factor * rx, factor * ry, factor * rz


@host_jit
def _end_value(q_s, w, length, step, exp_q, out):
  """The unit quaternion ``exp(length * w * step) (x) q_s`` into ``out`` (may be ``q_s``)."""
  ox, oy, oz = length * w[0] * step, length * w[1] * step, length * w[2] * step
  theta = math.sqrt(ox * ox + oy * oy + oz * oz)
  factor = math.sin(0.5 * theta) / theta if theta > 1e-12 else 0.5
  exp_q[0], exp_q[1], exp_q[2], exp_q[3] = math.cos(0.5 * theta), factor * ox, factor * oy, factor * oz
  _quat_mul(exp_q, q_s, out)
  norm = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3])
  for i in range(4):
    out[i] /= norm


@host_jit
def _inside_ball(w, logs, tau_i, e, step):
  """Frames 1..tau_i of the segment (``logs[i]``: frame i + 1's log-map
  deviation) all within the ball of radius ``e`` about ``tau * w * step``."""
  for i in range(min(tau_i, EXACT_SPAN)):
    tau = i + 1.0
    d2 = 0.0
    for k in range(3):
      d = tau * (w[k] * step) - logs[i, k]
      d2 += d * d
    if d2 > e * e:
      return False
  return True


@host_jit
def _rotation_best(lo, hi, pred, logs, sum_wt, sum_tt, tau_i, e, step, coarse, w, w_c):
  """:func:`mwbx.codec.fit._fit_rotation_paths`'s ``best`` for one path: the
  velocity (into ``w``) with the smallest residual among the cube's pick and,
  for segments of up to EXACT_SPAN frames, the lattice points of the ball's
  bounding box nearest the prediction, the window centre and the
  least-squares velocity whose every frame lies within the ball. Returns
  whether any is allowed. lo, hi: f64[2, 3] windows (cube, ball's box)."""
  m = lattice_exponent(tau_i, coarse)
  feasible = True
  cost = 0
  for k in range(3):
    v, r, ok = _pick(lo[0, k], hi[0, k], pred[k], m)
    w[k] = v
    cost += abs(r)
    feasible = feasible and ok
  if not feasible:
    cost = _INT_MAX
  if tau_i > EXACT_SPAN:
    return feasible
  scale = max(sum_tt, 1.0) * step
  for target in range(3):
    cand_cost = 0
    good = True
    for k in range(3):
      if target == 0:
        aim = np.float64(pred[k])
      elif target == 1:
        aim = 0.5 * (lo[1, k] + hi[1, k])
      else:
        aim = sum_wt[k] / scale
      v, r, ok = _pick_near(lo[1, k], hi[1, k], pred[k], aim, m)
      w_c[k] = v
      cand_cost += abs(r)
      good = good and ok
    if good and _inside_ball(w_c, logs, tau_i, e, step):
      feasible = True
      if cand_cost < cost:
        cost = cand_cost
        w[:] = w_c
  return feasible


@host_jit
def _rotation_windows(omega, tau, half, step, lo, hi):
  inv = 1.0 / (tau * step)
  for b in range(2):
    for k in range(3):
      lo[b, k], hi[b, k] = (omega[k] - half[b]) * inv, (omega[k] + half[b]) * inv


@host_jit
def fit_rotation_path(q, n, e, step, coarse, ends, vel):
  """Fit one rotation path (:func:`mwbx.codec.fit._fit_rotation_paths`).

  Args:
    q: f32[T, 4] quaternions (w, x, y, z; normalized here; signs may flip
      between frames); n: valid frames; e: radius of the ball that bounds the
      log-map error (radians); step: the finest angular velocity quantum
      (radians per frame); coarse: lattice exponent of a 1-frame segment.
    ends: bool[T] out, frame f closes a segment; vel: i64[T, 3] out, the
      integer angular velocity of the segment closing at f.
  """
  num_t = q.shape[0]
  # The arrays without reference counting from here on (held to the end).
  q, ends, vel = borrowed((q, ends, vel))
  owned = (np.array([CUBE * e, e]), np.full((2, 3), -np.inf), np.full((2, 3), np.inf), np.empty((2, 3)),
           np.empty((2, 3)), np.zeros((EXACT_SPAN, 3)), np.zeros(3), np.zeros(3, np.int64),
           np.zeros((3, 3), np.int64), np.empty((3, 4)), np.empty((2, 3)))
  half, lo, hi, nlo, nhi, logs, sum_wt, pred, w3, q3, o2 = borrowed(owned)
  w_prev, w_cur, w_c = w3[0], w3[1], w3[2]
  q_s, q_t, exp_q = q3[0], q3[1], q3[2]
  omega, sum_next = o2[0], o2[1]
  sum_tt = 0.0
  ends[:] = False
  vel[:, :] = 0
  _normalized(q[0], q_s)
  t_s = 0
  for t in range(1, min(n, num_t)):
    _normalized(q[t], q_t)
    tau_i = t - t_s
    tau = np.float64(tau_i)
    _rel_log(q_t, q_s, omega)
    _rotation_windows(omega, tau, half, step, nlo, nhi)
    for b in range(2):
      for k in range(3):
        nlo[b, k], nhi[b, k] = max(lo[b, k], nlo[b, k]), min(hi[b, k], nhi[b, k])
    if tau_i <= EXACT_SPAN:
      logs[tau_i - 1, :] = omega
    for k in range(3):
      sum_next[k] = sum_wt[k] + tau * omega[k]
    if tau_i <= MAX_SEGMENT and _rotation_best(nlo, nhi, pred, logs, sum_next, sum_tt + tau * tau, tau_i, e,
                                               step, coarse, w_cur, w_c):
      lo[:, :], hi[:, :] = nlo, nhi
      sum_wt[:] = sum_next
      sum_tt += tau * tau
      w_prev[:] = w_cur
      continue
    # The segment [t_s, t - 1] closes with the velocity found for it last frame.
    ends[t - 1] = True
    vel[t - 1, :] = w_prev
    _end_value(q_s, w_prev, tau_i - 1, step, exp_q, q_s)  # in place: q_s is read first
    _rel_log(q_t, q_s, omega)
    _rotation_windows(omega, 1.0, half, step, lo, hi)
    logs[:, :] = 0.0
    logs[0, :] = omega
    sum_wt[:] = omega
    sum_tt = 1.0
    pred[:] = w_prev
    # A 1-frame segment: the cube always holds a lattice point.
    m1 = lattice_exponent(1, coarse)
    for k in range(3):
      w_prev[k] = _pick(lo[0, k], hi[0, k], pred[k], m1)[0]
    t_s = t - 1
  if n >= 2:
    last = min(n, num_t) - 1
    ends[last] = True
    vel[last, :] = w_prev
  held(owned)


@host_jit
def _normalized(q, out):
  norm = math.sqrt(np.float64(q[0]) ** 2 + np.float64(q[1]) ** 2 + np.float64(q[2]) ** 2 + np.float64(q[3]) ** 2)
  scale = 1.0 / norm if norm > 0 else 1.0
  for i in range(4):
    out[i] = q[i] * scale


@host_jit
def _fit_rotation_paths(q, n, e, step, coarse, ends, vel):
  for p in range(q.shape[0]):
    fit_rotation_path(q[p], n[p], e[p], step, coarse, ends[p], vel[p])


def fit_rotation_batch(q, n, e, step, coarse) -> RotationFit:
  """:func:`mwbx.codec.fit.fit_rotation_batch` as compiled loops (numpy in
  and out, velocities i64). q: f32[N, T, 4]; n: i[N]; e: f[N]."""
  q = np.ascontiguousarray(q, np.float32)
  num, num_t, _ = q.shape
  ends, vel = np.zeros((num, num_t), bool), np.zeros((num, num_t, 3), np.int64)
  _fit_rotation_paths(q, np.asarray(n, np.int64), np.asarray(e, np.float64), float(step), int(coarse), ends, vel)
  return RotationFit(ends, vel)
