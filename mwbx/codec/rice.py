"""Block-adaptive Rice codes for integer sequences, vectorized with numpy.

A sequence of signed integers is zigzag-mapped to unsigned ``u`` and split into
blocks of ``BLOCK`` values; each block uses the Rice parameter ``k`` that makes
it shortest (5 bits per block). A value is written as ``q = u >> k`` in unary
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


def pack_bits(values: np.ndarray, widths: np.ndarray) -> bytes:
  """Concatenate the low ``widths[i]`` bits of ``values[i]`` (MSB first)."""
  values = np.asarray(values, np.uint64)
  widths = np.asarray(widths, np.int64)
  if values.size == 0 or int(widths.sum()) == 0:
    return b""
  wmax = int(widths.max())
  j = np.arange(wmax, dtype=np.int64)
  shift = widths[:, None] - 1 - j[None, :]
  mask = shift >= 0
  bits = (values[:, None] >> np.maximum(shift, 0).astype(np.uint64)) & np.uint64(1)
  return np.packbits(bits[mask].astype(np.uint8)).tobytes()


def unpack_bits(data: np.ndarray, offsets: np.ndarray, widths: np.ndarray) -> np.ndarray:
  """Read ``widths[i] <= 57`` bits at bit ``offsets[i]`` of the uint8 array ``data``."""
  if offsets.size == 0:
    return np.zeros(0, np.uint64)
  padded = np.concatenate([data, np.zeros(8, np.uint8)])
  byte = offsets >> 3
  word = np.zeros(offsets.size, np.uint64)
  for i in range(8):
    word = (word << np.uint64(8)) | padded[byte + i].astype(np.uint64)
  word <<= (offsets & 7).astype(np.uint64)
  out = word >> (np.uint64(64) - widths.astype(np.uint64))
  return np.where(widths > 0, out, np.uint64(0))


def _best_k(u: np.ndarray) -> np.ndarray:
  """Per block, the k in [0, KMAX] giving the fewest bits."""
  n = u.size
  nb = -(-n // BLOCK)
  pad = np.zeros(nb * BLOCK, np.uint64)
  pad[:n] = u
  valid = (np.arange(nb * BLOCK) < n).reshape(nb, BLOCK)
  ks = np.arange(KMAX + 1, dtype=np.uint64)
  q = pad.reshape(nb, BLOCK, 1) >> ks[None, None, :]
  escaped = q >= QMAX
  cost = np.where(escaped, QMAX + 1 + 64, q.astype(np.float64) + 1 + ks[None, None, :])
  cost = np.where(valid[:, :, None], cost, 0).sum(axis=1)
  return np.argmin(cost, axis=1).astype(np.int64)


def encode_ints(values: np.ndarray) -> bytes:
  """Rice-code a signed integer sequence (|v| < 2**52) into a self-delimiting blob."""
  values = np.asarray(values, np.int64).reshape(-1)
  n = values.size
  out = bytearray(write_varint(n))
  if n == 0:
    return bytes(out)
  if np.any(np.abs(values) >= VALUE_CAP):
    raise CodecError("integer residual too large to code (|v| >= 2**52)")
  u = zigzag(values)
  kb = _best_k(u)
  out += pack_bits(kb.astype(np.uint64), np.full(kb.size, 5))
  k = np.repeat(kb, BLOCK)[:n]
  q = u >> k.astype(np.uint64)
  escaped = q >= QMAX
  q = np.where(escaped, QMAX, q).astype(np.int64)
  unary_len = int(q.sum() + n)
  unary = np.ones(unary_len, np.uint8)
  unary[np.cumsum(q + 1) - 1] = 0
  out += write_varint(unary_len)
  out += np.packbits(unary).tobytes()
  rem_w = np.where(escaped, 0, k)
  out += pack_bits(u & ((np.uint64(1) << k.astype(np.uint64)) - np.uint64(1)), rem_w)
  out += u[escaped].astype("<u8").tobytes()
  return bytes(out)


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
