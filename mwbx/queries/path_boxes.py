"""Coarse boxes of every stored COM path: a volume query's first level,
answered without decoding a path.

Written with each shard (``index_boxes``) and read when a query first needs
them: per world and tracked body, the path's axis-aligned box (float32, the
extreme stored points exactly) and, per time chunk of ``chunk`` segments, the
chunk's box coded in 8 bits a side against the path's box, rounded outwards.
A volume query tests these boxes (:func:`classify`): a path whose every
in-window chunk lies outside one of the volume's planes misses, a path with
an in-window chunk wholly inside hits, and only the worlds left undecided are
decoded and tested segment by segment (:mod:`.index`), so the answers are
those of the full test. The boxes of a quickstart world are about a tenth of
its bytes on disk, a tower world's (200 bodies) under half.

On disk, one row of ``u8[w, B, row_bytes(NC)]`` per world and body
(:data:`LAYOUT`): the path box, then per chunk the codes of its corners;
code ``c`` stands for ``path_lo + (path_hi - path_lo) * c / CODE_MAX``.

Example::

  boxes = path_boxes.build(com)                    # f32[W, P, B, 3] -> PathBoxes
  state = path_boxes.classify(boxes, normals, offsets, body_mask, window)
  known, met = path_boxes.world_answers(state, body_mask, "any")
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# Segments per chunk box: 32 keeps a tower world's boxes under half its bytes on
# disk while a resting stretch (most of a path) still gets a tight box.
DEFAULT_CHUNK = 32
# Largest chunk corner code (8 bits).
CODE_MAX = 255
# Version of the stored layout (a shard's manifest entry says it).
VERSION = 1
# One stored row's byte ranges: the path box (f32 lo xyz, hi xyz), then the chunks'
# u8 codes (lo xyz, hi xyz per chunk).
LAYOUT = {"path_box": (0, 24), "chunk_codes": (24, None)}
CODES_PER_CHUNK = 6
# A path's state against a volume (classify).
HIT, MISS, UNKNOWN = np.int8(1), np.int8(-1), np.int8(0)
# Bound on the float64 rounding error of a box-plane distance, relative to the
# coordinates' and offsets' magnitudes (a few roundings of 2^-53, with room).
_SLACK_REL = 2.0**-40


class PathBoxes(NamedTuple):
  """The coarse boxes of W worlds' paths (numpy arrays).

  lo: f32[W, B, 3] path box minimum corners, metres (NaN where a point is not
    finite: such a path is never decided by its boxes).
  hi: f32[W, B, 3] path box maximum corners, metres.
  chunk_lo: u8[W, B, NC, 3] chunk box minimum corner codes.
  chunk_hi: u8[W, B, NC, 3] chunk box maximum corner codes.
  n_segments: real segments per path (P - 1, at least 1).
  chunk: segments per chunk.
  """

  lo: np.ndarray
  hi: np.ndarray
  chunk_lo: np.ndarray
  chunk_hi: np.ndarray
  n_segments: int
  chunk: int

  @property
  def n_worlds(self) -> int:
    return self.lo.shape[0]

  def take(self, rows) -> "PathBoxes":
    """The boxes of the worlds ``rows``."""
    return self._replace(lo=self.lo[rows], hi=self.hi[rows], chunk_lo=self.chunk_lo[rows],
                         chunk_hi=self.chunk_hi[rows])


def n_chunks(n_segments: int, chunk: int = DEFAULT_CHUNK) -> int:
  return -(-int(n_segments) // int(chunk))


def row_bytes(n_chunk: int) -> int:
  """Bytes of one stored (world, body) row with ``n_chunk`` chunks."""
  return LAYOUT["path_box"][1] + CODES_PER_CHUNK * n_chunk


def decode_corner(lo: np.ndarray, hi: np.ndarray, code: np.ndarray) -> np.ndarray:
  """f64 chunk corners of ``code`` (u8[..., NC, 3]) within path boxes lo, hi (f32[..., 3])."""
  lo = np.asarray(lo, np.float64)[..., None, :]
  span = np.asarray(hi, np.float64)[..., None, :] - lo
  return lo + span * (code / float(CODE_MAX))


def build(com: np.ndarray, chunk: int = DEFAULT_CHUNK) -> PathBoxes:
  """The boxes of stored COM paths.

  Args:
    com: f32[W, P, B, 3] COM polylines (``bank.com``), metres.
    chunk: segments per chunk box.

  Returns:
    PathBoxes; every stored point lies in its chunk's decoded box.
  """
  com = np.asarray(com, np.float32)
  if com.shape[1] == 1:  # one point: a zero-length segment, as the index makes it
    com = np.concatenate([com, com], axis=1)
  n_worlds, n_points, n_bodies, _ = com.shape
  n_seg = n_points - 1
  nc = n_chunks(n_seg, chunk)
  with np.errstate(invalid="ignore"):
    lo, hi = com.min(axis=1), com.max(axis=1)  # [W, B, 3]; NaN propagates
    pad = nc * chunk + 1 - n_points
    pts = np.concatenate([com, np.repeat(com[:, -1:], pad, axis=1)], axis=1) if pad else com
    body = pts[:, :-1].reshape(n_worlds, nc, chunk, n_bodies, 3)
    ends = pts[:, chunk::chunk]  # [W, NC, B, 3] the last point of each chunk
    chunk_lo = np.minimum(body.min(axis=2), ends).transpose(0, 2, 1, 3)  # [W, B, NC, 3]
    chunk_hi = np.maximum(body.max(axis=2), ends).transpose(0, 2, 1, 3)
  finite = np.isfinite(lo).all(axis=-1) & np.isfinite(hi).all(axis=-1)  # [W, B]
  return PathBoxes(lo, hi, _codes(lo, hi, chunk_lo, finite, lower=True),
                   _codes(lo, hi, chunk_hi, finite, lower=False), n_seg, int(chunk))


def _codes(lo, hi, corner, finite, lower: bool) -> np.ndarray:
  """u8 codes of chunk corners, rounded outwards: a lower corner's code
  decodes at or below it, an upper one's at or above it."""
  lo64 = np.asarray(lo, np.float64)[..., None, :]
  span = np.asarray(hi, np.float64)[..., None, :] - lo64
  with np.errstate(invalid="ignore", divide="ignore"):
    scaled = np.where(span > 0, (corner - lo64) / np.where(span > 0, span, 1.0) * CODE_MAX, 0.0)
  code = np.floor(scaled) if lower else np.ceil(scaled)
  code = np.clip(np.nan_to_num(code, nan=0.0), 0, CODE_MAX)
  decoded = decode_corner(lo, hi, code)  # as classify decodes it
  if lower:  # one step outwards wherever rounding put the decoded corner inside
    code = np.where(decoded > corner, np.maximum(code - 1, 0), code)
  else:
    code = np.where(decoded < corner, np.minimum(code + 1, CODE_MAX), code)
  code = np.where(finite[..., None, None], code, 0 if lower else CODE_MAX)
  return code.astype(np.uint8)


def pack(boxes: PathBoxes) -> np.ndarray:
  """u8[W, B, row_bytes(NC)]: the boxes as stored (:data:`LAYOUT`)."""
  n_worlds, n_bodies, nc, _ = boxes.chunk_lo.shape
  out = np.empty((n_worlds, n_bodies, row_bytes(nc)), np.uint8)
  start, end = LAYOUT["path_box"]
  path = np.concatenate([boxes.lo, boxes.hi], axis=-1).astype("<f4")
  out[..., start:end] = path.view(np.uint8).reshape(n_worlds, n_bodies, end - start)
  codes = np.concatenate([boxes.chunk_lo, boxes.chunk_hi], axis=-1)  # [W, B, NC, 6]
  out[..., LAYOUT["chunk_codes"][0]:] = codes.reshape(n_worlds, n_bodies, nc * CODES_PER_CHUNK)
  return out


def unpack(stored: np.ndarray, n_segments: int, chunk: int) -> PathBoxes:
  """The boxes :func:`pack` stored; ValueError when the shape disagrees."""
  stored = np.asarray(stored)
  nc = n_chunks(n_segments, chunk)
  if stored.dtype != np.uint8 or stored.ndim != 3 or stored.shape[2] != row_bytes(nc):
    raise ValueError(f"path boxes of shape {stored.shape} ({stored.dtype}), expected [worlds, bodies,"
                     f" {row_bytes(nc)}] bytes for {n_segments} segments in chunks of {chunk}")
  n_worlds, n_bodies, _ = stored.shape
  start, end = LAYOUT["path_box"]
  path = np.ascontiguousarray(stored[..., start:end]).view("<f4").reshape(n_worlds, n_bodies, 6)
  codes = stored[..., LAYOUT["chunk_codes"][0]:].reshape(n_worlds, n_bodies, nc, CODES_PER_CHUNK)
  return PathBoxes(path[..., :3].astype(np.float32), path[..., 3:].astype(np.float32),
                   np.ascontiguousarray(codes[..., :3]), np.ascontiguousarray(codes[..., 3:]),
                   int(n_segments), int(chunk))


def concat(parts: list[PathBoxes]) -> PathBoxes:
  """One PathBoxes of the worlds of ``parts`` (same bodies, segments and chunk)."""
  first = parts[0]
  return first._replace(**{name: np.concatenate([getattr(p, name) for p in parts])
                           for name in ("lo", "hi", "chunk_lo", "chunk_hi")})


def chunks_in_window(n_segments: int, chunk: int, window: np.ndarray) -> np.ndarray:
  """bool[NC]: chunks holding a real segment with a point in the window (segment
  units), by the arithmetic of :func:`mwbx.queries.segments.segment_ranges`."""
  nc = n_chunks(n_segments, chunk)
  k = np.arange(nc * chunk, dtype=np.float64)
  overlap = (float(window[1]) - k >= 0) & (float(window[0]) - k <= 1) & (k < n_segments)
  return overlap.reshape(nc, chunk).any(axis=1)


def classify(boxes: PathBoxes, normals, offsets, body_mask, window) -> np.ndarray:
  """Which paths the boxes decide against a convex volume.

  Args:
    boxes: the paths' boxes.
    normals: f32[F, 3] unit outward plane normals.
    offsets: f64[B, F] plane offsets per body, sphere radius added.
    body_mask: bool[B] bodies to test (others: MISS).
    window: f64[2] time window in segment units.

  Returns:
    i8[W, B]: HIT (an in-window chunk lies wholly inside the volume), MISS
    (every in-window chunk lies outside one of its planes) or UNKNOWN; each
    decision is the one the exact segment test makes.
  """
  n_worlds, n_bodies = boxes.lo.shape[:2]
  out = np.full((n_worlds, n_bodies), MISS, np.int8)
  chosen = np.flatnonzero(np.asarray(body_mask, bool))
  if chosen.size == 0 or n_worlds == 0:
    return out
  normals = np.asarray(normals, np.float32).astype(np.float64)
  offsets = np.asarray(offsets, np.float64)[chosen]  # [b, F]
  lo = boxes.lo[:, chosen].astype(np.float64)  # [W, b, 3]
  hi = boxes.hi[:, chosen].astype(np.float64)
  finite = np.isfinite(lo).all(axis=-1) & np.isfinite(hi).all(axis=-1)
  coords = np.abs(np.concatenate([lo[finite], hi[finite]])) if finite.any() else np.zeros((1, 3))
  extent = float(coords.max(initial=0.0))
  tol = _SLACK_REL * (np.abs(normals).sum(axis=1)[None, :] * extent + np.abs(offsets))  # [b, F]

  # Level 1, the whole path: outside one plane -> MISS for every chunk.
  path_out = np.zeros(lo.shape[:2], bool)
  for f, n in enumerate(normals):
    path_out |= _near(lo, hi, n) - offsets[:, f] > tol[:, f]
  state = np.where(finite & path_out, MISS, UNKNOWN).astype(np.int8)
  world, body = np.nonzero(finite & ~path_out)
  if world.size:  # level 2, the chunks of the paths left
    clo = decode_corner(lo[world, body], hi[world, body], boxes.chunk_lo[world, chosen[body]])  # [n, NC, 3]
    chi = decode_corner(lo[world, body], hi[world, body], boxes.chunk_hi[world, chosen[body]])
    off, t = offsets[body][:, None, :], tol[body][:, None, :]  # [n, 1, F]
    outside = np.zeros(clo.shape[:2], bool)
    inside = np.ones(clo.shape[:2], bool)
    for f, n in enumerate(normals):
      outside |= _near(clo, chi, n) - off[..., f] > t[..., f]
      inside &= _near(chi, clo, n) - off[..., f] < -t[..., f]  # the far corner
    live = chunks_in_window(boxes.n_segments, boxes.chunk, window)[None, :]
    verdict = np.where((inside & live).any(axis=1), HIT,
                       np.where((outside | ~live).all(axis=1), MISS, UNKNOWN))
    state[world, body] = verdict
  out[:, chosen] = state
  return out


def _near(lo: np.ndarray, hi: np.ndarray, n: np.ndarray) -> np.ndarray:
  """n·p at the corner of boxes [lo, hi] that minimises it (swap lo and hi:
  the corner that maximises it), summed as the exact test sums."""
  c = [np.where(n[i] > 0, lo[..., i], hi[..., i]) * n[i] for i in range(3)]
  return (c[0] + c[1]) + c[2]


def world_answers(state: np.ndarray, body_mask, mode: str) -> tuple[np.ndarray, np.ndarray]:
  """Per world, whether the boxes decide a query and its answer (before its sign).

  Args:
    state: i8[W, B] from :func:`classify`.
    body_mask: bool[B] the query's bodies.
    mode: "any" (one selected body meets the volume) or "all".

  Returns:
    (known: bool[W], met: bool[W], meaningful where known).
  """
  chosen = state[:, np.asarray(body_mask, bool)]
  if mode == "any":
    met = (chosen == HIT).any(axis=1)
    known = met | (chosen == MISS).all(axis=1)
  else:
    met = (chosen == HIT).all(axis=1)
    known = met | (chosen == MISS).any(axis=1)
  return known, met
