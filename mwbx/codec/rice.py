"""Block-adaptive Rice codes for integer sequences.

A sequence of signed integers is zigzag-mapped to unsigned ``u`` and split into
blocks of ``BLOCK`` values; each block uses the Rice parameter ``k`` that makes
it shortest among ``floor(log2(floor(mean) + 1)) + {-1, 0, 1}`` (5 bits per
block). A value is written as ``q = u >> k`` in unary
(``q`` one-bits and a zero) and its low ``k`` bits. Unary parts and remainders
go to two separate bit strings, so the unary string alone says where every
value ends and its length says where the remainders begin. A value with ``q >=
QMAX`` (an outlier) is an escape: ``QMAX`` one-bits without the zero, and among
the remainder bits ``q - QMAX`` as an order-0 exp-Golomb code before its ``k``
low bits, so an outlier costs about twice the bits of its magnitude.

Blob layout: varint n | k per block, 5 bits each, packed | varint unary_bits |
unary bytes | remainder bytes. Version 1 streams (still read) ended escapes'
unary parts with a zero after ``QMAX_V1`` ones and kept their ``u`` as u64
little-endian after the remainder bytes.

The bit loops are compiled (``rice_kernels.py``); this module is their checked,
numpy-facing front.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec import rice_kernels
from mwbx.codec.rice_kernels import BLOCK, KMAX, QMAX, QMAX_V1, VALUE_CAP  # noqa: F401  (part of this API)
from mwbx.codec.status import STATUS_COUNT, STATUS_OK, STATUS_TEXT

# Blob format of current streams (see the module docstring for version 1).
VERSION = 2
from mwbx.codec.layout import CodecError


def zigzag(v: np.ndarray) -> np.ndarray:
  """int64 -> uint64: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ..."""
  v = np.asarray(v, np.int64)
  return ((v << 1) ^ (v >> 63)).astype(np.uint64)


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


def encode_ints(values: np.ndarray, version: int = VERSION) -> bytes:
  """Rice-code a signed integer sequence (|v| < 2**52) into a self-delimiting blob."""
  values = np.asarray(values, np.int64).reshape(-1)
  return encode_ints_batch(values, np.array([values.size]), version)[0]


def decode_ints(buf: bytes | memoryview, pos: int, what: str, max_count: int,
                version: int = VERSION) -> tuple[np.ndarray, int]:
  """Inverse of ``encode_ints``; returns (int64 values, position after the blob).

  ``max_count`` bounds n so corrupt input cannot ask for huge allocations.
  """
  data = np.frombuffer(buf, np.uint8)
  values, end, status = rice_kernels.rice_decode_one(data, int(pos), data.size, int(max_count),
                                                version == 1)
  if status == STATUS_COUNT:
    n, _ = read_varint(buf, pos, what)
    raise CodecError(f"corrupt stream: {what} claims {n} values (at most {max_count})")
  if status != STATUS_OK:
    raise CodecError(f"corrupt stream: {what}: {STATUS_TEXT[status]}")
  return values, int(end)


# -- many sequences at once ------------------------------------------------------------


def encode_ints_batch(values: np.ndarray, counts: np.ndarray,
                      version: int = VERSION) -> list[bytes]:
  """``encode_ints`` of W sequences given back to back (``counts[w]`` values each).

  Returns the W blobs, byte for byte what ``encode_ints`` gives for each.
  """
  data, offsets = encode_ints_joined(values, counts, version)
  raw = data.tobytes()
  return [raw[a:b] for a, b in zip(offsets[:-1].tolist(), offsets[1:].tolist())]


def encode_ints_joined(values: np.ndarray, counts: np.ndarray,
                       version: int = VERSION) -> tuple[np.ndarray, np.ndarray]:
  """The blobs of ``encode_ints_batch`` back to back: (u8[N], i64[W + 1] offsets)."""
  values = np.ascontiguousarray(values, np.int64).reshape(-1)
  counts = np.ascontiguousarray(counts, np.int64).reshape(-1)
  if counts.sum() != values.size or np.any(counts < 0):
    raise ValueError("counts must be >= 0 and add up to the number of values")
  data, offsets, status = rice_kernels.rice_encode_blobs(values, counts, version == 1)
  if status != STATUS_OK:
    raise CodecError("integer residual too large to code (|v| >= 2**52)")
  return data, offsets


def decode_ints_batch(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                      max_counts: np.ndarray, version: int = VERSION) -> tuple[np.ndarray, np.ndarray]:
  """Decode W blobs of the uint8 array ``buf`` at once.

  Blob w occupies exactly ``buf[starts[w]:ends[w]]``. Returns (values i64, counts
  i64[W]). Raises CodecError on anything inconsistent (callers then decode
  world by world to name the culprit).
  """
  values, counts, status, world = rice_kernels.rice_decode_blobs(
      np.ascontiguousarray(buf, np.uint8), np.ascontiguousarray(starts, np.int64),
      np.ascontiguousarray(ends, np.int64), np.ascontiguousarray(max_counts, np.int64),
      version == 1)
  if status != STATUS_OK:
    raise CodecError(f"corrupt stream: {STATUS_TEXT[status]} (world {world})")
  return values, counts
