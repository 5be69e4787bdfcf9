"""Rice coding and varints as compiled loops (``rice.py`` is their checked API).

Sequential by nature (a unary code ends where the next begins), so far faster
as a compiled loop than as many numpy passes. Errors come back as
``status.STATUS_*`` codes.
"""

from __future__ import annotations

import numpy as np

from mwbx.codec.status import (STATUS_BLOB_LENGTH, STATUS_COUNT, STATUS_OK, STATUS_TRUNCATED,
                               STATUS_UNARY_CODES, STATUS_UNARY_LENGTH, STATUS_UNARY_TOO_LONG,
                               STATUS_VALUE_RANGE)
from mwbx.host_jit import host_jit

BLOCK = 32
KMAX = 31
# Unary parts of at least QMAX mark an escape. Version 2 streams write QMAX ones
# and then, among the remainder bits, ``q - QMAX`` as an order-0 exp-Golomb code
# and the k low bits; version 1 streams wrote QMAX_V1 ones and a zero and kept
# ``u`` raw (8 bytes) after the remainders.
QMAX = 6
QMAX_V1 = 24
# Decoded magnitudes beyond this are treated as corruption (int64 cumsums stay exact).
VALUE_CAP = 1 << 52


# -- bits -----------------------------------------------------------------------------


@host_jit
def read_varint(buf, pos, end):
  """(value, position after it), value -1 if truncated or longer than 8 groups."""
  value = np.int64(0)
  shift = 0
  while True:
    if pos >= end:
      return np.int64(-1), pos
    byte = np.int64(buf[pos])
    pos += 1
    value |= (byte & 0x7F) << shift
    if byte < 0x80:
      return value, pos
    shift += 7
    if shift > 56:
      return np.int64(-1), pos


@host_jit
def _window(buf, bit):
  """The 40 bits from the byte holding bit offset ``bit``, big-endian (0 past the end)."""
  byte = bit >> 3
  value = np.int64(0)
  for j in range(5):
    idx = byte + j
    value = (value << 8) | (np.int64(buf[idx]) if idx < buf.size else np.int64(0))
  return value


@host_jit
def _read_bits(buf, bit, width):
  """``width`` (<= 32) bits at bit offset ``bit``, most significant first."""
  return (_window(buf, bit) >> (40 - (bit & 7) - width)) & ((np.int64(1) << width) - 1)


@host_jit
def _put(out, pos, acc, n_bits, value, width):
  """Bit writer: append the low ``width`` (<= 32) bits of ``value``, whole bytes go
  to ``out[pos...]``; returns the new (pos, acc, n_bits)."""
  acc = (acc << width) | value
  n_bits += width
  while n_bits >= 8:
    n_bits -= 8
    out[pos] = np.uint8((acc >> n_bits) & 0xFF)
    pos += 1
  acc &= (np.int64(1) << n_bits) - 1
  return pos, acc, n_bits


@host_jit
def _flush(out, pos, acc, n_bits):
  """Write a bit writer's last partial byte, zero-padded."""
  if n_bits > 0:
    out[pos] = np.uint8((acc << (8 - n_bits)) & 0xFF)


@host_jit
def _varint_size(value):
  size = 1
  while value >= 0x80:
    value >>= 7
    size += 1
  return size


@host_jit
def _write_varint(out, pos, value):
  while value >= 0x80:
    out[pos] = np.uint8((value & 0x7F) | 0x80)
    value >>= 7
    pos += 1
  out[pos] = np.uint8(value)
  return pos + 1


@host_jit
def _zigzag(v):
  return (v << 1) ^ (v >> 63)


@host_jit
def floor_log2(x):
  n = -1
  while x > 0:
    x >>= 1
    n += 1
  return n


# -- Rice coding ----------------------------------------------------------------------


@host_jit
def _exp_golomb_bits(x):
  """Length of the order-0 exp-Golomb code of x >= 0."""
  return 2 * floor_log2(x + 1) + 1


@host_jit
def _value_bits(u, k, legacy):
  """Bits one value ``u`` costs with Rice parameter k (unary, remainder, escape)."""
  q = u >> k
  if legacy:
    return QMAX_V1 + 1 + 64 if q >= QMAX_V1 else q + 1 + k
  return QMAX + _exp_golomb_bits(q - QMAX) + k if q >= QMAX else q + 1 + k


@host_jit
def _block_k(u, lo, hi, legacy):
  """Rice parameter of the values ``u[lo:hi]``: the shortest of k0 - 1, k0, k0 + 1."""
  total = np.int64(0)
  for i in range(lo, hi):
    total += u[i]
  k0 = floor_log2(total // (hi - lo) + 1)
  best_k, best_cost = 0, np.int64(-1)
  for d in range(-1, 2):
    k = min(max(k0 + d, 0), KMAX)
    cost = np.int64(0)
    for i in range(lo, hi):
      cost += _value_bits(u[i], k, legacy)
    if best_cost < 0 or cost < best_cost:
      best_k, best_cost = k, cost
  return best_k


@host_jit
def _put_wide(out, pos, acc, n_bits, value, width):
  """``_put`` for widths up to 62 bits."""
  if width > 31:
    pos, acc, n_bits = _put(out, pos, acc, n_bits, value >> 31, width - 31)
    width = 31
  return _put(out, pos, acc, n_bits, value & ((np.int64(1) << width) - 1), width)


@host_jit
def rice_encode_blobs(values, counts, legacy):
  """Rice-code W integer sequences given back to back (``counts[w]`` values each).

  Returns (u8[N] all blobs, i64[W + 1] byte offsets, status). Layout of a blob:
  varint n | k per block, 5 bits each | varint unary bits | unary bits | remainder
  bits | (version 1 only) escapes u64 little-endian (see ``rice.py``). ``legacy``
  writes version 1 escapes.
  """
  n_w = counts.size
  u = np.empty(values.size, np.int64)
  for i in range(values.size):
    v = values[i]
    if v >= VALUE_CAP or v <= -VALUE_CAP:
      return np.zeros(0, np.uint8), np.zeros(n_w + 1, np.int64), STATUS_VALUE_RANGE
    u[i] = _zigzag(v)
  qmax = QMAX_V1 if legacy else QMAX
  n_blocks = 0
  for w in range(n_w):
    n_blocks += (counts[w] + BLOCK - 1) // BLOCK
  ks = np.empty(n_blocks, np.int64)
  sizes = np.empty(n_w, np.int64)
  unary_bits = np.empty(n_w, np.int64)
  rem_bits = np.empty(n_w, np.int64)
  escapes = np.empty(n_w, np.int64)
  start, b = 0, 0
  for w in range(n_w):
    n = counts[w]
    unary_bits[w] = rem_bits[w] = escapes[w] = 0
    for lo in range(start, start + n, BLOCK):
      hi = min(lo + BLOCK, start + n)
      k = _block_k(u, lo, hi, legacy)
      ks[b] = k
      b += 1
      for i in range(lo, hi):
        q = u[i] >> k
        if q < qmax:
          unary_bits[w] += q + 1
          rem_bits[w] += k
        elif legacy:
          unary_bits[w] += qmax + 1
          escapes[w] += 1
        else:
          unary_bits[w] += qmax
          rem_bits[w] += _exp_golomb_bits(q - qmax) + k
    if n == 0:
      sizes[w] = 1
    else:
      nb = (n + BLOCK - 1) // BLOCK
      sizes[w] = (_varint_size(n) + (5 * nb + 7) // 8 + _varint_size(unary_bits[w])
                  + (unary_bits[w] + 7) // 8 + (rem_bits[w] + 7) // 8 + 8 * escapes[w])
    start += n
  offsets = np.zeros(n_w + 1, np.int64)
  for w in range(n_w):
    offsets[w + 1] = offsets[w] + sizes[w]
  out = np.zeros(offsets[n_w], np.uint8)
  start, b = 0, 0
  for w in range(n_w):
    n = counts[w]
    pos = _write_varint(out, offsets[w], n)
    if n == 0:
      continue
    nb = (n + BLOCK - 1) // BLOCK
    k_pos, k_acc, k_bits = pos, np.int64(0), 0
    for j in range(nb):
      k_pos, k_acc, k_bits = _put(out, k_pos, k_acc, k_bits, ks[b + j], 5)
    _flush(out, k_pos, k_acc, k_bits)
    pos += (5 * nb + 7) // 8
    pos = _write_varint(out, pos, unary_bits[w])
    u_pos, u_acc, u_bits = pos, np.int64(0), 0
    r_pos, r_acc, r_bits = pos + (unary_bits[w] + 7) // 8, np.int64(0), 0
    esc_pos = r_pos + (rem_bits[w] + 7) // 8
    for i in range(start, start + n):
      k = ks[b + (i - start) // BLOCK]
      q = u[i] >> k
      low = u[i] & ((np.int64(1) << k) - 1)
      if q < qmax:
        # q ones and a zero, then k low bits.
        u_pos, u_acc, u_bits = _put(out, u_pos, u_acc, u_bits, (np.int64(1) << (q + 1)) - 2,
                                    q + 1)
        r_pos, r_acc, r_bits = _put(out, r_pos, r_acc, r_bits, low, k)
      elif legacy:
        u_pos, u_acc, u_bits = _put(out, u_pos, u_acc, u_bits,
                                    (np.int64(1) << (qmax + 1)) - 2, qmax + 1)
        value = u[i]
        for byte in range(8):
          out[esc_pos + byte] = np.uint8((value >> (8 * byte)) & 0xFF)
        esc_pos += 8
      else:
        # qmax ones; exp-Golomb of q - qmax (N zeros, then the N + 1 bits of q - qmax + 1).
        u_pos, u_acc, u_bits = _put(out, u_pos, u_acc, u_bits, (np.int64(1) << qmax) - 1, qmax)
        x = q - qmax + 1
        width = floor_log2(x)
        r_pos, r_acc, r_bits = _put_wide(out, r_pos, r_acc, r_bits, np.int64(0), width)
        r_pos, r_acc, r_bits = _put_wide(out, r_pos, r_acc, r_bits, x, width + 1)
        r_pos, r_acc, r_bits = _put(out, r_pos, r_acc, r_bits, low, k)
    _flush(out, u_pos, u_acc, u_bits)
    _flush(out, r_pos, r_acc, r_bits)
    start += n
    b += nb
  return out, offsets, STATUS_OK


@host_jit
def _blob_header(buf, lo, end, max_count, legacy):
  """(status, n, k position, unary position, unary bits, position after the varints)."""
  n, pos = read_varint(buf, lo, end)
  if n < 0:
    return STATUS_TRUNCATED, 0, 0, 0, 0, pos
  if n > max_count:
    return STATUS_COUNT, n, 0, 0, 0, pos
  if n == 0:
    return STATUS_OK, 0, pos, pos, 0, pos
  k_pos = pos
  pos += (5 * ((n + BLOCK - 1) // BLOCK) + 7) // 8
  unary_len, pos = read_varint(buf, pos, end)
  if unary_len < 0:
    return STATUS_TRUNCATED, n, k_pos, 0, 0, pos
  qmax = QMAX_V1 if legacy else QMAX
  if unary_len < n or unary_len > n * (qmax + 1) or pos + (unary_len + 7) // 8 > end:
    return STATUS_UNARY_LENGTH, n, k_pos, pos, unary_len, pos
  return STATUS_OK, n, k_pos, pos, unary_len, pos


@host_jit
def _refill(buf, end, pos, acc, n_bits):
  """Top up a bit reader to more than 48 bits (zeros past ``end``)."""
  while n_bits <= 48:
    acc = (acc << 8) | (np.int64(buf[pos]) if pos < end else np.int64(0))
    pos += 1
    n_bits += 8
  return pos, acc, n_bits


@host_jit
def _take(buf, end, pos, acc, n_bits, width):
  """Read ``width`` (<= 31) bits: (value, pos, acc, n_bits)."""
  if n_bits < width:
    pos, acc, n_bits = _refill(buf, end, pos, acc, n_bits)
  n_bits -= width
  value = acc >> n_bits
  acc &= (np.int64(1) << n_bits) - 1
  return value, pos, acc, n_bits


@host_jit
def _decode_blob(buf, end, n, k_pos, u_pos, unary_len, out, exact_end, legacy):
  """Decode one blob's ``n`` values into ``out``; (status, position after the blob).

  With ``exact_end`` the blob must end exactly at ``end``; otherwise it may be
  followed by other bytes and only must not run past ``end``. Bits are read
  through a reader holding the next ``n_bits`` bits right-aligned in ``acc``.
  """
  qmax = QMAX_V1 if legacy else QMAX
  n_blocks = (n + BLOCK - 1) // BLOCK
  ks = np.empty(n_blocks, np.int64)
  for b in range(n_blocks):
    ks[b] = _read_bits(buf, 8 * k_pos + 5 * b, 5)
  q = np.empty(n, np.int64)
  r_pos = u_pos + (unary_len + 7) // 8
  pos, acc, n_bits = u_pos, np.int64(0), 0
  used = np.int64(0)
  rem_bits = np.int64(0)
  n_esc = 0
  for i in range(n):
    pos, acc, n_bits = _refill(buf, r_pos, pos, acc, n_bits)
    # Version 2 stops at qmax ones (an escape); version 1 errs past QMAX_V1.
    limit = qmax + 1 if legacy else qmax
    count = 0
    while count < limit and (acc >> (n_bits - 1 - count)) & 1:
      count += 1
    if legacy and count > qmax:
      return STATUS_UNARY_TOO_LONG, 0
    # A version 2 escape is qmax ones without the closing zero.
    width = count if (not legacy and count == qmax) else count + 1
    used += width
    if used > unary_len:
      return STATUS_UNARY_CODES, 0
    n_bits -= width
    acc &= (np.int64(1) << n_bits) - 1
    q[i] = count
    if count == qmax:
      n_esc += 1
    else:
      rem_bits += ks[i // BLOCK]
  if used != unary_len:
    return STATUS_UNARY_CODES, 0
  if legacy:
    e_pos = r_pos + (rem_bits + 7) // 8
    blob_end = e_pos + 8 * n_esc
    if (exact_end and blob_end != end) or blob_end > end:
      return STATUS_BLOB_LENGTH if exact_end else STATUS_TRUNCATED, 0
  else:
    e_pos = blob_end = end
  read_end = e_pos
  pos, acc, n_bits = r_pos, np.int64(0), 0
  bits_read = np.int64(0)
  for i in range(n):
    k = ks[i // BLOCK]
    if q[i] == qmax and legacy:
      if buf[e_pos + 7] >= 0x80:
        return STATUS_VALUE_RANGE, 0
      u = np.int64(0)
      for byte in range(7, -1, -1):
        u = (u << 8) | np.int64(buf[e_pos + byte])
      e_pos += 8
    else:
      high = q[i]
      if q[i] == qmax:
        # Exp-Golomb: N zeros, then N + 1 bits holding q - qmax + 1.
        zeros = 0
        while True:
          bit, pos, acc, n_bits = _take(buf, read_end, pos, acc, n_bits, 1)
          bits_read += 1
          if bit:
            break
          zeros += 1
          if zeros > 52:
            return STATUS_VALUE_RANGE, 0
        x = np.int64(1)
        left = zeros
        while left > 0:
          part = min(left, 31)
          value, pos, acc, n_bits = _take(buf, read_end, pos, acc, n_bits, part)
          x = (x << part) | value
          left -= part
        bits_read += zeros
        high = qmax + x - 1
        if high >= (2 * VALUE_CAP) >> k:
          return STATUS_VALUE_RANGE, 0
      low, pos, acc, n_bits = _take(buf, read_end, pos, acc, n_bits, k)
      bits_read += k
      u = (high << k) | low
    if u >= 2 * VALUE_CAP:
      return STATUS_VALUE_RANGE, 0
    out[i] = (u >> 1) ^ -(u & 1)
  if not legacy:
    blob_end = r_pos + (bits_read + 7) // 8
    if (exact_end and blob_end != end) or blob_end > end:
      return STATUS_BLOB_LENGTH if exact_end else STATUS_TRUNCATED, 0
  return STATUS_OK, blob_end


@host_jit
def rice_decode_blobs(buf, starts, ends, max_counts, legacy):
  """Decode W blobs, blob w occupying exactly ``buf[starts[w]:ends[w]]``.

  Returns (i64 values back to back, i64[W] counts, status, world of the first
  problem or -1).
  """
  n_w = starts.size
  counts = np.zeros(n_w, np.int64)
  k_pos = np.zeros(n_w, np.int64)
  u_pos = np.zeros(n_w, np.int64)
  u_len = np.zeros(n_w, np.int64)
  for w in range(n_w):
    status, n, kp, up, ul, pos = _blob_header(buf, starts[w], ends[w], max_counts[w], legacy)
    if status != STATUS_OK:
      return np.zeros(0, np.int64), counts, status, w
    if n == 0 and pos != ends[w]:
      return np.zeros(0, np.int64), counts, STATUS_BLOB_LENGTH, w
    counts[w], k_pos[w], u_pos[w], u_len[w] = n, kp, up, ul
  values = np.empty(counts.sum(), np.int64)
  off = 0
  for w in range(n_w):
    if counts[w]:
      status, _ = _decode_blob(buf, ends[w], counts[w], k_pos[w], u_pos[w], u_len[w],
                               values[off:off + counts[w]], True, legacy)
      if status != STATUS_OK:
        return np.zeros(0, np.int64), counts, status, w
    off += counts[w]
  return values, counts, STATUS_OK, -1


@host_jit
def rice_decode_one(buf, pos, end, max_count, legacy):
  """One blob at ``pos`` ending at or before ``end``: (values, position after it,
  status). Version 2 blobs are not self-delimiting: they must end at ``end``."""
  status, n, kp, up, ul, after = _blob_header(buf, pos, end, max_count, legacy)
  if status != STATUS_OK:
    return np.zeros(0, np.int64), after, status
  values = np.empty(n, np.int64)
  if n == 0:
    return values, after, STATUS_OK
  status, blob_end = _decode_blob(buf, end, n, kp, up, ul, values, False, legacy)
  return values, blob_end, status


@host_jit
def varint_rows(codes):
  """The varints of every row of ``codes: i64[W, n]`` (values >= 0), back to back:
  (u8[N], i64[W + 1] row offsets)."""
  n_w, n = codes.shape
  offsets = np.zeros(n_w + 1, np.int64)
  for w in range(n_w):
    size = 0
    for j in range(n):
      size += _varint_size(codes[w, j])
    offsets[w + 1] = offsets[w] + size
  out = np.empty(offsets[n_w], np.uint8)
  for w in range(n_w):
    pos = offsets[w]
    for j in range(n):
      pos = _write_varint(out, pos, codes[w, j])
  return out, offsets
