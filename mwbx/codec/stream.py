"""The per-world byte stream: a self-describing container around the segments.

Layout (little-endian):

  magic b"MWQC" | version u8 | n_frames varint | nq varint | n_pos, n_rot,
  n_scalar varint | fps, e_pos, e_rot, e_scalar, quad f32 | vel_shift,
  rot_shift, scalar_shift, lattice_shift u8 | qpos address per channel varint |
  mode per channel, one bit, packed from the low bit (0 fitted, 1 raw; version
  1: one byte per channel) | frame-0 value of every component as a
  zigzag varint on its grid (``initial_steps``) | raw channels f32[n_frames,
  width] | one Rice blob of integers (``rice.py``): segments per fitted
  channel, then per segment its length code (translation: 2 * (L - 1) +
  vertical-quadratic flag; others: L - 1), then the velocity residuals
  (translation, rotation, scalar) | CRC32 u32 of everything before it.

Version 2 (written) and version 1 (read) differ in how modes are stored and
how the Rice blob codes outliers.

Residual of segment k of a channel: ``r_k`` with ``v_k = v_{k-1} + g_k + r_k *
2**m_k`` (``v_{-1} = 0``), ``g_k`` the gravity increment predicted from the
previous segment's flag and length, ``m_k`` the lattice exponent of its length
(``Quanta``); constant-velocity and ballistic motion code to zeros, and decoding
velocities is a running sum per channel. Channel
order is all translations, then rotations, then scalars, each in layout order.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib
from typing import NamedTuple

import numpy as np

from mwbx.codec import rice, stream_kernels
from mwbx.codec.layout import ChannelLayout, CodecBounds, CodecError
from mwbx.codec.status import STATUS_OK, STATUS_TEXT

MAGIC = b"MWQC"
VERSION = rice.VERSION
VERSIONS = (1, 2)  # read; VERSION is written
MODE_FIT = 0
MODE_RAW = 1
WIDTH = {"pos": 3, "rot": 4, "scalar": 1}
# Sanity caps: corrupt headers must not make the decoder allocate without limit.
MAX_FRAMES = 1 << 24
FLOAT_FIELDS = struct.Struct("<5f")


@dataclasses.dataclass(frozen=True)
class Quanta:
  """Quantization of one stream.

  quad: vertical quadratic coefficient of translation (metres per frame**2).
  vel_shift, rot_shift, scalar_shift: finest velocity step per frame is
    ``bound * 2**-shift`` for each kind.
  lattice_shift: a segment of L frames may only use every ``2**m``-th fine
    step, ``m = max(0, shift - lattice_shift - floor(log2 L))``: its displacement
    quantum stays about ``bound * 2**-lattice_shift``. The default 0 (a quantum
    of about the bound) gave the smallest streams on the shipped scenes with the
    ball-checked rotation fit; 1 gives longer segments with larger residuals.
  """

  quad: float
  vel_shift: int = 6
  rot_shift: int = 6
  scalar_shift: int = 6
  lattice_shift: int = 0

  def steps(self, bounds: CodecBounds) -> tuple[float, float, float]:
    """(translation, rotation, scalar) finest velocity steps per frame, float64.

    Computed from the bounds rounded to float32, as the stream stores them.
    """
    e_pos, e_rot, e_scalar = stored_bounds(bounds)
    return (e_pos * 2.0**-self.vel_shift, e_rot * 2.0**-self.rot_shift,
            e_scalar * 2.0**-self.scalar_shift)

  def coarse(self) -> dict[str, int]:
    """Lattice exponent of a 1-frame segment, per kind."""
    return {"pos": max(0, self.vel_shift - self.lattice_shift),
            "rot": max(0, self.rot_shift - self.lattice_shift),
            "scalar": max(0, self.scalar_shift - self.lattice_shift)}

  def g_fp(self, bounds: CodecBounds) -> int:
    """Vertical velocity gained per ballistic frame, in fine steps * 256."""
    return int(round(2.0 * self.quad / self.steps(bounds)[0] * 256.0))


def stored_bounds(bounds: CodecBounds) -> tuple[float, float, float]:
  """The bounds as a stream stores them (float32)."""
  return tuple(float(np.float32(e)) for e in (bounds.e_pos, bounds.e_rot, bounds.e_scalar))


def initial_steps(bounds: CodecBounds) -> dict[str, float]:
  """Quantum of the frame-0 value of each kind: its error stays below half the bound
  (a quaternion's 4 components each off by step / 2 turn it by about 2 * step)."""
  e_pos, e_rot, e_scalar = stored_bounds(bounds)
  return {"pos": 0.5 * e_pos, "rot": 0.25 * e_rot, "scalar": 0.5 * e_scalar}


def quantize_initial(kind: str, x: np.ndarray, bounds: CodecBounds) -> np.ndarray:
  """i64[..., width] codes of frame-0 values (quaternions normalized first; NaN -> 0)."""
  x = np.asarray(x, np.float64)
  if kind == "rot":
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
      x = np.where(norm > 0, x / norm, 0.0)
  codes = np.round(np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0) / initial_steps(bounds)[kind])
  return np.clip(codes, -2.0**50, 2.0**50).astype(np.int64)


class Segments(NamedTuple):
  """Segments of the fitted channels of one kind, channels in layout order.

  seg_count: i64[Cf] segments per fitted channel.
  lengths: i64[S] segment lengths in frames (>= 1).
  vel: i64[S, D] integer velocities (D = 3, or 1 for scalars).
  flags: bool[S] vertical quadratic term on (translation only, else False).
  """

  seg_count: np.ndarray
  lengths: np.ndarray
  vel: np.ndarray
  flags: np.ndarray


@dataclasses.dataclass
class WorldCode:
  """Everything one stream holds, as arrays.

  initial: f64[C, 4], frame-0 value of each channel (first ``width`` used), on
    its quantization grid (``initial_steps``).
  modes: u8[C] per channel (MODE_FIT or MODE_RAW), channel order pos, rot, scalar.
  raw: dict channel index -> f32[n_frames, width].
  segs: kind -> Segments of that kind's fitted channels.
  version: stream format it was read from (``serialize`` writes ``VERSION``).
  """

  n_frames: int
  layout: ChannelLayout
  bounds: CodecBounds
  fps: float
  quanta: Quanta
  modes: np.ndarray
  initial: np.ndarray
  raw: dict
  segs: dict
  version: int = VERSION

  def kinds(self) -> list[str]:
    lay = self.layout
    return ["pos"] * len(lay.pos_adr) + ["rot"] * len(lay.rot_adr) + ["scalar"] * len(
        lay.scalar_adr)

  def addresses(self) -> list[int]:
    lay = self.layout
    return list(lay.pos_adr) + list(lay.rot_adr) + list(lay.scalar_adr)


KINDS = ("pos", "rot", "scalar")
DIM = {"pos": 3, "rot": 3, "scalar": 1}


def channel_starts(seg_count: np.ndarray) -> np.ndarray:
  """bool[S]: segment k is the first of its channel."""
  total = int(seg_count.sum())
  first = np.zeros(total, bool)
  starts = np.cumsum(seg_count) - seg_count
  first[starts[seg_count > 0]] = True
  return first


def lattice_exponent(lengths: np.ndarray, coarse: int) -> np.ndarray:
  return np.maximum(0, coarse - rice.floor_log2(np.maximum(lengths, 1)))


def gravity_increment(flags: np.ndarray, lengths: np.ndarray, first: np.ndarray,
                      g_fp: int) -> np.ndarray:
  """i64[S]: vertical velocity gained over the previous (ballistic) segment."""
  prev_flag = np.concatenate([[False], flags[:-1]]) & ~first
  prev_len = np.concatenate([[0], lengths[:-1]]).astype(np.int64)
  return np.where(prev_flag, (prev_len * g_fp + 128) >> 8, 0).astype(np.int64)


def segment_codes(seg, kind: str, g_fp, coarse) -> tuple[np.ndarray, np.ndarray]:
  """Length codes and velocity residuals of one kind's segments.

  Returns:
    (i64[n_seg] length codes: ``2·(length-1) + gravity flag`` for positions,
     ``length-1`` otherwise; the residuals component by component, since each
     coordinate's residuals have their own statistics).
  """
  first = channel_starts(seg.seg_count)
  if kind == "pos":
    lengths = 2 * (seg.lengths - 1) + seg.flags
    inc = gravity_increment(seg.flags, seg.lengths, first, g_fp)
  else:
    lengths, inc = seg.lengths - 1, None
  m = lattice_exponent(seg.lengths, coarse[kind])
  return lengths, _residuals(np.asarray(seg.vel, np.int64), first, inc, m).T.reshape(-1)


def _residuals(vel, first, increment, m) -> np.ndarray:
  """r with ``vel = prev + increment + r * 2**m`` (prev = 0 at a channel start)."""
  prev = np.concatenate([np.zeros((1, vel.shape[1]), np.int64), vel[:-1]])
  prev[first] = 0
  diff = vel - prev
  if increment is not None:
    diff[:, -1] -= increment
  r = diff >> m[:, None]
  if np.any((r << m[:, None]) != diff):
    raise CodecError("internal: a fitted velocity is off its lattice")
  return r


HEADER = struct.Struct("<4sB")


def serialize(code: WorldCode, version: int = VERSION) -> bytes:
  """The stream of ``code``; ``version`` 1 writes the old escape format."""
  lay = code.layout
  q = code.quanta
  out = bytearray(HEADER.pack(MAGIC, version))
  for v in (code.n_frames, lay.nq, len(lay.pos_adr), len(lay.rot_adr), len(lay.scalar_adr)):
    out += rice.write_varint(int(v))
  out += FLOAT_FIELDS.pack(code.fps, code.bounds.e_pos, code.bounds.e_rot, code.bounds.e_scalar,
                      q.quad)
  out += bytes([q.vel_shift, q.rot_shift, q.scalar_shift, q.lattice_shift])
  for adr in code.addresses():
    out += rice.write_varint(int(adr))
  out += mode_bytes(code.modes, version)
  kinds = code.kinds()
  out += initial_bytes(initial_codes(code.initial, kinds, code.bounds).tolist())
  for c, kind in enumerate(kinds):
    if code.modes[c] == MODE_RAW:
      out += np.asarray(code.raw[c], "<f4").reshape(code.n_frames, WIDTH[kind]).tobytes()
  g_fp, coarse = q.g_fp(code.bounds), q.coarse()
  counts, length_codes, residuals = [], [], []
  for kind in KINDS:
    seg = code.segs[kind]
    counts.append(seg.seg_count)
    lengths, res = segment_codes(seg, kind, g_fp, coarse)
    length_codes.append(lengths)
    residuals.append(res)
  out += rice.encode_ints(np.concatenate(counts + length_codes + residuals), version)
  out += struct.pack("<I", zlib.crc32(out))
  return bytes(out)


def mode_bytes(modes: np.ndarray, version: int = VERSION) -> bytes:
  """Channel modes as stored: one bit per channel (version 1: one byte each)."""
  modes = np.asarray(modes, np.uint8)
  if version == 1:
    return modes.tobytes()
  return np.packbits(modes, bitorder="little").tobytes()


def initial_codes(initial: np.ndarray, kinds: list[str], bounds: CodecBounds) -> np.ndarray:
  """u64[..., n] zigzag grid codes of frame-0 values ``initial: f64[..., C, 4]``
  (already on their grid), channel by channel (each kind's width).

  The values are only divided by the grid step and rounded: normalizing a
  quaternion that is already on the grid could move it to a neighbouring grid
  point, and the decoder would then start from another rotation than the fit did.
  """
  kinds_arr = np.array(kinds)
  steps = initial_steps(bounds)
  out = []
  for kind in KINDS:
    sel = np.flatnonzero(kinds_arr == kind)
    if sel.size:
      values = np.nan_to_num(initial[..., sel, :WIDTH[kind]] / steps[kind], nan=0.0, posinf=0.0,
                             neginf=0.0)
      codes = np.clip(np.round(values), -2.0**50, 2.0**50).astype(np.int64)
      out.append((sel, codes.reshape(*codes.shape[:-2], -1)))
  if not out:
    return np.zeros(initial.shape[:-2] + (0,), np.uint64)
  # Back to channel order: kinds are contiguous (pos, rot, scalar) in a layout.
  return rice.zigzag(np.concatenate([c for _, c in out], axis=-1))


def initial_bytes(codes) -> bytes:
  """Zigzag codes (from ``initial_codes``) as varints."""
  return b"".join(map(rice.write_varint, codes))


def read_initial(buf, pos: int, kinds: list[str], bounds: CodecBounds):
  """Inverse of ``initial_bytes``: (f64[C, 4] values, position after them)."""
  steps = initial_steps(bounds)
  initial = np.zeros((len(kinds), 4))
  for c, kind in enumerate(kinds):
    for i in range(WIDTH[kind]):
      u, pos = rice.read_varint(buf, pos, "initial value")
      if u >= 1 << 52:
        raise CodecError("corrupt stream: initial value out of range")
      initial[c, i] = float((u >> 1) ^ -(u & 1)) * steps[kind]
  return initial, pos


def _take(buf, pos, size, what):
  if pos + size > len(buf):
    raise CodecError(f"truncated stream while reading {what}")
  return pos + size


def parse(stream: bytes | bytearray | memoryview | np.ndarray) -> WorldCode:
  """Parse and validate a stream; raises CodecError on anything inconsistent."""
  if isinstance(stream, np.ndarray):
    stream = stream.tobytes()
  buf = bytes(stream)
  if len(buf) < HEADER.size + 4:
    raise CodecError(f"stream too short ({len(buf)} bytes) to be a codec stream")
  magic, version = HEADER.unpack_from(buf, 0)
  if magic != MAGIC:
    raise CodecError(f"not a codec stream (magic {magic!r}, expected {MAGIC!r})")
  (crc,) = struct.unpack_from("<I", buf, len(buf) - 4)
  if zlib.crc32(memoryview(buf)[:-4]) != crc:
    raise CodecError("corrupt stream: CRC32 mismatch")
  buf = buf[:-4]
  if version not in VERSIONS:
    raise CodecError(f"unsupported codec stream version {version} (this build reads "
                     f"{', '.join(map(str, VERSIONS))})")
  pos = HEADER.size
  header = []
  for what in ("n_frames", "nq", "n_pos", "n_rot", "n_scalar"):
    v, pos = rice.read_varint(buf, pos, what)
    header.append(v)
  n_frames, nq, n_pos, n_rot, n_scalar = header
  if n_frames > MAX_FRAMES or nq > 65535 or n_pos + n_rot + n_scalar > nq:
    raise CodecError(f"corrupt stream header (n_frames={n_frames}, nq={nq})")
  end = _take(buf, pos, FLOAT_FIELDS.size + 4, "header")
  fps, e_pos, e_rot, e_scalar, quad = FLOAT_FIELDS.unpack_from(buf, pos)
  shifts = buf[pos + FLOAT_FIELDS.size:end]
  pos = end
  if not all(map(np.isfinite, (fps, e_pos, e_rot, e_scalar, quad))) or fps <= 0 or max(
      shifts) > 40:
    raise CodecError("corrupt stream header (fps, bounds or quanta out of range)")
  n_ch = n_pos + n_rot + n_scalar
  adrs = []
  for _ in range(n_ch):
    v, pos = rice.read_varint(buf, pos, "channel address")
    adrs.append(v)
  try:
    layout = ChannelLayout(nq=nq, pos_adr=tuple(adrs[:n_pos]),
                           rot_adr=tuple(adrs[n_pos:n_pos + n_rot]),
                           scalar_adr=tuple(adrs[n_pos + n_rot:]))
    bounds = CodecBounds(e_pos, e_rot, e_scalar)
  except CodecError as err:
    raise CodecError(f"corrupt stream header: {err}") from None
  size = len(mode_bytes(np.zeros(n_ch, np.uint8), version))
  end = _take(buf, pos, size, "channel modes")
  stored = np.frombuffer(buf, np.uint8, size, pos)
  pos = end
  if version == 1:
    modes = stored.copy()
  else:
    bits = np.unpackbits(stored, bitorder="little")
    modes, unused = bits[:n_ch].astype(np.uint8), bits[n_ch:]
    if np.any(unused):
      raise CodecError("corrupt stream: unknown channel mode")
  if np.any(modes > MODE_RAW):
    raise CodecError("corrupt stream: unknown channel mode")
  kinds = ["pos"] * n_pos + ["rot"] * n_rot + ["scalar"] * n_scalar
  initial, pos = read_initial(buf, pos, kinds, bounds)
  raw = {}
  for c in np.flatnonzero(modes == MODE_RAW).tolist():
    size = n_frames * WIDTH[kinds[c]]
    end = _take(buf, pos, 4 * size, "raw channel")
    raw[c] = np.frombuffer(buf, "<f4", size, pos).reshape(n_frames, WIDTH[kinds[c]])
    pos = end
  fit = modes == MODE_FIT
  n_fit = {"pos": int(fit[:n_pos].sum()), "rot": int(fit[n_pos:n_pos + n_rot].sum()),
           "scalar": int(fit[n_pos + n_rot:].sum())}
  cf = sum(n_fit.values())
  expect = max(n_frames - 1, 0)
  values, pos = rice.decode_ints(buf, pos, "segment data", version=version,
                                 max_count=cf + 7 * expect * cf)
  if pos != len(buf):
    raise CodecError("corrupt stream: trailing bytes after the segment data")
  quanta = Quanta(quad=quad, vel_shift=shifts[0], rot_shift=shifts[1], scalar_shift=shifts[2],
                  lattice_shift=shifts[3])
  ratio = 2.0 * quad / quanta.steps(bounds)[0] * 256.0
  if not abs(ratio) < 2.0**40:
    raise CodecError("corrupt stream header: gravity term out of range")
  coarse = quanta.coarse()
  # The same segment assembly as a batch of streams (batch.parse_batch), for one.
  status, _, seg_counts, lengths, vels, flags = stream_kernels.segments_from_values(
      values, np.zeros(1, np.int64), np.array([values.size], np.int64),
      np.array([n_fit[k] for k in KINDS], np.int64), np.array([expect], np.int64),
      int(quanta.g_fp(bounds)), np.array([coarse[k] for k in KINDS], np.int64))
  if status != STATUS_OK:
    raise CodecError(f"corrupt stream: {STATUS_TEXT[status]}")
  segs = {kind: Segments(seg_counts[i], lengths[i], vels[i], flags[i])
          for i, kind in enumerate(KINDS)}
  return WorldCode(n_frames=n_frames, layout=layout, bounds=bounds, fps=fps, quanta=quanta,
                   modes=modes, initial=initial, raw=raw, segs=segs, version=version)
