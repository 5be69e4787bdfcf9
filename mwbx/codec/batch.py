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

from mwbx.codec import rice
from mwbx.codec.decode import KIND_ID, decode_world, evaluate
from mwbx.codec.layout import ChannelLayout, CodecBounds, CodecError
from mwbx.codec.stream import (_FLOATS, _HEAD, DIM, KINDS, MAGIC, VERSION, Quanta,
                               Segments, _velocities, channel_starts,
                               gravity_increment, initial_bytes, initial_codes, lattice_exponent, parse,
                               read_initial, segment_codes)


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
  out += _FLOATS.pack(fps, bounds.e_pos, bounds.e_rot, bounds.e_scalar, quanta.quad)
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
  modes = bytes(n_ch)
  kinds = [k for k in KINDS for _ in cols[k]]
  init_codes = initial_codes(bc.initial, kinds, bc.bounds).tolist()
  head = _HEAD.pack(MAGIC, VERSION)
  out = []
  for w in range(n_w):
    body = b"".join((head, rice.write_varint(int(bc.n_frames[w])), sig, modes,
                     initial_bytes(init_codes[w]), blobs[w]))
    out.append(body + struct.pack("<I", zlib.crc32(body)))
  return out


class _Fallback(Exception):
  """The batch path does not cover these streams; decode world by world."""


def parse_batch(data: np.ndarray, offsets: np.ndarray) -> BatchCode:
  """Parse the streams ``data[offsets[w]:offsets[w + 1]]`` of W worlds together.

  Raises _Fallback if they differ in layout or hold raw channels, CodecError if
  they are inconsistent.
  """
  data = np.ascontiguousarray(data, np.uint8)
  view = memoryview(data)
  n_w = offsets.size - 1
  first = parse(view[offsets[0]:offsets[1]])
  lay = first.layout
  if np.any(first.modes != 0):
    raise _Fallback()
  sig = _signature(lay, first.bounds, first.fps, first.quanta)
  n_ch = lay.n_channels
  kinds = first.kinds()
  n_frames = np.zeros(n_w, np.int64)
  initial = np.zeros((n_w, n_ch, 4))
  blob_start = np.zeros(n_w, np.int64)
  blob_end = np.zeros(n_w, np.int64)
  head = _HEAD.pack(MAGIC, VERSION)
  modes = bytes(n_ch)
  for w in range(n_w):
    lo, hi = int(offsets[w]), int(offsets[w + 1])
    if hi - lo < len(head) + 4 or view[lo:lo + len(head)] != head:
      raise _Fallback()
    (crc,) = struct.unpack_from("<I", view, hi - 4)
    if zlib.crc32(view[lo:hi - 4]) != crc:
      raise _Fallback()
    n, pos = rice.read_varint(view, lo + len(head), "n_frames")
    end = pos + len(sig)
    if view[pos:end] != sig or view[end:end + n_ch] != modes:
      raise _Fallback()
    n_frames[w] = n
    initial[w], blob_start[w] = read_initial(view, end + n_ch, kinds, first.bounds)
    blob_end[w] = hi - 4
  if np.any(blob_start > blob_end) or np.any(n_frames > (1 << 24)):
    raise _Fallback()
  expect = np.maximum(n_frames - 1, 0)
  values, counts = rice.decode_ints_batch(data, blob_start, blob_end, n_ch + 7 * expect * n_ch)
  starts = np.cumsum(counts) - counts
  if np.any(counts < n_ch):
    raise CodecError("corrupt stream: missing segment counts")
  seg_counts = values[starts[:, None] + np.arange(n_ch)[None, :]]
  if (np.any(seg_counts < 0) or np.any(seg_counts > expect[:, None])
      or np.any((seg_counts == 0) & (expect[:, None] > 0))):
    raise CodecError("corrupt stream: segment count out of range")
  cols = _kind_columns(lay)
  n_seg = {k: seg_counts[:, cols[k]].sum(axis=1) for k in KINDS}
  total = sum(n_seg.values())
  n_res = sum(DIM[k] * n_seg[k] for k in KINDS)
  if np.any(counts != n_ch + total + n_res):
    raise CodecError("corrupt stream: segment data size does not match segment counts")

  def gather(offset, sizes):
    world = np.repeat(np.arange(n_w), sizes)
    local = np.arange(int(sizes.sum())) - (np.cumsum(sizes) - sizes)[world]
    return values[offset[world] + local]

  q = first.quanta
  ratio = 2.0 * q.quad / q.steps(first.bounds)[0] * 256.0
  if not abs(ratio) < 2.0**40:
    raise CodecError("corrupt stream header: gravity term out of range")
  g_fp, coarse = q.g_fp(first.bounds), q.coarse()
  l_off = starts + n_ch
  r_off = starts + n_ch + total
  segs = {}
  for kind in KINDS:
    codes = gather(l_off, n_seg[kind])
    l_off = l_off + n_seg[kind]
    flat = gather(r_off, DIM[kind] * n_seg[kind])  # per world: coordinate-major
    world = np.repeat(np.arange(n_w), DIM[kind] * n_seg[kind])
    local = np.arange(flat.size) - (np.cumsum(DIM[kind] * n_seg[kind]) - DIM[kind] * n_seg[kind])[world]
    per = np.maximum(n_seg[kind][world], 1)
    res = np.zeros((int(n_seg[kind].sum()), DIM[kind]), np.int64)
    res[(np.cumsum(n_seg[kind]) - n_seg[kind])[world] + local % per, local // per] = flat
    r_off = r_off + DIM[kind] * n_seg[kind]
    if kind == "pos":
      lengths, flags = (codes >> 1) + 1, (codes & 1).astype(bool)
    else:
      lengths, flags = codes + 1, np.zeros(codes.size, bool)
    seg_count = seg_counts[:, cols[kind]].reshape(-1)
    if np.any(lengths < 1):
      raise CodecError("corrupt stream: segment length out of range")
    first_seg = channel_starts(seg_count)
    if lengths.size:
      per_channel = np.add.reduceat(lengths, np.flatnonzero(first_seg))
      chan_world = np.repeat(np.arange(n_w), cols[kind].size)[seg_count > 0]
      if np.any(per_channel != expect[chan_world]):
        raise CodecError("corrupt stream: segment lengths do not add up to the frame count")
    inc = gravity_increment(flags, lengths, first_seg, g_fp) if kind == "pos" else None
    m = lattice_exponent(lengths, coarse[kind])
    vel = _velocities(res, first_seg, inc, m) if lengths.size else res
    if np.any(np.abs(vel) >= rice.VALUE_CAP):
      raise CodecError("corrupt stream: velocity out of range")
    segs[kind] = Segments(seg_count, lengths, vel, flags)
  return BatchCode(n_frames=n_frames, layout=lay, bounds=first.bounds, fps=first.fps,
                   quanta=q, initial=initial, segs=segs)


def _batchable(data: np.ndarray, offsets: np.ndarray) -> np.ndarray:
  """Worlds whose header matches the first all-fitted stream (cheap byte checks)."""
  view = memoryview(data)
  n_w = offsets.size - 1
  ref = None
  for w in range(n_w):
    try:
      code = parse(view[offsets[w]:offsets[w + 1]])
    except CodecError:
      continue
    if not np.any(code.modes):
      ref = code
      break
  if ref is None:
    return np.zeros(0, np.int64)
  sig = _signature(ref.layout, ref.bounds, ref.fps, ref.quanta) + bytes(ref.layout.n_channels)
  head = _HEAD.pack(MAGIC, VERSION)
  keep = []
  for w in range(n_w):
    lo, hi = int(offsets[w]), int(offsets[w + 1])
    if hi - lo < len(head) + len(sig) + 5 or view[lo:lo + len(head)] != head:
      continue
    try:
      _, pos = rice.read_varint(view, lo + len(head), "n_frames")
    except CodecError:
      continue
    if view[pos:pos + len(sig)] == sig:
      keep.append(w)
  return np.asarray(keep, np.int64)


def decode_batch(data: np.ndarray, offsets: np.ndarray, start: int = 0,
                 stop: int | None = None) -> list[np.ndarray]:
  """Frames ``start:stop`` of every stream ``data[offsets[w]:offsets[w + 1]]``.

  Returns one f32[n, nq] array per world. Worlds sharing a layout with all
  channels fitted are decoded in one vectorized pass; the others (raw channels,
  another layout, corruption) one by one, and a corrupt stream raises
  CodecError naming its world.
  """
  offsets = np.asarray(offsets, np.int64)
  data = np.ascontiguousarray(data, np.uint8)
  n_w = offsets.size - 1
  if n_w <= 0:
    return []
  result = [None] * n_w
  fast = _batchable(data, offsets)
  if fast.size:
    if fast.size == n_w:
      sub_data, sub_off = data, offsets
    else:
      lo, hi = offsets[fast], offsets[fast + 1]
      sub_data = np.concatenate([data[a:b] for a, b in zip(lo, hi)])
      sub_off = np.concatenate([[0], np.cumsum(hi - lo)])
    try:
      bc = parse_batch(sub_data, sub_off)
      out, row_off = evaluate(bc.n_frames, bc.initial, bc.segs, bc.channel_kinds(),
                              bc.addresses(), bc.layout.nq, bc.quanta, bc.bounds, start, stop)
      for i, w in enumerate(fast):
        result[w] = out[row_off[i]:row_off[i + 1]]
    except (_Fallback, CodecError, ArithmeticError, IndexError, ValueError):
      pass
  for w in range(n_w):
    if result[w] is None:
      try:
        result[w] = decode_world(data[offsets[w]:offsets[w + 1]], start, stop)
      except CodecError as err:
        raise CodecError(f"world {w}: {err}") from None
  return result
