"""Block-adaptive Rice codes for integer sequences, vectorized with numpy.

A sequence of signed integers is zigzag-mapped to unsigned ``u`` and split into
blocks of ``BLOCK`` values; each block uses the Rice parameter ``k`` that makes
it shortest among ``floor(log2(floor(mean) + 1)) + {-1, 0, 1}`` (5 bits per
block). A value is written as ``q = u >> k`` in unary
(``q`` one-bits and a zero) and its low ``k`` bits. Unary parts and remainders
go to two separate bit strings, so decoding needs no per-value loop: the zeros
of the unary string are the value boundaries and the remainder offsets are a
cumulative sum of the ``k``s. Values with ``q >= QMAX`` (outliers) are written as
``QMAX`` in unary and their ``u`` raw (8 bytes, an escape).

Stream layout: varint n | k per block, 5 bits each, packed | varint
unary_bits | unary bytes | remainder bytes | escapes u64 little-endian.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec.layout import CodecError

BLOCK = 32
KMAX = 31
QMAX = 24
# Decoded magnitudes beyond this are treated as corruption (int64 cumsums stay exact).
VALUE_CAP = 1 << 52


def zigzag(v: np.ndarray) -> np.ndarray:
  """int64 -> uint64: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ..."""
  v = np.asarray(v, np.int64)
  return ((v << 1) ^ (v >> 63)).astype(np.uint64)


def unzigzag(u: np.ndarray) -> np.ndarray:
  u = np.asarray(u, np.uint64)
  return ((u >> np.uint64(1)).astype(np.int64)) ^ (-(u & np.uint64(1)).astype(np.int64))


def floor_log2(x: np.ndarray) -> np.ndarray:
  """floor(log2(x)) of integers x >= 1, exactly."""
  # frexp is exact on integers below 2**53: x = m * 2**e with m in [0.5, 1).
  return np.frexp(np.asarray(x, np.int64).astype(np.float64))[1].astype(np.int64) - 1


def write_varint(value: int) -> bytes:
  if value < 0:
    raise ValueError("varint of a negative number")
  out = bytearray()
  while True:
    byte = value & 0x7F
    value >>= 7
    if value:
      out.append(byte | 0x80)
    else:
      out.append(byte)
      return bytes(out)


def read_varint(buf: memoryview | bytes, pos: int, what: str) -> tuple[int, int]:
  value, shift = 0, 0
  while True:
    if pos >= len(buf):
      raise CodecError(f"truncated stream while reading {what}")
    byte = buf[pos]
    pos += 1
    value |= (byte & 0x7F) << shift
    if not byte & 0x80:
      return value, pos
    shift += 7
    if shift > 56:
      raise CodecError(f"corrupt stream: {what} is not a valid varint")


def unpack_bits(data: np.ndarray, offsets: np.ndarray, widths: np.ndarray) -> np.ndarray:
  """Read ``widths[i] <= 57`` bits at bit ``offsets[i]`` of the uint8 array ``data``."""
  if offsets.size == 0:
    return np.zeros(0, np.uint64)
  byte = offsets >> 3
  last = data.size - 1
  word = np.zeros(offsets.size, np.uint64)
  for i in range(8):
    idx = byte + i
    value = data[np.clip(idx, 0, max(last, 0))].astype(np.uint64) if data.size else 0
    word = (word << np.uint64(8)) | np.where(idx <= last, value, np.uint64(0))
  word <<= (offsets & 7).astype(np.uint64)
  out = word >> (np.uint64(64) - widths.astype(np.uint64))
  return np.where(widths > 0, out, np.uint64(0))


def encode_ints(values: np.ndarray) -> bytes:
  """Rice-code a signed integer sequence (|v| < 2**52) into a self-delimiting blob."""
  values = np.asarray(values, np.int64).reshape(-1)
  return encode_ints_batch(values, np.array([values.size]))[0]


def decode_ints(buf: bytes | memoryview, pos: int, what: str,
                max_count: int) -> tuple[np.ndarray, int]:
  """Inverse of ``encode_ints``; returns (int64 values, position after the blob).

  ``max_count`` bounds n so corrupt input cannot ask for huge allocations.
  """
  n, pos = read_varint(buf, pos, f"{what} count")
  if n == 0:
    return np.zeros(0, np.int64), pos
  if n > max_count:
    raise CodecError(f"corrupt stream: {what} claims {n} values (at most {max_count})")
  nb = -(-n // BLOCK)
  kbytes = -(-nb * 5 // 8)
  if pos + kbytes > len(buf):
    raise CodecError(f"truncated stream in {what} parameters")
  kdata = np.frombuffer(buf, np.uint8, kbytes, pos)
  pos += kbytes
  kb = unpack_bits(kdata, np.arange(nb, dtype=np.int64) * 5, np.full(nb, 5)).astype(np.int64)
  if np.any(kb > KMAX):
    raise CodecError(f"corrupt stream: {what} Rice parameter out of range")
  unary_len, pos = read_varint(buf, pos, f"{what} unary length")
  if unary_len < n or unary_len > n * (QMAX + 1):
    raise CodecError(f"corrupt stream: {what} unary length {unary_len} for {n} values")
  ubytes = -(-unary_len // 8)
  if pos + ubytes > len(buf):
    raise CodecError(f"truncated stream in {what} unary codes")
  unary = np.unpackbits(np.frombuffer(buf, np.uint8, ubytes, pos))[:unary_len]
  pos += ubytes
  zeros = np.flatnonzero(unary == 0)
  if zeros.size != n or zeros[-1] != unary_len - 1:
    raise CodecError(f"corrupt stream: {what} unary codes do not hold {n} values")
  q = np.diff(zeros, prepend=-1) - 1
  if np.any(q > QMAX):
    raise CodecError(f"corrupt stream: {what} unary code longer than {QMAX}")
  k = np.repeat(kb, BLOCK)[:n]
  escaped = q == QMAX
  rem_w = np.where(escaped, 0, k)
  rem_off = np.concatenate([[0], np.cumsum(rem_w)[:-1]]).astype(np.int64)
  rbytes = -(-int(rem_w.sum()) // 8)
  if pos + rbytes > len(buf):
    raise CodecError(f"truncated stream in {what} remainders")
  rdata = np.frombuffer(buf, np.uint8, rbytes, pos)
  pos += rbytes
  rem = unpack_bits(rdata, rem_off, rem_w)
  u = (q.astype(np.uint64) << k.astype(np.uint64)) | rem
  n_esc = int(escaped.sum())
  if n_esc:
    if pos + 8 * n_esc > len(buf):
      raise CodecError(f"truncated stream in {what} escapes")
    u[escaped] = np.frombuffer(buf, "<u8", n_esc, pos)
    pos += 8 * n_esc
  if np.any(u >= np.uint64(2 * VALUE_CAP)):
    raise CodecError(f"corrupt stream: {what} value out of range")
  return unzigzag(u), pos


# -- many sequences at once ------------------------------------------------------------


def pack_ragged(values: np.ndarray, widths: np.ndarray, group: np.ndarray,
                n_groups: int) -> tuple[bytes, np.ndarray]:
  """Bit strings of several groups, each packed MSB first from a byte boundary.

  values: u64[n] (only the low ``widths`` bits are used); widths: i64[n] in
  [0, 57]; group: i64[n] non-decreasing group id. Returns (all bytes, i64[n_groups
  + 1] byte offsets of each group).
  """
  widths = np.asarray(widths, np.int64)
  group = np.asarray(group, np.int64)
  group_bits = np.bincount(group, weights=widths, minlength=n_groups).astype(np.int64)
  byte_off = np.concatenate([[0], np.cumsum(-(-group_bits // 8))])
  keep = widths > 0
  if not keep.any():
    return bytes(int(byte_off[-1])), byte_off
  excl = np.cumsum(widths) - widths
  first_of_group = np.searchsorted(group, np.arange(n_groups))
  bit_start = (8 * byte_off[group] + excl - excl[np.minimum(first_of_group[group],
                                                            group.size - 1)])[keep]
  w = widths[keep].astype(np.uint64)
  v = np.asarray(values, np.uint64)[keep] & ((np.uint64(1) << w) - np.uint64(1))
  # Big-endian 64-bit words; a value starts in word i and may spill into i + 1.
  word = bit_start >> 6
  shift = (bit_start & 63).astype(np.uint64)
  room = np.uint64(64) - shift  # bits left in word i
  fits = w <= room
  primary = np.where(fits, v << np.where(fits, room - w, 0),
                     v >> np.where(fits, 0, w - room))
  n_words = int(8 * byte_off[-1] + 63) // 64 + 1
  words = np.zeros(n_words, np.uint64)
  heads = np.flatnonzero(np.diff(word, prepend=-1))
  words[word[heads]] = np.bitwise_or.reduceat(primary, heads)
  spill = ~fits
  spill_bits = (w - room)[spill]
  words[word[spill] + 1] |= v[spill] << (np.uint64(64) - spill_bits)
  out = words.astype(">u8").tobytes()
  return out[:int(byte_off[-1])], byte_off


def encode_ints_batch(values: np.ndarray, counts: np.ndarray) -> list[bytes]:
  """``encode_ints`` of W sequences given back to back (``counts[w]`` values each).

  Returns the W blobs, byte for byte what ``encode_ints`` gives for each.
  """
  values = np.asarray(values, np.int64).reshape(-1)
  counts = np.asarray(counts, np.int64)
  n_w = counts.size
  if values.size and np.any(np.abs(values) >= VALUE_CAP):
    raise CodecError("integer residual too large to code (|v| >= 2**52)")
  starts = np.cumsum(counts) - counts
  world = np.repeat(np.arange(n_w), counts)
  local = np.arange(values.size) - starts[world]
  u = zigzag(values)
  nb = -(-counts // BLOCK)
  block = (np.cumsum(nb) - nb)[world] + local // BLOCK
  if values.size:
    block_first = np.flatnonzero(np.diff(block, prepend=-1))
    block_sum = np.add.reduceat(u.astype(np.int64), block_first)
    block_len = np.diff(np.append(block_first, values.size))
    k0 = floor_log2(block_sum // block_len + 1)
    cand = np.clip(k0[:, None] + np.array([-1, 0, 1])[None, :], 0, KMAX)  # [NB, 3]
    kc = cand[block].astype(np.uint64)
    q_all = u[:, None] >> kc
    cost = np.where(q_all >= QMAX, QMAX + 1 + 64, q_all.astype(np.float64) + 1 + kc)
    best = np.argmin(np.add.reduceat(cost, block_first, axis=0), axis=1)
    kb = cand[np.arange(cand.shape[0]), best]
  else:
    kb = np.zeros(0, np.int64)
  block_world = np.repeat(np.arange(n_w), nb)
  kbytes, k_off = pack_ragged(kb.astype(np.uint64), np.full(kb.size, 5), block_world, n_w)
  k = kb[block] if values.size else np.zeros(0, np.int64)
  q = u >> k.astype(np.uint64)
  escaped = q >= QMAX
  q = np.where(escaped, QMAX, q).astype(np.int64)
  unary_vals = (np.uint64(1) << (q + 1).astype(np.uint64)) - np.uint64(2)
  ubytes, u_off = pack_ragged(unary_vals, q + 1, world, n_w)
  unary_len = np.bincount(world, weights=q + 1, minlength=n_w).astype(np.int64)
  rem_w = np.where(escaped, 0, k)
  rem = u & ((np.uint64(1) << k.astype(np.uint64)) - np.uint64(1))
  rbytes, r_off = pack_ragged(rem, rem_w, world, n_w)
  esc_world = world[escaped]
  esc_bytes = u[escaped].astype("<u8").tobytes()
  esc_off = 8 * np.concatenate([[0], np.cumsum(np.bincount(esc_world, minlength=n_w))])
  blobs = []
  for w in range(n_w):
    n = int(counts[w])
    if n == 0:
      blobs.append(write_varint(0))
      continue
    blobs.append(b"".join((write_varint(n), kbytes[k_off[w]:k_off[w + 1]],
                           write_varint(int(unary_len[w])), ubytes[u_off[w]:u_off[w + 1]],
                           rbytes[r_off[w]:r_off[w + 1]], esc_bytes[esc_off[w]:esc_off[w + 1]])))
  return blobs


def decode_ints_batch(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                      max_counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """Decode W blobs of the uint8 array ``buf`` at once.

  Blob w occupies exactly ``buf[starts[w]:ends[w]]``. Returns (values i64, counts
  i64[W]). Raises CodecError on anything inconsistent (callers then decode
  world by world to name the culprit).
  """
  n_w = len(starts)
  counts = np.zeros(n_w, np.int64)
  k_pos = np.zeros(n_w, np.int64)
  u_pos = np.zeros(n_w, np.int64)
  u_len = np.zeros(n_w, np.int64)
  view = memoryview(buf)
  for w in range(n_w):
    n, pos = read_varint(view, int(starts[w]), "count")
    if n > max_counts[w]:
      raise CodecError("corrupt stream: too many values")
    counts[w] = n
    if n == 0:
      if pos != ends[w]:
        raise CodecError("corrupt stream: trailing bytes")
      continue
    k_pos[w] = pos
    pos += -(-(-(-n // BLOCK)) * 5 // 8)
    ul, pos = read_varint(view, pos, "unary length")
    if ul < n or ul > n * (QMAX + 1) or pos + -(-ul // 8) > ends[w]:
      raise CodecError("corrupt stream: unary length")
    u_pos[w], u_len[w] = pos, ul
  total = int(counts.sum())
  if total == 0:
    return np.zeros(0, np.int64), counts
  world = np.repeat(np.arange(n_w), counts)
  local = np.arange(total) - (np.cumsum(counts) - counts)[world]
  nb = -(-counts // BLOCK)
  block_world = np.repeat(np.arange(n_w), nb)
  block_local = np.arange(int(nb.sum())) - (np.cumsum(nb) - nb)[block_world]
  kb = unpack_bits(buf, 8 * k_pos[block_world] + 5 * block_local,
                   np.full(block_world.size, 5)).astype(np.int64)
  if np.any(kb > KMAX):
    raise CodecError("corrupt stream: Rice parameter out of range")
  k = kb[(np.cumsum(nb) - nb)[world] + local // BLOCK]
  # Unary bits of every blob, back to back: each ends with a zero, so the
  # zeros' positions give every q, across blob boundaries too.
  ubit_world = np.repeat(np.arange(n_w), u_len)
  ubit_local = np.arange(int(u_len.sum())) - (np.cumsum(u_len) - u_len)[ubit_world]
  ubit_pos = 8 * u_pos[ubit_world] + ubit_local
  bits = (buf[ubit_pos >> 3] >> (7 - (ubit_pos & 7)).astype(np.uint8)) & 1
  zeros = np.flatnonzero(bits == 0)
  if zeros.size != total or np.any(np.bincount(ubit_world[zeros], minlength=n_w) != counts):
    raise CodecError("corrupt stream: unary codes do not match counts")
  q = np.diff(zeros, prepend=-1) - 1
  if np.any(q > QMAX):
    raise CodecError("corrupt stream: unary code too long")
  escaped = q == QMAX
  rem_w = np.where(escaped, 0, k)
  rem_bits = np.bincount(world, weights=rem_w, minlength=n_w).astype(np.int64)
  r_pos = u_pos + -(-u_len // 8)
  excl = np.cumsum(rem_w) - rem_w
  first = np.cumsum(counts) - counts
  rem_off = 8 * r_pos[world] + excl - excl[first[world]]
  n_esc = np.bincount(world[escaped], minlength=n_w)
  e_pos = r_pos + -(-rem_bits // 8)
  blob_end = e_pos + 8 * n_esc
  if np.any((blob_end != ends) & (counts > 0)):
    raise CodecError("corrupt stream: blob length mismatch")
  rem = unpack_bits(buf, rem_off, rem_w)
  u = (q.astype(np.uint64) << k.astype(np.uint64)) | rem
  if escaped.any():
    esc_idx = np.flatnonzero(escaped)
    esc_rank = np.arange(esc_idx.size) - (np.cumsum(n_esc) - n_esc)[world[esc_idx]]
    byte0 = e_pos[world[esc_idx]] + 8 * esc_rank
    word = np.zeros(esc_idx.size, np.uint64)
    for i in range(7, -1, -1):
      word = (word << np.uint64(8)) | buf[byte0 + i].astype(np.uint64)
    u[esc_idx] = word
  if np.any(u >= np.uint64(2 * VALUE_CAP)):
    raise CodecError("corrupt stream: value out of range")
  return unzigzag(u), counts
