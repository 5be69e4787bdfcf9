"""Many worlds at once: streams written and read with one vectorized pass.

Worlds of one bank share their layout, bounds and quantization, so their
streams differ only in frame count, frame-0 values and the Rice blob. Writing
and reading them together turns per-world numpy calls into per-batch ones; the
bytes are exactly those of ``stream.serialize`` / ``stream.parse`` (tests check
it), and any stream the fast path does not cover (raw channels, another layout,
corruption) goes through the per-world path, which names the problem.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib

import numpy as np

from mwbx.codec import rice, rice_kernels, stream_kernels
from mwbx.codec.decode import KIND_ID, decode_world, evaluate
from mwbx.codec.layout import ChannelLayout, CodecBounds, CodecError
from mwbx.codec.status import STATUS_OK, STATUS_TEXT
from mwbx.codec.stream import (DIM, FLOAT_FIELDS, HEADER, KINDS, MAGIC, VERSION, WIDTH, Quanta,
                               Segments, initial_codes, initial_steps,
                               mode_bytes, parse, segment_codes)


@dataclasses.dataclass
class BatchCode:
  """Segments of W worlds sharing one layout, every channel fitted.

  n_frames: i64[W]; initial: f64[W, C, 4] frame-0 values on their grid (order pos,
  rot, scalar); segs: kind -> Segments over the W * C_kind channels of that kind,
  world-major.
  """

  n_frames: np.ndarray
  layout: ChannelLayout
  bounds: CodecBounds
  fps: float
  quanta: Quanta
  initial: np.ndarray
  segs: dict

  def channel_kinds(self) -> np.ndarray:
    lay = self.layout
    return np.array([KIND_ID["pos"]] * len(lay.pos_adr) + [KIND_ID["rot"]] * len(lay.rot_adr) +
                    [KIND_ID["scalar"]] * len(lay.scalar_adr), np.int64)

  def addresses(self) -> list[int]:
    lay = self.layout
    return list(lay.pos_adr) + list(lay.rot_adr) + list(lay.scalar_adr)


def _signature(layout, bounds, fps, quanta) -> bytes:
  """Header bytes after the frame count up to the channel modes (shared by a bank)."""
  out = bytearray()
  for v in (layout.nq, len(layout.pos_adr), len(layout.rot_adr), len(layout.scalar_adr)):
    out += rice.write_varint(int(v))
  out += FLOAT_FIELDS.pack(fps, bounds.e_pos, bounds.e_rot, bounds.e_scalar, quanta.quad)
  out += bytes([quanta.vel_shift, quanta.rot_shift, quanta.scalar_shift, quanta.lattice_shift])
  for adr in list(layout.pos_adr) + list(layout.rot_adr) + list(layout.scalar_adr):
    out += rice.write_varint(int(adr))
  return bytes(out)


def _kind_columns(layout: ChannelLayout) -> dict[str, np.ndarray]:
  n_pos, n_rot = len(layout.pos_adr), len(layout.rot_adr)
  return {"pos": np.arange(n_pos), "rot": n_pos + np.arange(n_rot),
          "scalar": n_pos + n_rot + np.arange(len(layout.scalar_adr))}


def serialize_batch(bc: BatchCode) -> list[bytes]:
  """One stream per world, identical to ``stream.serialize`` of each."""
  lay, q = bc.layout, bc.quanta
  n_w, n_ch = bc.n_frames.size, lay.n_channels
  g_fp, coarse = q.g_fp(bc.bounds), q.coarse()
  pieces, worlds = [], []
  # Per world: segment counts, then length codes per kind, then residuals per kind.
  counts = np.zeros((n_w, n_ch), np.int64)
  cols = _kind_columns(lay)
  for kind in KINDS:
    counts[:, cols[kind]] = bc.segs[kind].seg_count.reshape(n_w, cols[kind].size)
  pieces.append(counts.reshape(-1))
  worlds.append(np.repeat(np.arange(n_w), n_ch))
  res_pieces, res_worlds = [], []
  for kind in KINDS:
    seg = bc.segs[kind]
    seg_world = np.repeat(np.arange(n_w), counts[:, cols[kind]].sum(axis=1))
    lengths, res = segment_codes(seg, kind, g_fp, coarse)
    pieces.append(lengths)
    worlds.append(seg_world)
    # Coordinate-major; the stable sort by world below keeps that order per world.
    res_pieces.append(res)
    res_worlds.append(np.tile(seg_world, DIM[kind]))
  values = np.concatenate(pieces + res_pieces)
  world = np.concatenate(worlds + res_worlds)
  order = np.argsort(world, kind="stable")
  blobs = rice.encode_ints_batch(values[order], np.bincount(world, minlength=n_w))
  sig = _signature(lay, bc.bounds, bc.fps, q)
  modes = mode_bytes(np.zeros(n_ch, np.uint8))
  kinds = [k for k in KINDS for _ in cols[k]]
  # Zigzag codes are < 2**53, so they fit int64 for the compiled varint writer.
  init_data, init_off = rice_kernels.varint_rows(
      initial_codes(bc.initial, kinds, bc.bounds).astype(np.int64).reshape(n_w, -1))
  init_data = init_data.tobytes()
  head = HEADER.pack(MAGIC, VERSION)
  out = []
  for w in range(n_w):
    body = b"".join((head, rice.write_varint(int(bc.n_frames[w])), sig, modes,
                     init_data[init_off[w]:init_off[w + 1]], blobs[w]))
    out.append(body + struct.pack("<I", zlib.crc32(body)))
  return out


class _Fallback(Exception):
  """The batch path does not cover these streams; decode world by world."""


def _reference(view: memoryview, offsets: np.ndarray):
  """The first stream that parses and has every channel fitted, or None."""
  for w in range(offsets.size - 1):
    try:
      code = parse(view[offsets[w]:offsets[w + 1]])
    except CodecError:
      continue
    if not np.any(code.modes):
      return code
  return None


def parse_batch(data: np.ndarray, offsets: np.ndarray) -> tuple[BatchCode, np.ndarray]:
  """Parse together the streams ``data[offsets[w]:offsets[w + 1]]`` that can be.

  Returns (the BatchCode of the worlds ``fast``, i64 ``fast``): the streams with
  a valid CRC and the header of the first all-fitted stream (same layout,
  bounds, fps and quanta; no raw channel). Raises _Fallback if there is none,
  CodecError if their segment data are inconsistent.
  """
  data = np.ascontiguousarray(data, np.uint8)
  offsets = np.asarray(offsets, np.int64)
  view = memoryview(data)
  ref = _reference(view, offsets)
  if ref is None:
    raise _Fallback()
  lay = ref.layout
  n_ch = lay.n_channels
  kinds = ref.kinds()
  head = np.frombuffer(HEADER.pack(MAGIC, ref.version), np.uint8)
  sig = np.frombuffer(_signature(lay, ref.bounds, ref.fps, ref.quanta)
                      + mode_bytes(np.zeros(n_ch, np.uint8), ref.version), np.uint8)
  widths = np.array([WIDTH[k] for k in kinds], np.int64)
  init_steps = initial_steps(ref.bounds)
  steps = np.array([init_steps[k] for k in kinds], np.float64)
  ok, n_frames, initial, blob_start = stream_kernels.scan_headers(data, offsets, head, sig, widths, steps)
  for w in np.flatnonzero(ok).tolist():
    lo, hi = int(offsets[w]), int(offsets[w + 1])
    ok[w] = zlib.crc32(view[lo:hi - 4]) == struct.unpack_from("<I", view, hi - 4)[0]
  fast = np.flatnonzero(ok)
  if fast.size == 0:
    raise _Fallback()
  n_frames, initial, blob_start = n_frames[fast], initial[fast], blob_start[fast]
  blob_end = offsets[fast + 1] - 4
  if np.any(blob_start > blob_end):
    raise _Fallback()
  expect = np.maximum(n_frames - 1, 0)
  values, counts = rice.decode_ints_batch(data, blob_start, blob_end, n_ch + 7 * expect * n_ch,
                                          ref.version)
  q = ref.quanta
  g_fp, coarse = q.g_fp(ref.bounds), q.coarse()
  n_kind = np.array([len(lay.pos_adr), len(lay.rot_adr), len(lay.scalar_adr)], np.int64)
  status, world, seg_counts, lengths, vels, flags = stream_kernels.segments_from_values(
      values, np.cumsum(counts) - counts, counts, n_kind, expect, int(g_fp),
      np.array([coarse[k] for k in KINDS], np.int64))
  if status != STATUS_OK:
    raise CodecError(f"corrupt stream: {STATUS_TEXT[status]} (world {fast[world]})")
  segs = {kind: Segments(seg_counts[i], lengths[i], vels[i], flags[i])
          for i, kind in enumerate(KINDS)}
  code = BatchCode(n_frames=n_frames, layout=lay, bounds=ref.bounds, fps=ref.fps, quanta=q,
                   initial=initial, segs=segs)
  return code, fast


def decode_batch(data: np.ndarray, offsets: np.ndarray, start: int = 0,
                 stop: int | None = None, channels=None) -> list[np.ndarray]:
  """Frames ``start:stop`` of every stream ``data[offsets[w]:offsets[w + 1]]``.

  Returns one f32[n, nq] array per world. channels: optional bool[C] over the
  layout's channels (translations, rotations, scalars, each in layout order):
  only those are decoded, the other columns stay zero. Worlds sharing a layout
  with all channels fitted are decoded in one pass; the others (raw channels,
  another layout, corruption) one by one, and a corrupt stream raises
  CodecError naming its world.
  """
  offsets = np.asarray(offsets, np.int64)
  data = np.ascontiguousarray(data, np.uint8)
  n_w = offsets.size - 1
  if n_w <= 0:
    return []
  result = [None] * n_w
  try:
    bc, fast = parse_batch(data, offsets)
    if channels is not None and np.size(channels) != bc.layout.n_channels:
      raise CodecError(f"channels has {np.size(channels)} entries, the streams "
                       f"{bc.layout.n_channels} channels")
    out, row_off = evaluate(bc.n_frames, bc.initial, bc.segs, bc.channel_kinds(),
                            bc.addresses(), bc.layout.nq, bc.quanta, bc.bounds, start, stop,
                            channels)
    for i, w in enumerate(fast.tolist()):
      result[w] = out[row_off[i]:row_off[i + 1]]
  except (_Fallback, CodecError, ArithmeticError, IndexError, ValueError):
    pass
  for w in range(n_w):
    if result[w] is None:
      try:
        result[w] = decode_world(data[offsets[w]:offsets[w + 1]], start, stop, channels)
      except CodecError as err:
        raise CodecError(f"world {w}: {err}") from None
  return result
