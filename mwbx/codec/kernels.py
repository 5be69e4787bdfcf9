"""Compiled host loops of the codec: Rice coding, stream headers, evaluation.

The fit is a jitted JAX kernel (``fit.py``); what remains is byte work and
per-frame evaluation, which is sequential by nature (a unary code ends where
the next begins) and far faster as a compiled loop than as many numpy passes.
These loops run under numba with ``cache=True`` and ``nogil=True`` (a sampler
may compress in one thread while another decodes). They never raise: a problem
comes back as a status code (``STATUS_*``) and the caller turns it into a
``CodecError`` naming it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

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

STATUS_OK = 0
STATUS_TRUNCATED = 1
STATUS_COUNT = 2
STATUS_UNARY_LENGTH = 3
STATUS_UNARY_CODES = 4
STATUS_UNARY_TOO_LONG = 5
STATUS_BLOB_LENGTH = 6
STATUS_VALUE_RANGE = 7
STATUS_HEADER = 8
STATUS_SEGMENT_COUNT = 9
STATUS_SEGMENT_SIZE = 10
STATUS_SEGMENT_LENGTH = 11
STATUS_VELOCITY = 12

STATUS_TEXT = {
    STATUS_TRUNCATED: "truncated stream",
    STATUS_COUNT: "too many values",
    STATUS_UNARY_LENGTH: "unary length out of range",
    STATUS_UNARY_CODES: "unary codes do not match counts",
    STATUS_UNARY_TOO_LONG: "unary code too long",
    STATUS_BLOB_LENGTH: "blob length mismatch",
    STATUS_VALUE_RANGE: "value out of range",
    STATUS_HEADER: "header does not match the batch",
    STATUS_SEGMENT_COUNT: "segment count out of range",
    STATUS_SEGMENT_SIZE: "segment data size does not match segment counts",
    STATUS_SEGMENT_LENGTH: "segment lengths do not add up to the frame count",
    STATUS_VELOCITY: "velocity out of range",
}

_jit = numba.njit(cache=True, nogil=True)


# -- bits -----------------------------------------------------------------------------


@_jit
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


@_jit
def _window(buf, bit):
  """The 40 bits from the byte holding bit offset ``bit``, big-endian (0 past the end)."""
  byte = bit >> 3
  value = np.int64(0)
  for j in range(5):
    idx = byte + j
    value = (value << 8) | (np.int64(buf[idx]) if idx < buf.size else np.int64(0))
  return value


@_jit
def _read_bits(buf, bit, width):
  """``width`` (<= 32) bits at bit offset ``bit``, most significant first."""
  return (_window(buf, bit) >> (40 - (bit & 7) - width)) & ((np.int64(1) << width) - 1)


@_jit
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


@_jit
def _flush(out, pos, acc, n_bits):
  """Write a bit writer's last partial byte, zero-padded."""
  if n_bits > 0:
    out[pos] = np.uint8((acc << (8 - n_bits)) & 0xFF)


@_jit
def _varint_size(value):
  size = 1
  while value >= 0x80:
    value >>= 7
    size += 1
  return size


@_jit
def _write_varint(out, pos, value):
  while value >= 0x80:
    out[pos] = np.uint8((value & 0x7F) | 0x80)
    value >>= 7
    pos += 1
  out[pos] = np.uint8(value)
  return pos + 1


@_jit
def _zigzag(v):
  return (v << 1) ^ (v >> 63)


@_jit
def _floor_log2(x):
  n = -1
  while x > 0:
    x >>= 1
    n += 1
  return n


# -- Rice coding ----------------------------------------------------------------------


@_jit
def _exp_golomb_bits(x):
  """Length of the order-0 exp-Golomb code of x >= 0."""
  return 2 * _floor_log2(x + 1) + 1


@_jit
def _value_bits(u, k, legacy):
  """Bits one value ``u`` costs with Rice parameter k (unary, remainder, escape)."""
  q = u >> k
  if legacy:
    return QMAX_V1 + 1 + 64 if q >= QMAX_V1 else q + 1 + k
  return QMAX + _exp_golomb_bits(q - QMAX) + k if q >= QMAX else q + 1 + k


@_jit
def _block_k(u, lo, hi, legacy):
  """Rice parameter of the values ``u[lo:hi]``: the shortest of k0 - 1, k0, k0 + 1."""
  total = np.int64(0)
  for i in range(lo, hi):
    total += u[i]
  k0 = _floor_log2(total // (hi - lo) + 1)
  best_k, best_cost = 0, np.int64(-1)
  for d in range(-1, 2):
    k = min(max(k0 + d, 0), KMAX)
    cost = np.int64(0)
    for i in range(lo, hi):
      cost += _value_bits(u[i], k, legacy)
    if best_cost < 0 or cost < best_cost:
      best_k, best_cost = k, cost
  return best_k


@_jit
def _put_wide(out, pos, acc, n_bits, value, width):
  """``_put`` for widths up to 62 bits."""
  if width > 31:
    pos, acc, n_bits = _put(out, pos, acc, n_bits, value >> 31, width - 31)
    width = 31
  return _put(out, pos, acc, n_bits, value & ((np.int64(1) << width) - 1), width)


@_jit
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
        width = _floor_log2(x)
        r_pos, r_acc, r_bits = _put_wide(out, r_pos, r_acc, r_bits, np.int64(0), width)
        r_pos, r_acc, r_bits = _put_wide(out, r_pos, r_acc, r_bits, x, width + 1)
        r_pos, r_acc, r_bits = _put(out, r_pos, r_acc, r_bits, low, k)
    _flush(out, u_pos, u_acc, u_bits)
    _flush(out, r_pos, r_acc, r_bits)
    start += n
    b += nb
  return out, offsets, STATUS_OK


@_jit
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


@_jit
def _refill(buf, end, pos, acc, n_bits):
  """Top up a bit reader to more than 48 bits (zeros past ``end``)."""
  while n_bits <= 48:
    acc = (acc << 8) | (np.int64(buf[pos]) if pos < end else np.int64(0))
    pos += 1
    n_bits += 8
  return pos, acc, n_bits


@_jit
def _take(buf, end, pos, acc, n_bits, width):
  """Read ``width`` (<= 31) bits: (value, pos, acc, n_bits)."""
  if n_bits < width:
    pos, acc, n_bits = _refill(buf, end, pos, acc, n_bits)
  n_bits -= width
  value = acc >> n_bits
  acc &= (np.int64(1) << n_bits) - 1
  return value, pos, acc, n_bits


@_jit
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


@_jit
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


@_jit
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


# -- stream headers -------------------------------------------------------------------


@_jit
def scan_headers(buf, offsets, head, signature, widths, steps):
  """The per-world part of W stream headers that share ``head`` and ``signature``.

  A stream is head | varint n_frames | signature | frame-0 values (one zigzag
  varint per component; ``widths[c]`` components of channel c, quantum
  ``steps[c]``) | Rice blob | CRC32. Returns (ok bool[W]: the stream has this
  shape, n_frames i64[W], initial f64[W, C, 4], blob_start i64[W]). CRCs are
  checked by the caller.
  """
  n_w = offsets.size - 1
  n_ch = widths.size
  ok = np.zeros(n_w, np.bool_)
  n_frames = np.zeros(n_w, np.int64)
  initial = np.zeros((n_w, n_ch, 4))
  blob_start = np.zeros(n_w, np.int64)
  for w in range(n_w):
    lo, hi = offsets[w], offsets[w + 1] - 4
    if hi - lo < head.size + signature.size + 1:
      continue
    same = True
    for j in range(head.size):
      if buf[lo + j] != head[j]:
        same = False
        break
    if not same:
      continue
    n, pos = read_varint(buf, lo + head.size, hi)
    if n < 0 or n > (1 << 24) or pos + signature.size > hi:
      continue
    for j in range(signature.size):
      if buf[pos + j] != signature[j]:
        same = False
        break
    if not same:
      continue
    pos += signature.size
    for c in range(n_ch):
      for i in range(widths[c]):
        u, pos = read_varint(buf, pos, hi)
        if u < 0 or u >= (np.int64(1) << 52):
          same = False
          break
        initial[w, c, i] = np.float64((u >> 1) ^ -(u & 1)) * steps[c]
      if not same:
        break
    if not same:
      continue
    ok[w] = True
    n_frames[w] = n
    blob_start[w] = pos
  return ok, n_frames, initial, blob_start


@_jit
def segments_from_values(values, starts, counts, n_kind, expect, g_fp, coarse):
  """Segments of W decoded Rice blobs (layout in ``stream.py``), kind by kind.

  values, starts, counts: the integers of each world's blob; n_kind: i64[3]
  channels per kind (translation, rotation, scalar); expect: i64[W] frames to
  cover (n_frames - 1); g_fp: vertical velocity gained per ballistic frame (fine
  steps * 256); coarse: i64[3] lattice exponent of a 1-frame
  segment per kind. Velocities: ``v_k = v_{k-1} + g_k + r_k * 2**m_k``.

  Returns (status, world of the first problem or -1, then per kind: seg_count
  i64[W * n_kind], lengths i64[S], vel i64[S, D], flags bool[S]).
  """
  n_w = starts.size
  n_ch = n_kind[0] + n_kind[1] + n_kind[2]
  dims = (3, 3, 1)
  n_seg = np.zeros((n_w, 3), np.int64)
  bad = -1
  status = STATUS_OK
  for w in range(n_w):
    if counts[w] < n_ch:
      status, bad = STATUS_SEGMENT_SIZE, w
      break
    c = 0
    for kind in range(3):
      for _ in range(n_kind[kind]):
        sc = values[starts[w] + c]
        c += 1
        if sc < 0 or sc > expect[w] or (sc == 0 and expect[w] > 0):
          status, bad = STATUS_SEGMENT_COUNT, w
        n_seg[w, kind] += sc
    size = n_ch
    for kind in range(3):
      size += (1 + dims[kind]) * n_seg[w, kind]
    if status == STATUS_OK and counts[w] != size:
      status, bad = STATUS_SEGMENT_SIZE, w
    if status != STATUS_OK:
      break
  totals = np.zeros(3, np.int64)
  if status == STATUS_OK:
    for kind in range(3):
      totals[kind] = n_seg[:, kind].sum()
  seg_counts = (np.zeros(n_w * n_kind[0], np.int64), np.zeros(n_w * n_kind[1], np.int64),
                np.zeros(n_w * n_kind[2], np.int64))
  lengths = (np.zeros(totals[0], np.int64), np.zeros(totals[1], np.int64),
             np.zeros(totals[2], np.int64))
  vels = (np.zeros((totals[0], 3), np.int64), np.zeros((totals[1], 3), np.int64),
          np.zeros((totals[2], 1), np.int64))
  flags = (np.zeros(totals[0], np.bool_), np.zeros(totals[1], np.bool_),
           np.zeros(totals[2], np.bool_))
  if status != STATUS_OK:
    return status, bad, seg_counts, lengths, vels, flags
  prev = np.zeros(3, np.int64)
  out_seg = np.zeros(3, np.int64)
  for w in range(n_w):
    base = starts[w]
    l_pos = base + n_ch
    r_pos = l_pos + n_seg[w, 0] + n_seg[w, 1] + n_seg[w, 2]
    c = 0
    for kind in range(3):
      dim = dims[kind]
      local = 0
      for j in range(n_kind[kind]):
        sc = values[base + c]
        c += 1
        seg_counts[kind][w * n_kind[kind] + j] = sc
        frames = 0
        prev[:] = 0
        prev_flag, prev_len = False, 0
        for _ in range(sc):
          code = values[l_pos]
          l_pos += 1
          if kind == 0:
            length, flag = (code >> 1) + 1, (code & 1) == 1
          else:
            length, flag = code + 1, False
          if length < 1 or length > expect[w]:
            return STATUS_SEGMENT_LENGTH, w, seg_counts, lengths, vels, flags
          frames += length
          m = max(0, coarse[kind] - _floor_log2(length))
          s = out_seg[kind]
          for d in range(dim):
            r = values[r_pos + d * n_seg[w, kind] + local]
            if m > 40 or abs(r) >= (VALUE_CAP >> m):
              return STATUS_VELOCITY, w, seg_counts, lengths, vels, flags
            v = prev[d] + (r << m)
            if kind == 0 and d == dim - 1 and prev_flag:
              if abs(g_fp) >= (np.int64(1) << 62) // prev_len:  # the product would overflow
                return STATUS_VELOCITY, w, seg_counts, lengths, vels, flags
              v += (prev_len * g_fp + 128) >> 8
            if abs(v) >= VALUE_CAP:
              return STATUS_VELOCITY, w, seg_counts, lengths, vels, flags
            vels[kind][s, d] = v
            prev[d] = v
          lengths[kind][s] = length
          flags[kind][s] = flag
          prev_flag, prev_len = flag, length
          out_seg[kind] += 1
          local += 1
        if sc > 0 and frames != expect[w]:
          return STATUS_SEGMENT_LENGTH, w, seg_counts, lengths, vels, flags
      r_pos += dim * n_seg[w, kind]
  return STATUS_OK, -1, seg_counts, lengths, vels, flags


# -- evaluation -----------------------------------------------------------------------


@_jit
def _channel_rows(c, n_per_world, columns, lo, hi, row_off):
  """(first column, frame range lo:hi, row of frame 0) of channel c's output."""
  w = c // n_per_world
  return columns[c % n_per_world], lo[w], hi[w], row_off[w] - lo[w]


@_jit
def eval_linear(out, initial, seg_count, lengths, vel, flags, step, quad, n_per_world, columns,
                wanted, lo, hi, row_off):
  """Write decoded linear channels (translations when ``quad`` != 0) into ``out``.

  Channel c (world ``c // n_per_world``, columns ``columns[c % n_per_world] + d``)
  starts at ``initial[c]`` and moves ``vel * step`` per frame within each of its
  segments, plus ``quad * tau**2`` on its last coordinate in flagged segments;
  segment k covers frames (start, start + L], frame 0 belongs to the first.
  Frames ``lo[w]:hi[w]`` of world w go to rows ``row_off[w]...``. Segment starts
  accumulate in float64; each frame is evaluated in float32 (the encoder
  measures the error of exactly this output).

  out: f32[rows, nq]; initial: f64[C, 4]; seg_count: i64[C]; lengths: i64[S];
  vel: i64[S, D]; flags: bool[S]; wanted: bool[C] channels to write.
  """
  dim = vel.shape[1]
  rate = np.empty(dim)
  p = np.empty(dim)
  s = 0
  for c in range(seg_count.size):
    n_seg = seg_count[c]
    col, f_lo, f_hi, row0 = _channel_rows(c, n_per_world, columns, lo, hi, row_off)
    if not wanted[c] or f_lo >= f_hi:
      s += n_seg
      continue
    if n_seg == 0:
      for f in range(f_lo, f_hi):
        for d in range(dim):
          out[row0 + f, col + d] = np.float32(initial[c, d])
      continue
    for d in range(dim):
      p[d] = initial[c, d]
    start = 0
    for j in range(s, s + n_seg):
      length = lengths[j]
      for d in range(dim):
        rate[d] = vel[j, d] * step
      first = start + 1 if j > s else 0
      last = min(start + length, f_hi - 1)
      gravity = np.float32(quad) if flags[j] else np.float32(0.0)
      for f in range(max(first, f_lo), last + 1):
        tau = np.float32(f - start)
        for d in range(dim):
          out[row0 + f, col + d] = np.float32(p[d]) + tau * np.float32(rate[d])
        if quad != 0.0:
          out[row0 + f, col + dim - 1] += gravity * tau * tau
      lf = np.float64(length)
      for d in range(dim):
        p[d] += lf * rate[d]
      if quad != 0.0 and flags[j]:
        p[dim - 1] += quad * lf * lf
      start += length
      if start >= f_hi:
        break
    s += n_seg


@_jit
def _quat_mul(a, b, out):
  out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
  out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
  out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
  out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@_jit
def eval_rotation(out, initial, seg_count, lengths, vel, step, n_per_world, columns, wanted, lo,
                  hi, row_off):
  """Write decoded rotation channels (unit quaternions w, x, y, z) into ``out``.

  Within a segment of integer rotation velocity ``w = vel * step`` (radians per
  frame about a fixed axis), frame ``start + tau`` is ``exp(tau w) (x) q_s =
  cos(a) q_s + sin(a) (0, axis) (x) q_s`` with ``a = tau |w| / 2`` and ``q_s``
  the segment's start: the channel's normalized frame-0 value, then each
  segment's end. Everything is float64 (cos(a), sin(a) advance frame by frame by
  angle addition) and rounded to float32 on output. Arguments as
  ``eval_linear`` (vel: i64[S, 3]).
  """
  q = np.empty(4)
  turned = np.empty(4)
  pure = np.zeros(4)
  s = 0
  for c in range(seg_count.size):
    n_seg = seg_count[c]
    col, f_lo, f_hi, row0 = _channel_rows(c, n_per_world, columns, lo, hi, row_off)
    if not wanted[c] or f_lo >= f_hi:
      s += n_seg
      continue
    norm = math.sqrt(initial[c, 0]**2 + initial[c, 1]**2 + initial[c, 2]**2 + initial[c, 3]**2)
    for i in range(4):
      q[i] = initial[c, i] / norm if norm > 0 else initial[c, i]
    if n_seg == 0:
      for f in range(f_lo, f_hi):
        for i in range(4):
          out[row0 + f, col + i] = np.float32(q[i])
      continue
    start = 0
    for j in range(s, s + n_seg):
      length = lengths[j]
      wx, wy, wz = vel[j, 0] * step, vel[j, 1] * step, vel[j, 2] * step
      rate = math.sqrt(wx * wx + wy * wy + wz * wz)
      if rate > 0:
        pure[1], pure[2], pure[3] = wx / rate, wy / rate, wz / rate
      else:
        pure[1] = pure[2] = pure[3] = 0.0
      _quat_mul(pure, q, turned)
      half = 0.5 * rate
      first = max(start + 1 if j > s else 0, f_lo)
      last = min(start + length, f_hi - 1)
      if first <= last:
        step_cos, step_sin = math.cos(half), math.sin(half)
        tau = first - start
        if tau == 0:
          cos_a, sin_a = 1.0, 0.0
        elif tau == 1:
          cos_a, sin_a = step_cos, step_sin
        else:
          cos_a, sin_a = math.cos(half * tau), math.sin(half * tau)
        for f in range(first, last + 1):
          for i in range(4):
            out[row0 + f, col + i] = np.float32(cos_a * q[i] + sin_a * turned[i])
          cos_a, sin_a = (cos_a * step_cos - sin_a * step_sin,
                          sin_a * step_cos + cos_a * step_sin)
      # The next segment starts at exp(L w) (x) q.
      cos_end, sin_end = math.cos(half * length), math.sin(half * length)
      for i in range(4):
        q[i] = cos_end * q[i] + sin_end * turned[i]
      start += length
      if start >= f_hi:
        break
    s += n_seg


@_jit
def max_errors(decoded, row_off, qpos, frame_count, kinds, columns):
  """Largest error per world and channel of decoded frames against the originals.

  decoded: f32[rows, nq] (world w's frames at rows ``row_off[w]...``); qpos:
  f32[W, T, nq]; kinds: i64[C] (0 translation, 1 rotation, 2 scalar); columns:
  i64[C] first qpos address. Translation and scalars: largest absolute
  difference of a coordinate; rotation: the angle between the two orientations
  (radians). NaN in both is exact, NaN in one is an infinite error. f64[W, C].
  """
  n_w = frame_count.size
  n_ch = kinds.size
  err = np.zeros((n_w, n_ch))
  for w in range(n_w):
    for f in range(frame_count[w]):
      row = row_off[w] + f
      for c in range(n_ch):
        col = columns[c]
        if kinds[c] == 1:
          d0, d1, d2, d3 = (np.float64(decoded[row, col]), np.float64(decoded[row, col + 1]),
                            np.float64(decoded[row, col + 2]), np.float64(decoded[row, col + 3]))
          x0, x1, x2, x3 = (np.float64(qpos[w, f, col]), np.float64(qpos[w, f, col + 1]),
                            np.float64(qpos[w, f, col + 2]), np.float64(qpos[w, f, col + 3]))
          nan_d = math.isnan(d0 + d1 + d2 + d3)
          nan_x = math.isnan(x0 + x1 + x2 + x3)
          if nan_d and nan_x:
            continue
          norm = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2 + x3 * x3)
          if norm > 0:
            x0, x1, x2, x3 = x0 / norm, x1 / norm, x2 / norm, x3 / norm
          # conj(d) (x) x
          r0 = d0 * x0 + d1 * x1 + d2 * x2 + d3 * x3
          r1 = d0 * x1 - d1 * x0 - d2 * x3 + d3 * x2
          r2 = d0 * x2 + d1 * x3 - d2 * x0 - d3 * x1
          r3 = d0 * x3 - d1 * x2 + d2 * x1 - d3 * x0
          e = 2.0 * math.atan2(math.sqrt(r1 * r1 + r2 * r2 + r3 * r3), abs(r0))
          if math.isnan(e):
            e = np.inf
          if e > err[w, c]:
            err[w, c] = e
        else:
          width = 3 if kinds[c] == 0 else 1
          for d in range(width):
            a = np.float64(decoded[row, col + d])
            b = np.float64(qpos[w, f, col + d])
            if math.isnan(a) and math.isnan(b):
              continue
            e = abs(a - b)
            if math.isnan(e):
              e = np.inf
            if e > err[w, c]:
              err[w, c] = e
  return err


# -- fit input ------------------------------------------------------------------------


@_jit
def finite_paths(qpos, frame_count, columns, width):
  """bool[W, C]: channel c of world w (qpos columns ``columns[c] + 0..width-1``) is
  finite over its ``frame_count[w]`` recorded frames. qpos: f32[W, T, nq]."""
  n_w, n_ch = frame_count.size, columns.size
  out = np.ones((n_w, n_ch), np.bool_)
  for w in range(n_w):
    for f in range(frame_count[w]):
      for c in range(n_ch):
        for d in range(width):
          if not math.isfinite(qpos[w, f, columns[c] + d]):
            out[w, c] = False
  return out


@_jit
def gather_paths(qpos, rows, n_ch, columns, initial, relative, finite, out):
  """Fill ``out: f32[m, T', width]`` with paths ``rows`` (path p: world p // n_ch,
  channel p % n_ch at qpos columns ``columns[p % n_ch] + d``), frames 0..T'-1.

  relative: subtract the path's ``initial: f64[P, width]`` (in float64, then
  rounded), else frame 0 becomes ``initial``. Paths that are not ``finite`` are
  left zero (their channels are stored raw).
  """
  m, t, width = out.shape
  for i in range(m):
    p = rows[i]
    if not finite[p]:
      continue
    w, col = p // n_ch, columns[p % n_ch]
    for f in range(t):
      for d in range(width):
        x = np.float64(qpos[w, f, col + d])
        out[i, f, d] = np.float32(x - initial[p, d]) if relative else np.float32(x)
    if not relative:
      for d in range(width):
        out[i, 0, d] = np.float32(initial[p, d])


@_jit
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
