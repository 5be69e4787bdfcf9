"""Bounds hierarchy over a bank's COM polylines and the culled query kernel.

Depth 3, as in the paper (§4.2): the path, chunks of `chunk` consecutive
segments with an axis-aligned box each, and the segments in the leaves. The
path level is implied by the chunk boxes: testing all chunk boxes of the bank
is one fused pass over a few MB, cheaper than compacting twice.

A query runs in three jitted steps:
  1. test the chunk boxes (float32) of every selected body (a `lax.cond` per
     body skips the others) against the volume, the time window and world
     validity -> candidate mask bool[B, W, NC];
  2. compact the candidates without a scatter: a prefix sum of per-path counts
     plus a search maps output slot j to (path, chunk);
  3. in blocks of `block` candidate chunks (a while loop, so any number of
     candidates is handled), gather their points and run the exact float64
     segment test of `segments.py`; OR the chunk answers into their paths.

The box test only culls when a plane separates the box by more than a bound
on its float32 rounding error (`slack`), so a chunk the exact float64 test
would hit is never dropped: culling never changes answers (the tests compare
with a brute-force reference on many random banks).
"""

from functools import partial
from typing import NamedTuple

import jax
from jax import numpy as jp
import numpy as np

from mwbx.queries import segments

# Segments per leaf chunk; 16 keeps the chunk boxes tight on 30 fps paths.
DEFAULT_CHUNK = 16
# Candidate chunks tested per block of the exact stage: about 1/64 of all
# chunks (a typical query keeps a few percent), within these bounds.
MIN_BLOCK = 128
MAX_BLOCK = 2048
# Relative bound on the float32 rounding error of a box-plane distance
# (about 6 roundings of 2^-24 each, with a factor 8 to spare).
_SLACK_REL = 2.0**-18


class PathIndex(NamedTuple):
  """Bounds hierarchy of all COM polylines of a bank (device arrays).

  Body-major, so that one body's arrays are contiguous:
  points: f32[B, W, NC*chunk + 1, 3] polylines, the last point repeated as
    padding, metres.
  box_lo: f32[B, 3, W, NC] chunk box minimum corners, metres.
  box_hi: f32[B, 3, W, NC] chunk box maximum corners, metres.
  valid: bool[W] worlds that may match (not unstable).
  n_segments: i32 real segments per path (P - 1, at least 1).
  extent: f32 largest absolute coordinate in the bank, metres (for `slack`).
  """

  points: jax.Array
  box_lo: jax.Array
  box_hi: jax.Array
  valid: jax.Array
  n_segments: jax.Array
  extent: jax.Array

  @property
  def chunk(self) -> int:
    return (self.points.shape[2] - 1) // self.n_chunks

  @property
  def n_chunks(self) -> int:
    return self.box_lo.shape[3]

  @property
  def shape(self) -> tuple[int, int]:
    """(W, B)."""
    return self.points.shape[1], self.points.shape[0]


def build_index(
    com: np.ndarray, valid: np.ndarray, chunk: int = DEFAULT_CHUNK
) -> PathIndex:
  """Builds the hierarchy from a bank's query polylines.

  Args:
    com: f32[W, P, B, 3] COM positions (bank.com), metres.
    valid: bool[W] worlds that may match.
    chunk: segments per leaf chunk.

  Returns:
    PathIndex on the default device.
  """
  com = np.asarray(com, np.float32)
  if com.shape[1] == 1:  # one point: a zero-length segment
    com = np.concatenate([com, com], axis=1)
  n_seg = com.shape[1] - 1
  n_chunks = -(-n_seg // chunk)
  points, lo, hi, extent = _build(jp.asarray(com), jp.asarray(valid, bool), n_chunks, chunk)
  return PathIndex(
      points=points,
      box_lo=lo,
      box_hi=hi,
      valid=jp.asarray(np.asarray(valid, bool)),
      n_segments=jp.asarray(n_seg, jp.int32),
      extent=extent,
  )


@partial(jax.jit, static_argnums=(2, 3))
def _build(com, valid, n_chunks: int, chunk: int):
  """Padded per-path polylines, chunk boxes and the coordinate extent."""
  w, p, b, _ = com.shape
  pts = jp.transpose(com, (2, 0, 1, 3))  # [B, W, P, 3]
  pad = n_chunks * chunk + 1 - p
  pts = jp.concatenate([pts, jp.repeat(pts[:, :, -1:], pad, axis=2)], axis=2)
  body = pts[:, :, :-1].reshape(b, w, n_chunks, chunk, 3)
  ends = pts[:, :, chunk::chunk]  # [B, W, NC, 3] last point of each chunk
  lo = jp.minimum(body.min(axis=3), ends)
  hi = jp.maximum(body.max(axis=3), ends)
  # Invalid worlds never match, and may hold NaN or huge values.
  mag = jp.abs(pts)
  mag = jp.where(valid[None, :, None, None] & jp.isfinite(mag), mag, 0.0)
  extent = jp.max(mag, initial=0.0)
  to_soa = lambda x: jp.transpose(x, (0, 3, 1, 2))  # [B, 3, W, NC]
  return pts, to_soa(lo), to_soa(hi), extent


def _box_tests(
    index: PathIndex,
    normals: jax.Array,
    offsets: jax.Array,
    body_mask: jax.Array,
    window: jax.Array,
) -> tuple[jax.Array, jax.Array]:
  """Float32 chunk-box tests against the volume.

  Returns:
    (candidates: bool[B, W, NC], chunks that may meet the volume and need the
    exact test; inside: bool[B, W], paths with a chunk wholly inside the
    volume and in the window, which therefore hit).
  """
  w, b = index.shape
  n_chunks, c = index.n_chunks, index.chunk
  off32 = offsets.astype(jp.float32)  # [B, F]
  slack = _SLACK_REL * (
      jp.sum(jp.abs(normals), axis=1)[None, :] * index.extent + jp.abs(off32)
  )
  # Chunks holding a real segment that overlaps the window (exact: the same
  # per-segment arithmetic as the leaf test, on the segment indices only).
  k = jp.arange(n_chunks * c, dtype=jp.float64)
  overlap, _, _ = segments.segment_ranges(k, window)
  overlap &= k < index.n_segments
  in_window = jp.any(overlap.reshape(n_chunks, c), axis=1)
  keep = in_window[None, :] & index.valid[:, None]  # [W, NC]

  def one_body(lo, hi, off, tol):
    """lo, hi: f32[3, W, NC]; off, tol: f32[F] -> (candidates, inside)."""
    outside = jp.zeros((w, n_chunks), bool)
    inside = jp.ones((w, n_chunks), bool)
    for f in range(normals.shape[0]):  # F <= 6, unrolled
      n = normals[f]
      pos = n > 0
      # Box corners that minimise and maximise n·p.
      near = (jp.where(pos[0], lo[0], hi[0]) * n[0]
              + jp.where(pos[1], lo[1], hi[1]) * n[1]) + jp.where(
                  pos[2], lo[2], hi[2]) * n[2]
      far = (jp.where(pos[0], hi[0], lo[0]) * n[0]
             + jp.where(pos[1], hi[1], lo[1]) * n[1]) + jp.where(
                 pos[2], hi[2], lo[2]) * n[2]
      outside |= near - off[f] > tol[f]
      inside &= far - off[f] < -tol[f]
    inside_path = jp.any(inside & keep, axis=1)
    return ~outside & keep & ~inside_path[:, None], inside_path

  def skipped(*_):
    return jp.zeros((w, n_chunks), bool), jp.zeros(w, bool)

  def per_body(i):
    # A real branch: unselected bodies cost nothing.
    return jax.lax.cond(body_mask[i], one_body, skipped,
                        index.box_lo[i], index.box_hi[i], off32[i], slack[i])

  return jax.lax.map(per_body, jp.arange(b))


def _exact_blocks(
    index: PathIndex,
    candidates: jax.Array,
    normals: jax.Array,
    offsets: jax.Array,
    window: jax.Array,
    block: int,
) -> jax.Array:
  """Exact test of all candidate chunks, block by block: bool[B, W]."""
  w, b = index.shape
  n_chunks = candidates.shape[2]
  c = index.chunk
  per_path = candidates.reshape(b * w, n_chunks)  # path = body * W + world
  counts = jp.sum(per_path, axis=1, dtype=jp.int32)
  ends = jp.cumsum(counts)  # slot j belongs to the path with ends[p] > j
  total = ends[-1]
  flat_points = index.points.reshape(w * b, -1, 3)
  steps = jp.arange(c + 1)

  def one_block(carry):
    i, hits = carry
    slot = i * block + jp.arange(block, dtype=jp.int32)
    live = slot < total
    path = jp.searchsorted(ends, slot, side="right").astype(jp.int32)
    path = jp.minimum(path, b * w - 1)
    rank = slot - (ends[path] - counts[path])
    rows = per_path[path]  # [block, NC]
    seen = jp.cumsum(rows, axis=1, dtype=jp.int32)
    chunk_id = jp.argmax(seen > rank[:, None], axis=1)
    first = chunk_id * c
    pts = flat_points[path[:, None], first[:, None] + steps[None, :]]
    body_off = offsets[path // w]  # [block, F]
    hit, _ = jax.vmap(
        segments.polyline_hits, in_axes=(0, None, 0, None, 0, None)
    )(pts, normals, body_off, window, first.astype(jp.float64), index.n_segments)
    chunk_hit = jp.any(hit, axis=1) & live
    hits = hits.at[path].max(chunk_hit)
    return i + 1, hits

  def more(carry):
    return carry[0] * block < total

  _, hits = jax.lax.while_loop(more, one_block, (0, jp.zeros(b * w, bool)))
  return hits.reshape(b, w)


def path_hits(
    index: PathIndex,
    normals: jax.Array,
    offsets: jax.Array,
    body_mask: jax.Array,
    window: jax.Array,
    block: int | None = None,
) -> jax.Array:
  """Which paths meet the volume, culled by the hierarchy.

  Args:
    index: the bank's PathIndex.
    normals: f32[F, 3] unit outward plane normals.
    offsets: f64[B, F] plane offsets per body with its sphere radius added.
    body_mask: bool[B] bodies to test; others report False.
    window: f64[2] time window in segment units, 0 <= w0 <= w1.
    block: candidate chunks per exact-test block (static); None: chosen
      from the bank size by `default_block`.

  Returns:
    bool[W, B]; False for unselected bodies and invalid worlds.
  """
  if block is None:
    block = default_block(index)
  with jax.enable_x64(True):
    return _path_hits_jit(index, normals, offsets, body_mask, window, block)


def default_block(index: PathIndex) -> int:
  """Exact-test block size for a bank: a power of two near 1/64 of its chunks."""
  w, b = index.shape
  n_chunks = w * b * index.n_chunks
  block = 1 << max(0, (n_chunks // 64 - 1).bit_length())
  return min(MAX_BLOCK, max(MIN_BLOCK, block))


def _path_hits(index, normals, offsets, body_mask, window, block):
  candidates, inside = _box_tests(index, normals, offsets, body_mask, window)
  exact = _exact_blocks(index, candidates, normals, offsets, window, block)
  return (exact | inside).T


_path_hits_jit = jax.jit(_path_hits, static_argnums=5)


def brute_force_hits(
    index: PathIndex,
    normals: jax.Array,
    offsets: jax.Array,
    body_mask: jax.Array,
    window: jax.Array,
) -> jax.Array:
  """`path_hits` without culling: every segment of every path (baseline)."""
  with jax.enable_x64(True):
    return _brute_force_jit(index, normals, offsets, body_mask, window)


def _brute_force(index, normals, offsets, body_mask, window):
  w, b = index.shape

  def one_path(points, off):
    hit, _ = segments.polyline_hits(
        points, normals, off, window, 0, index.n_segments
    )
    return jp.any(hit)

  per_world = jax.vmap(one_path, in_axes=(0, None))
  hits = jax.vmap(per_world, in_axes=(0, 0))(index.points, offsets)  # [B, W]
  return hits.T & body_mask[None, :] & index.valid[:, None]


_brute_force_jit = jax.jit(_brute_force)
