"""Bit-exact decoder: stream -> ``qpos`` frames, vectorized with numpy.

Segment starts come from (segmented) cumulative sums over segments, rotation
keyframes from a parallel prefix product of quaternions (both float64); every
frame is then evaluated independently in float32, so decoding a time range
only touches those frames.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec.layout import CodecError
from mwbx.codec.stream import KINDS, MODE_FIT, WIDTH, Segments, WorldCode, channel_starts, parse

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


def _locate(seg: Segments, chan_q: np.ndarray, frame_q: np.ndarray):
  """Segment of every query (global channel ``chan_q``, frame ``frame_q``).

  Returns (k: i64[Q] segment, tau: f64[Q] frames since it began, has: bool[Q] the
  channel has segments, chan: i64[S] channel of each segment, chan_start: i64[S]
  first segment of that channel).
  """
  seg_count, lengths = seg.seg_count, seg.lengths
  first = channel_starts(seg_count)
  chan = np.repeat(np.arange(seg_count.size), seg_count)
  chan_start = np.maximum.accumulate(np.where(first, np.arange(first.size), 0))
  total = np.cumsum(lengths)
  end_local = total - (total - lengths)[chan_start]
  has = seg_count[chan_q] > 0
  if lengths.size == 0:
    return np.zeros(chan_q.size, np.int64), np.zeros(chan_q.size), has, chan, chan_start
  # Segment k covers frames (start, end]; frame 0 belongs to a channel's first segment.
  stride = int(max(end_local.max(), frame_q.max(initial=0))) + 1
  k = np.searchsorted(end_local + chan * stride, frame_q + chan_q * stride, side="left")
  k = np.minimum(k, lengths.size - 1)
  tau = (frame_q - (end_local - lengths)[k]).astype(np.float64)
  return k, tau, has, chan, chan_start


def eval_linear(initial: np.ndarray, seg: Segments, step: float, chan_q: np.ndarray,
                frame_q: np.ndarray, quad: float | None = None) -> np.ndarray:
  """f32[Q, D] decoded values of linear channels (translation when ``quad`` is set).

  initial: f64[Cg, D] frame-0 values of the Cg channels ``seg`` describes.
  """
  k, tau, has, chan, chan_start = _locate(seg, chan_q, frame_q)
  if seg.lengths.size == 0:
    return initial[chan_q].copy()
  rate = seg.vel.astype(np.float64) * step
  lf = seg.lengths.astype(np.float64)
  disp = lf[:, None] * rate
  if quad is not None:
    disp[:, -1] += np.where(seg.flags, quad * lf * lf, 0.0)
  excl = np.cumsum(disp, axis=0) - disp
  p_start = initial[chan] + excl - excl[chan_start]
  # Per frame in float32 (the encoder measures the error of exactly this output).
  tau32 = tau.astype(np.float32)
  out = p_start.astype(np.float32)[k] + tau32[:, None] * rate.astype(np.float32)[k]
  if quad is not None:
    out[:, -1] += np.where(seg.flags, np.float32(quad), np.float32(0))[k] * tau32 * tau32
  return np.where(has[:, None], out, initial[chan_q].astype(np.float32))


def _segmented_prefix_product(delta: np.ndarray, chan: np.ndarray) -> np.ndarray:
  """Inclusive prefix product of quaternions within runs of equal ``chan``, later
  factors on the left (Hillis-Steele, log2 of the longest run passes); [S, 4]."""
  out = delta.copy()
  d = 1
  while d < out.shape[0]:
    same = chan[d:] == chan[:-d]
    if not same.any():
      break
    idx = np.flatnonzero(same)
    out[idx + d] = quat_mul(out[idx + d], out[idx])
    d *= 2
  return out


def eval_rotation(initial: np.ndarray, seg: Segments, step: float, chan_q: np.ndarray,
                  frame_q: np.ndarray) -> np.ndarray:
  """f32[Q, 4] decoded unit quaternions; initial: f64[Cg, 4] frame-0 values."""
  q0 = normalize(initial)
  k, tau, has, chan, chan_start = _locate(seg, chan_q, frame_q)
  if seg.lengths.size == 0:
    return q0[chan_q]
  rate_vec = seg.vel.astype(np.float64) * step
  rate = np.linalg.norm(rate_vec, axis=-1)
  # Keyframes: segment j of a channel starts at delta_{j-1} (x) ... (x) delta_0 (x) q0.
  keys = quat_mul(_segmented_prefix_product(quat_exp(seg.lengths[:, None] * rate_vec), chan),
                  q0[chan])
  first = np.zeros(chan.size, bool)
  first[chan_start] = True
  q_start = np.where(first[:, None], q0[chan], np.roll(keys, 1, axis=0))
  with np.errstate(invalid="ignore", divide="ignore"):
    axis = np.where(rate[:, None] > 0, rate_vec / np.where(rate > 0, rate, 1.0)[:, None], 0.0)
  # exp(tau * w) (x) q_s = cos(a) q_s + sin(a) (0, axis) (x) q_s with a = tau |w| / 2;
  # per frame in float32 (the encoder measures the error of exactly this output).
  turned = quat_mul(np.concatenate([np.zeros((axis.shape[0], 1)), axis], axis=-1), q_start)
  half = (0.5 * rate.astype(np.float32))[k] * tau.astype(np.float32)
  out = (np.cos(half)[:, None] * q_start.astype(np.float32)[k]
         + np.sin(half)[:, None] * turned.astype(np.float32)[k])
  return np.where(has[:, None], out, q0[chan_q].astype(np.float32))


def _queries(n_frames: np.ndarray, n_chan: int, start, stop):
  """Per world w (n_frames[w] frames) and each of its n_chan channels, the frames
  ``start:stop``: (chan_q, frame_q, rows: output row of each query, row offsets)."""
  lo = np.array([range(int(n))[start:stop].start for n in n_frames], np.int64)
  hi = np.array([range(int(n))[start:stop].stop for n in n_frames], np.int64)
  count = np.maximum(hi - lo, 0)
  row_off = np.concatenate([[0], np.cumsum(count)])
  world = np.repeat(np.arange(n_frames.size), n_chan)
  per_chan = count[world]
  chan_q = np.repeat(np.arange(world.size), per_chan)
  local = np.arange(chan_q.size) - (np.cumsum(per_chan) - per_chan)[chan_q]
  frame_q = lo[world[chan_q]] + local
  rows = row_off[world[chan_q]] + local
  return chan_q, frame_q, rows, row_off


def evaluate(n_frames, initial, segs, channel_kind, addresses, nq, quanta, bounds, start=0,
             stop=None):
  """Decoded frames of W worlds that share a layout, all channels fitted.

  n_frames: i64[W]; initial: f32[W, C, 4]; segs: kind -> Segments over the
  W * C_kind channels of that kind (world-major). Returns (f32[rows, nq], row
  offsets i64[W + 1]): world w's frames ``start:stop`` are rows
  ``off[w]:off[w + 1]``.
  """
  steps = dict(zip(KINDS, quanta.steps(bounds)))
  out = None
  row_off = None
  channel_kind = np.asarray(channel_kind)
  addresses = np.asarray(addresses, np.int64)
  for kind in KINDS:
    sel = np.flatnonzero(channel_kind == KIND_ID[kind])
    chan_q, frame_q, rows, row_off = _queries(n_frames, sel.size, start, stop)
    if out is None:
      out = np.zeros((int(row_off[-1]), nq), np.float32)
    if sel.size == 0:
      continue
    width = WIDTH[kind]
    init = initial[:, sel, :width].reshape(-1, width).astype(np.float64)
    seg = segs[kind]
    if kind == "rot":
      values = eval_rotation(init, seg, steps[kind], chan_q, frame_q)
    else:
      values = eval_linear(init, seg, steps[kind], chan_q, frame_q,
                           quad=quanta.quad if kind == "pos" else None)
    cols = addresses[sel][chan_q % sel.size][:, None] + np.arange(width)[None, :]
    out[rows[:, None], cols] = values
  if out is None:
    _, _, _, row_off = _queries(n_frames, 0, start, stop)
    out = np.zeros((int(row_off[-1]), nq), np.float32)
  return out, row_off


def decode_code(code: WorldCode, start: int = 0, stop: int | None = None) -> np.ndarray:
  """Frames ``start:stop`` (slice semantics) of a parsed stream; f32[n, nq]."""
  kinds = code.kinds()
  fit = np.asarray(code.modes) == MODE_FIT
  kind_id = np.array([KIND_ID[k] for k in kinds], np.int64)
  # Raw channels take no part in the fitted evaluation.
  kind_fit = np.where(fit, kind_id, -1)
  out, _ = evaluate(np.array([code.n_frames]), code.initial[None], code.segs, kind_fit,
                    code.addresses(), code.layout.nq, code.quanta, code.bounds, start, stop)
  frames = np.arange(code.n_frames, dtype=np.int64)[start:stop]
  adrs = code.addresses()
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
