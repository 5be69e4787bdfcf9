"""Stream scanning as compiled loops: the batch headers of many streams, and
segment tables from decoded values (callers: ``batch.py``, ``stream.py``)."""

from __future__ import annotations

import numpy as np

from mwbx.codec.rice_kernels import VALUE_CAP, floor_log2, read_varint
from mwbx.codec.status import (STATUS_OK, STATUS_SEGMENT_COUNT, STATUS_SEGMENT_LENGTH, STATUS_SEGMENT_SIZE,
                               STATUS_VELOCITY)
from mwbx.host_jit import host_jit


# -- stream headers -------------------------------------------------------------------


@host_jit
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


@host_jit
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
          m = max(0, coarse[kind] - floor_log2(length))
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


