"""Evaluation and error checks as compiled loops: decoded frames from segment
tables, the decoded error against the input, and the fit's input paths
(callers: ``decode.py``, ``encode.py``)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mwbx.host_jit import host_jit


# -- evaluation -----------------------------------------------------------------------


class OutputRows(NamedTuple):
  """Where channel c's decoded frames go: world ``c // n_per_world``, columns
  from ``columns[c % n_per_world]``; frames ``lo[w]:hi[w]`` of world w to rows
  from ``row_off[w]``; only channels ``wanted`` (bool[C]) are written."""

  n_per_world: int
  columns: np.ndarray
  wanted: np.ndarray
  lo: np.ndarray
  hi: np.ndarray
  row_off: np.ndarray


@host_jit
def _channel_rows(c, rows):
  """(first column, frame range lo:hi, row of frame 0) of channel c's output."""
  w = c // rows.n_per_world
  return rows.columns[c % rows.n_per_world], rows.lo[w], rows.hi[w], rows.row_off[w] - rows.lo[w]


@host_jit
def eval_linear(out, initial, segments, step, quad, rows):
  """Write decoded linear channels (translations when ``quad`` != 0) into ``out``.

  Channel c (world ``c // n_per_world``, columns ``columns[c % n_per_world] + d``)
  starts at ``initial[c]`` and moves ``vel * step`` per frame within each of its
  segments, plus ``quad * tau**2`` on its last coordinate in flagged segments;
  segment k covers frames (start, start + L], frame 0 belongs to the first.
  Frames ``lo[w]:hi[w]`` of world w go to rows ``row_off[w]...``. Segment starts
  accumulate in float64; each frame is evaluated in float32 (the encoder
  measures the error of exactly this output).

  out: f32[rows, nq]; initial: f64[C, 4]; segments: :class:`mwbx.codec.stream.Segments`
  (arrays contiguous, i64 and bool);
  step, quad: the kind's quanta; rows: :class:`OutputRows`.
  """
  seg_count, lengths, vel, flags, wanted = segments.seg_count, segments.lengths, segments.vel, segments.flags, rows.wanted
  dim = vel.shape[1]
  rate = np.empty(dim)
  p = np.empty(dim)
  s = 0
  for c in range(seg_count.size):
    n_seg = seg_count[c]
    col, f_lo, f_hi, row0 = _channel_rows(c, rows)
    if not wanted[c] or f_lo >= f_hi:
      s += n_seg
      continue
    if n_seg == 0:
      for f in range(f_lo, f_hi):
        for d in range(dim):
          out[row0 + f, col + d] = np.float32(initial[c, d])
      continue
    for d in range(dim):
      p[d] = initial[c, d]
    start = 0
    for j in range(s, s + n_seg):
      length = lengths[j]
      for d in range(dim):
        rate[d] = vel[j, d] * step
      first = start + 1 if j > s else 0
      last = min(start + length, f_hi - 1)
      gravity = np.float32(quad) if flags[j] else np.float32(0.0)
      for f in range(max(first, f_lo), last + 1):
        tau = np.float32(f - start)
        for d in range(dim):
          out[row0 + f, col + d] = np.float32(p[d]) + tau * np.float32(rate[d])
        if quad != 0.0:
          out[row0 + f, col + dim - 1] += gravity * tau * tau
      lf = np.float64(length)
      for d in range(dim):
        p[d] += lf * rate[d]
      if quad != 0.0 and flags[j]:
        p[dim - 1] += quad * lf * lf
      start += length
      if start >= f_hi:
        break
    s += n_seg


@host_jit
def _quat_mul(a, b, out):
  out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
  out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
  out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
  out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@host_jit
def eval_rotation(out, initial, segments, step, rows):
  """Write decoded rotation channels (unit quaternions w, x, y, z) into ``out``.

  Within a segment of integer rotation velocity ``w = vel * step`` (radians per
  frame about a fixed axis), frame ``start + tau`` is ``exp(tau w) (x) q_s =
  cos(a) q_s + sin(a) (0, axis) (x) q_s`` with ``a = tau |w| / 2`` and ``q_s``
  the segment's start: the channel's normalized frame-0 value, then each
  segment's end. Everything is float64 (cos(a), sin(a) advance frame by frame by
  angle addition) and rounded to float32 on output. Arguments as
  ``eval_linear`` (vel: i64[S, 3]; flags unused).
  """
  seg_count, lengths, vel, wanted = segments.seg_count, segments.lengths, segments.vel, rows.wanted
  q = np.empty(4)
  turned = np.empty(4)
  pure = np.zeros(4)
  s = 0
  for c in range(seg_count.size):
    n_seg = seg_count[c]
    col, f_lo, f_hi, row0 = _channel_rows(c, rows)
    if not wanted[c] or f_lo >= f_hi:
      s += n_seg
      continue
    norm = math.sqrt(initial[c, 0]**2 + initial[c, 1]**2 + initial[c, 2]**2 + initial[c, 3]**2)
    for i in range(4):
      q[i] = initial[c, i] / norm if norm > 0 else initial[c, i]
    if n_seg == 0:
      for f in range(f_lo, f_hi):
        for i in range(4):
          out[row0 + f, col + i] = np.float32(q[i])
      continue
    start = 0
    for j in range(s, s + n_seg):
      length = lengths[j]
      wx, wy, wz = vel[j, 0] * step, vel[j, 1] * step, vel[j, 2] * step
      rate = math.sqrt(wx * wx + wy * wy + wz * wz)
      if rate > 0:
        pure[1], pure[2], pure[3] = wx / rate, wy / rate, wz / rate
      else:
        pure[1] = pure[2] = pure[3] = 0.0
      _quat_mul(pure, q, turned)
      half = 0.5 * rate
      first = max(start + 1 if j > s else 0, f_lo)
      last = min(start + length, f_hi - 1)
      if first <= last:
        step_cos, step_sin = math.cos(half), math.sin(half)
        tau = first - start
        if tau == 0:
          cos_a, sin_a = 1.0, 0.0
        elif tau == 1:
          cos_a, sin_a = step_cos, step_sin
        else:
          cos_a, sin_a = math.cos(half * tau), math.sin(half * tau)
        for f in range(first, last + 1):
          for i in range(4):
            out[row0 + f, col + i] = np.float32(cos_a * q[i] + sin_a * turned[i])
          cos_a, sin_a = (cos_a * step_cos - sin_a * step_sin,
                          sin_a * step_cos + cos_a * step_sin)
      # The next segment starts at exp(L w) (x) q.
      cos_end, sin_end = math.cos(half * length), math.sin(half * length)
      for i in range(4):
        q[i] = cos_end * q[i] + sin_end * turned[i]
      start += length
      if start >= f_hi:
        break
    s += n_seg


NOT_CHECKED = -2  # a kind for max_errors: the channel is skipped


@host_jit
def max_errors(decoded, row_off, qpos, frame_count, kinds, columns):
  """Largest error per world and channel of decoded frames against the originals.

  decoded: f32[rows, nq] (world w's frames at rows ``row_off[w]...``); qpos:
  f32[W, T, nq]; kinds: i64[C] (0 translation, 1 rotation, 2 scalar,
  ``NOT_CHECKED``: left at 0); columns:
  i64[C] first qpos address. Translation and scalars: largest absolute
  difference of a coordinate; rotation: the angle between the two orientations
  (radians). NaN in both is exact, NaN in one is an infinite error. f64[W, C].
  """
  n_w = frame_count.size
  n_ch = kinds.size
  err = np.zeros((n_w, n_ch))
  for w in range(n_w):
    for f in range(frame_count[w]):
      row = row_off[w] + f
      for c in range(n_ch):
        col = columns[c]
        if kinds[c] == NOT_CHECKED:
          continue
        if kinds[c] == 1:
          d0, d1, d2, d3 = (np.float64(decoded[row, col]), np.float64(decoded[row, col + 1]),
                            np.float64(decoded[row, col + 2]), np.float64(decoded[row, col + 3]))
          x0, x1, x2, x3 = (np.float64(qpos[w, f, col]), np.float64(qpos[w, f, col + 1]),
                            np.float64(qpos[w, f, col + 2]), np.float64(qpos[w, f, col + 3]))
          nan_d = math.isnan(d0 + d1 + d2 + d3)
          nan_x = math.isnan(x0 + x1 + x2 + x3)
          if nan_d and nan_x:
            continue
          norm = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2 + x3 * x3)
          if norm > 0:
            x0, x1, x2, x3 = x0 / norm, x1 / norm, x2 / norm, x3 / norm
          # conj(d) (x) x
          r0 = d0 * x0 + d1 * x1 + d2 * x2 + d3 * x3
          r1 = d0 * x1 - d1 * x0 - d2 * x3 + d3 * x2
          r2 = d0 * x2 + d1 * x3 - d2 * x0 - d3 * x1
          r3 = d0 * x3 - d1 * x2 + d2 * x1 - d3 * x0
          e = 2.0 * math.atan2(math.sqrt(r1 * r1 + r2 * r2 + r3 * r3), abs(r0))
          if math.isnan(e):
            e = np.inf
          if e > err[w, c]:
            err[w, c] = e
        else:
          width = 3 if kinds[c] == 0 else 1
          for d in range(width):
            a = np.float64(decoded[row, col + d])
            b = np.float64(qpos[w, f, col + d])
            if math.isnan(a) and math.isnan(b):
              continue
            e = abs(a - b)
            if math.isnan(e):
              e = np.inf
            if e > err[w, c]:
              err[w, c] = e
  return err


# -- fit input ------------------------------------------------------------------------


@host_jit
def finite_paths(qpos, frame_count, columns, width):
  """bool[W, C]: channel c of world w (qpos columns ``columns[c] + 0..width-1``) is
  finite over its ``frame_count[w]`` recorded frames. qpos: f32[W, T, nq]."""
  n_w, n_ch = frame_count.size, columns.size
  out = np.ones((n_w, n_ch), np.bool_)
  for w in range(n_w):
    for f in range(frame_count[w]):
      for c in range(n_ch):
        for d in range(width):
          if not math.isfinite(qpos[w, f, columns[c] + d]):
            out[w, c] = False
  return out


@host_jit
def constant_paths(qpos, frame_count, columns, width):
  """bool[W, C]: channel c of world w holds its frame-0 value (bitwise) on
  every one of its ``frame_count[w]`` frames, two or more (a body asleep or
  at rest throughout). qpos: f32[W, T, nq]."""
  n_w, n_ch = frame_count.size, columns.size
  out = np.zeros((n_w, n_ch), np.bool_)
  for w in range(n_w):
    if frame_count[w] < 2:
      continue
    for c in range(n_ch):
      same = True
      for f in range(1, frame_count[w]):
        for d in range(width):
          if qpos[w, f, columns[c] + d] != qpos[w, 0, columns[c] + d]:
            same = False
            break
        if not same:
          break
      out[w, c] = same
  return out


@host_jit
def gather_paths(qpos, rows, n_ch, columns, initial, relative, finite, out):
  """Fill ``out: f32[m, T', width]`` with paths ``rows`` (path p: world p // n_ch,
  channel p % n_ch at qpos columns ``columns[p % n_ch] + d``), frames 0..T'-1.

  relative: subtract the path's ``initial: f64[P, width]`` (in float64, then
  rounded), else frame 0 becomes ``initial``. Paths that are not ``finite`` are
  left zero (their channels are stored raw).
  """
  m, t, width = out.shape
  for i in range(m):
    p = rows[i]
    if not finite[p]:
      continue
    w, col = p // n_ch, columns[p % n_ch]
    for f in range(t):
      for d in range(width):
        x = np.float64(qpos[w, f, col + d])
        out[i, f, d] = np.float32(x - initial[p, d]) if relative else np.float32(x)
    if not relative:
      for d in range(width):
        out[i, 0, d] = np.float32(initial[p, d])


