"""Bit-exact decoder: stream -> ``qpos`` frames, vectorized with numpy.

Segment starts come from (segmented) cumulative sums over segments, rotation
keyframes from a parallel prefix product of quaternions; every frame is then
evaluated independently, so decoding a time range only touches those frames.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec.layout import CodecError
from mwbx.codec.stream import KINDS, MODE_FIT, WIDTH, WorldCode, channel_starts, parse

KIND_ID = {"pos": 0, "rot": 1, "scalar": 2}


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """Hamilton product of (w, x, y, z) quaternions, [..., 4]."""
  aw, ax, ay, az = np.moveaxis(a, -1, 0)
  bw, bx, by, bz = np.moveaxis(b, -1, 0)
  return np.stack([
      aw * bw - ax * bx - ay * by - az * bz,
      aw * bx + ax * bw + ay * bz - az * by,
      aw * by - ax * bz + ay * bw + az * bx,
      aw * bz + ax * by - ay * bx + az * bw,
  ], axis=-1)


def quat_exp(omega: np.ndarray) -> np.ndarray:
  """Unit quaternion of rotation vectors ``omega: [..., 3]`` (radians)."""
  theta = np.linalg.norm(omega, axis=-1, keepdims=True)
  with np.errstate(invalid="ignore", divide="ignore"):
    factor = np.where(theta > 1e-12, np.sin(0.5 * theta) / theta, 0.5)
  return np.concatenate([np.cos(0.5 * theta), factor * omega], axis=-1)


def normalize(q: np.ndarray) -> np.ndarray:
  norm = np.linalg.norm(q, axis=-1, keepdims=True)
  with np.errstate(invalid="ignore", divide="ignore"):
    return np.where(norm > 0, q / norm, q)


def _segment_index(lengths: np.ndarray, seg_count: np.ndarray, n_frames: int,
                   frames: np.ndarray):
  """For every (channel, frame): its segment and the frames since that segment began.

  Returns (k: i64[C, F], tau: f64[C, F], first: bool[S], channel start of each segment).
  """
  first = channel_starts(seg_count)
  chan = np.repeat(np.arange(seg_count.size), seg_count)
  chan_start = np.maximum.accumulate(np.where(first, np.arange(first.size), 0))
  total = np.cumsum(lengths)
  end_local = total - (total - lengths)[chan_start]
  start_local = end_local - lengths
  # Segment k covers frames (start, end]; frame 0 belongs to a channel's first segment.
  key = end_local + chan * n_frames
  query = frames[None, :] + np.arange(seg_count.size)[:, None] * n_frames
  k = np.searchsorted(key, query, side="left")
  tau = (frames[None, :] - start_local[k]).astype(np.float64)
  return k, tau, first, chan_start


def _decode_linear(initial, lengths, seg_count, vel, step, n_frames, frames, flags=None,
                   quad=0.0) -> np.ndarray:
  """f64[C, F, D] for linear channels (translation when ``flags`` is given)."""
  k, tau, first, chan_start = _segment_index(lengths, seg_count, n_frames, frames)
  chan = np.repeat(np.arange(seg_count.size), seg_count)
  rate = vel.astype(np.float64) * step
  lf = lengths.astype(np.float64)
  disp = lf[:, None] * rate
  if flags is not None:
    disp[:, -1] += np.where(flags, quad * lf * lf, 0.0)
  excl = np.cumsum(disp, axis=0) - disp
  p_start = initial[chan] + excl - excl[chan_start]
  out = p_start[k] + tau[:, :, None] * rate[k]
  if flags is not None:
    out[:, :, -1] += np.where(flags[k], quad, 0.0) * tau * tau
  return out


def _prefix_product(delta: np.ndarray) -> np.ndarray:
  """Inclusive prefix product along axis 1, later factors on the left; [C, K, 4]."""
  out = delta.copy()
  d = 1
  while d < out.shape[1]:
    out[:, d:] = quat_mul(out[:, d:], out[:, :-d])
    d *= 2
  return out


def _decode_rotation(initial, lengths, seg_count, vel, step, n_frames, frames) -> np.ndarray:
  """f64[C, F, 4] unit quaternions for rotation channels."""
  k, tau, first, chan_start = _segment_index(lengths, seg_count, n_frames, frames)
  n_ch = seg_count.size
  rate_vec = vel.astype(np.float64) * step
  rate = np.linalg.norm(rate_vec, axis=-1)
  delta = quat_exp(lengths[:, None] * rate_vec)
  # Keyframe j of a channel: delta_j (x) ... (x) delta_0 (x) q0; pad channels to K.
  k_max = int(seg_count.max())
  local = np.arange(first.size) - chan_start
  chan = np.repeat(np.arange(n_ch), seg_count)
  padded = np.zeros((n_ch, k_max + 1, 4))
  padded[:, :, 0] = 1.0
  padded[chan, local + 1] = delta
  q0 = normalize(initial)
  keys = quat_mul(_prefix_product(padded), q0[:, None, :])
  q_start = keys[chan, local]
  with np.errstate(invalid="ignore", divide="ignore"):
    axis = np.where(rate[:, None] > 0, rate_vec / np.where(rate > 0, rate, 1.0)[:, None], 0.0)
  # exp(tau * w) (x) q_s = cos(a) q_s + sin(a) (0, axis) (x) q_s with a = tau |w| / 2.
  pure = np.concatenate([np.zeros((axis.shape[0], 1)), axis], axis=-1)
  turned = quat_mul(pure, q_start)
  half = 0.5 * tau * rate[k]
  return np.cos(half)[:, :, None] * q_start[k] + np.sin(half)[:, :, None] * turned[k]


def decode_code(code: WorldCode, start: int = 0, stop: int | None = None) -> np.ndarray:
  """Frames ``start:stop`` (slice semantics) of a parsed stream; f32[n, nq]."""
  frames = np.arange(code.n_frames, dtype=np.int64)[start:stop]
  out = np.zeros((frames.size, code.layout.nq), np.float32)
  if frames.size == 0:
    return out
  kinds = code.kinds()
  adrs = np.array(code.addresses(), np.int64)
  kind_arr = np.array([KIND_ID[k] for k in kinds], np.int64)
  fit = np.asarray(code.modes) == MODE_FIT
  steps = dict(zip(KINDS, code.quanta.steps(code.bounds)))
  for kind in KINDS:
    width = WIDTH[kind]
    sel = fit & (kind_arr == KIND_ID[kind])
    if not np.any(sel):
      continue
    seg = code.segs[kind]
    initial = code.initial[sel, :width].astype(np.float64)
    if code.n_frames <= 1:
      values = np.broadcast_to(initial[:, None, :], (initial.shape[0], frames.size, width))
      if kind == "rot":
        values = normalize(values)
    elif kind == "rot":
      values = _decode_rotation(initial, seg.lengths, seg.seg_count, seg.vel, steps[kind],
                                code.n_frames, frames)
    else:
      values = _decode_linear(initial, seg.lengths, seg.seg_count, seg.vel, steps[kind],
                              code.n_frames, frames,
                              flags=seg.flags if kind == "pos" else None, quad=code.quanta.quad)
    cols = (adrs[sel][:, None] + np.arange(width)[None, :]).reshape(-1)
    out[:, cols] = values.transpose(1, 0, 2).reshape(frames.size, -1)
  for c, data in code.raw.items():
    width = data.shape[1]
    values = data[frames].astype(np.float64)
    if kinds[c] == "rot":
      values = normalize(values)
    out[:, adrs[c]:adrs[c] + width] = values
  return out


def decode_world(stream: bytes | np.ndarray, start: int = 0, stop: int | None = None) -> np.ndarray:
  """Decode frames ``start:stop`` of one world's stream; f32[n, nq].

  Raises CodecError on a corrupt or truncated stream.
  """
  try:
    code = parse(stream)
    with np.errstate(over="ignore", invalid="ignore"):
      return decode_code(code, start, stop)
  except CodecError:
    raise
  except (ArithmeticError, IndexError, ValueError, TypeError, MemoryError) as err:
    # Defensive: the parser validates what it reads; never let a raw crash out.
    raise CodecError(f"corrupt stream: {type(err).__name__}: {err}") from None
