"""Exact polyline-segment tests against a convex volume (a frustum).

A volume is the intersection of F closed half-spaces `n·p - off <= 0` with
unit outward normals `n: f32[F, 3]` and offsets `off: f64[F]` (metres). A
swept sphere of radius r is tested by moving every plane outward by r
(`off + r`): near edges and corners this is a slight superset of the exact
Minkowski sum, the usual frustum-culling convention.

A path is a polyline `points: f32[P, 3]` sampled at `fps` points per second;
segment k joins points k and k+1 and covers times [k, k+1] / fps. The tests
treat whole segments (one that crosses the volume with both ends outside
counts) and clip them to a time window given in segment units
`window = (w0, w1)` = (t0·fps, t1·fps), without creating new points: the part
of segment k inside the window is the parameter range
[max(w0 - k, 0), min(w1 - k, 1)].

Arithmetic is float64 on float32 inputs. Normals are float32, so every product
`n_i·x_i` is exact in float64 and the distances do not depend on whether the
compiler fuses multiply-adds; the numpy reference in the tests computes the
same expressions and gets bit-identical answers. All functions here take ONE
path (or one segment) and are vmapped by the callers. They must run with
64-bit types enabled (`jax.enable_x64(True)`), as `index.py` does.
"""

import jax
from jax import numpy as jp


def point_distances(
    points: jax.Array, normals: jax.Array, offsets: jax.Array
) -> jax.Array:
  """Signed distances of points to planes, positive outside.

  Args:
    points: f32[..., 3] positions, metres.
    normals: f32[F, 3] unit outward plane normals.
    offsets: f64[F] plane offsets (metres), sphere radius already added.

  Returns:
    f64[..., F] distances `((n0·x + n1·y) + n2·z) - off`, metres.
  """
  p = points.astype(jp.float64)[..., None, :]
  n = normals.astype(jp.float64)
  return ((p[..., 0] * n[:, 0] + p[..., 1] * n[:, 1]) + p[..., 2] * n[:, 2]) - offsets


def clip_segment(
    da: jax.Array, db: jax.Array, s0: jax.Array, s1: jax.Array
) -> tuple[jax.Array, jax.Array]:
  """Liang–Barsky clip of one segment parameter range against F planes.

  Args:
    da: f64[F] distances of the segment start to the planes.
    db: f64[F] distances of the segment end to the planes.
    s0: f64 lower end of the parameter range to consider (0 = start).
    s1: f64 upper end (1 = end).

  Returns:
    (hit, enter): bool, True if some point with parameter in [s0, s1] lies in
    the closed volume; f64 the smallest such parameter (meaningful if hit).
  """
  out_a = da > 0
  out_b = db > 0
  entering = out_a & ~out_b
  exiting = ~out_a & out_b
  crossing = entering | exiting
  # da - db is nonzero wherever the segment crosses a plane.
  s = da / jp.where(crossing, da - db, 1.0)
  enter = jp.maximum(s0, jp.max(jp.where(entering, s, -jp.inf)))
  exit_ = jp.minimum(s1, jp.min(jp.where(exiting, s, jp.inf)))
  hit = ~jp.any(out_a & out_b) & (enter <= exit_)
  return hit, enter


def segment_ranges(
    k: jax.Array, window: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Parameter ranges of segments k inside a time window.

  Args:
    k: f64[...] segment indices (whole numbers).
    window: f64[2] (w0, w1) in segment units, 0 <= w0 <= w1.

  Returns:
    (overlap: bool[...], segment k has a point in the window; s0, s1: f64[...]
    the part of the segment inside it, [max(w0 - k, 0), min(w1 - k, 1)]).
  """
  u0 = window[0] - k
  u1 = window[1] - k
  overlap = (u1 >= 0) & (u0 <= 1)
  return overlap, jp.maximum(u0, 0.0), jp.minimum(u1, 1.0)


def polyline_hits(
    points: jax.Array,
    normals: jax.Array,
    offsets: jax.Array,
    window: jax.Array,
    first_segment: jax.Array | int = 0,
    n_segments: jax.Array | int | None = None,
) -> tuple[jax.Array, jax.Array]:
  """Tests every segment of one polyline piece against one volume.

  Args:
    points: f32[S + 1, 3] consecutive polyline points, metres.
    normals: f32[F, 3] unit outward normals.
    offsets: f64[F] plane offsets with the sphere radius added, metres.
    window: f64[2] time window in segment units of the whole path.
    first_segment: index in the whole path of the first segment here.
    n_segments: segments of the whole path; segments at or beyond it are
      padding and never hit. None: all S are real.

  Returns:
    (hit: bool[S], enter: f64[S]) per segment; the entry time of segment j is
    (first_segment + j + enter[j]) / fps.
  """
  d = point_distances(points, normals, offsets)
  s = points.shape[0] - 1
  k = jp.arange(s, dtype=jp.float64) + first_segment
  overlap, s0, s1 = segment_ranges(k, window)
  hit, enter = jax.vmap(clip_segment)(d[:-1], d[1:], s0, s1)
  hit &= overlap
  if n_segments is not None:
    hit &= k < n_segments
  return hit, enter


def path_first_entry(
    points: jax.Array, normals: jax.Array, offsets: jax.Array, window: jax.Array
) -> jax.Array:
  """Earliest time (in segment units) one path is inside the volume.

  Args:
    points: f32[P, 3] the path, P >= 2.
    normals, offsets, window: as in `polyline_hits`.

  Returns:
    f64 smallest k + enter over hit segments, +inf if the path never enters.
  """
  hit, enter = polyline_hits(points, normals, offsets, window)
  k = jp.arange(points.shape[0] - 1, dtype=jp.float64)
  return jp.min(jp.where(hit, k + enter, jp.inf))
