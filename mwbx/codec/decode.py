"""Bit-exact decoder: stream -> ``qpos`` frames.

Evaluation is a compiled loop per channel (``eval_kernels.eval_linear`` /
``eval_kernels.eval_rotation``): segment starts accumulate in float64, every frame is
evaluated in float32 from its segment's start, so decoding a time range touches
only those frames, and decoding a subset of channels skips the others.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec import eval_kernels
from mwbx.codec.layout import CodecError
from mwbx.codec.stream import KINDS, MODE_FIT, Segments, WorldCode, parse

KIND_ID = {"pos": 0, "rot": 1, "scalar": 2}


def normalize(q: np.ndarray) -> np.ndarray:
  norm = np.linalg.norm(q, axis=-1, keepdims=True)
  with np.errstate(invalid="ignore", divide="ignore"):
    return np.where(norm > 0, q / norm, q)


def frame_ranges(n_frames: np.ndarray, start: int | None, stop: int | None):
  """Per world the frames ``start:stop`` (slice semantics) of its ``n_frames``.

  Returns (lo i64[W], hi i64[W], row offsets i64[W + 1]): world w's frames
  lo..hi-1 become output rows ``off[w]:off[w + 1]``.
  """
  n_frames = np.asarray(n_frames, np.int64).reshape(-1)
  lo = np.zeros(n_frames.size, np.int64)
  hi = np.zeros(n_frames.size, np.int64)
  window = slice(start, stop)
  for w, n in enumerate(n_frames.tolist()):
    lo[w], hi[w], _ = window.indices(n)
  hi = np.maximum(hi, lo)
  return lo, hi, np.concatenate([[0], np.cumsum(hi - lo)])


def evaluate(n_frames, initial, segs, channel_kind, addresses, nq, quanta, bounds, start=0,
             stop=None, channels=None):
  """Decoded frames of W worlds that share a layout.

  n_frames: i64[W]; initial: f64[W, C, 4]; segs: kind -> Segments over the W *
  C_kind fitted channels of that kind (world-major); channel_kind: i64[C] kind id
  per channel, -1 for channels not evaluated here (raw); channels: optional
  bool[C], only these channels are written (the others stay zero). Returns
  (f32[rows, nq], row offsets i64[W + 1]): world w's frames ``start:stop`` are
  rows ``off[w]:off[w + 1]``.
  """
  steps = dict(zip(KINDS, quanta.steps(bounds)))
  n_frames = np.asarray(n_frames, np.int64).reshape(-1)
  n_w = n_frames.size
  lo, hi, row_off = frame_ranges(n_frames, start, stop)
  channel_kind = np.asarray(channel_kind)
  # A layout covers every qpos column once, so a full decode writes every entry.
  full = channels is None and bool(np.all(channel_kind >= 0))
  out = (np.empty if full else np.zeros)((int(row_off[-1]), nq), np.float32)
  addresses = np.asarray(addresses, np.int64)
  wanted_channels = (np.ones(channel_kind.size, bool) if channels is None
                     else np.asarray(channels, bool))
  for kind in KINDS:
    sel = np.flatnonzero(channel_kind == KIND_ID[kind])
    if sel.size == 0 or not wanted_channels[sel].any():
      continue
    seg = segs[kind]
    init = np.ascontiguousarray(initial[:, sel, :].reshape(-1, 4), np.float64)
    wanted = np.tile(wanted_channels[sel], n_w)
    columns = np.ascontiguousarray(addresses[sel])
    segments = Segments(
        np.ascontiguousarray(seg.seg_count, np.int64), np.ascontiguousarray(seg.lengths, np.int64),
        np.ascontiguousarray(seg.vel, np.int64), np.ascontiguousarray(seg.flags, np.bool_))
    rows = eval_kernels.OutputRows(int(sel.size), columns, wanted, lo, hi, row_off)
    if kind == "rot":
      eval_kernels.eval_rotation(out, init, segments, float(steps[kind]), rows)
    else:
      quad = float(quanta.quad) if kind == "pos" else 0.0
      eval_kernels.eval_linear(out, init, segments, float(steps[kind]), quad, rows)
  return out, row_off


def decode_code(code: WorldCode, start: int = 0, stop: int | None = None,
                channels=None) -> np.ndarray:
  """Frames ``start:stop`` (slice semantics) of a parsed stream; f32[n, nq]."""
  kinds = code.kinds()
  fit = np.asarray(code.modes) == MODE_FIT
  kind_id = np.array([KIND_ID[k] for k in kinds], np.int64)
  # Raw channels take no part in the fitted evaluation.
  kind_fit = np.where(fit, kind_id, -1)
  out, _ = evaluate(np.array([code.n_frames]), code.initial[None], code.segs, kind_fit,
                    code.addresses(), code.layout.nq, code.quanta, code.bounds, start, stop,
                    channels)
  frames = np.arange(code.n_frames, dtype=np.int64)[start:stop]
  adrs = code.addresses()
  for c, data in code.raw.items():
    if channels is not None and not channels[c]:
      continue
    width = data.shape[1]
    values = data[frames].astype(np.float64)
    if kinds[c] == "rot":
      values = normalize(values)
    out[:, adrs[c]:adrs[c] + width] = values
  return out


def decode_world(stream: bytes | np.ndarray, start: int = 0, stop: int | None = None,
                 channels=None) -> np.ndarray:
  """Decode frames ``start:stop`` of one world's stream; f32[n, nq].

  channels: optional bool[C] over the stream's channels (translations, then
  rotations, then scalars, each in layout order); the columns of the others
  stay zero. Raises CodecError on a corrupt or truncated stream.
  """
  try:
    code = parse(stream)
    if channels is not None:
      channels = np.asarray(channels, bool).reshape(-1)
      if channels.size != code.layout.n_channels:
        raise CodecError(f"channels has {channels.size} entries, the stream "
                         f"{code.layout.n_channels} channels")
    with np.errstate(over="ignore", invalid="ignore"):
      return decode_code(code, start, stop, channels)
  except CodecError:
    raise
  except (ArithmeticError, IndexError, ValueError, TypeError, MemoryError) as err:
    # Defensive: the parser validates what it reads; never let a raw crash out.
    raise CodecError(f"corrupt stream: {type(err).__name__}: {err}") from None
