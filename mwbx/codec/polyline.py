"""COM polylines on a grid, stored as deflated integer deltas.

The query paths (``f32[W, P, B, 3]``, metres) are rounded to a grid of step
``2·e`` once, when sampled, so every stored point is within ``e`` of the
simulated one (plus float32 rounding) and queries are exact on what is
stored. On disk a grid path is its integer grid coordinates, differenced
twice along the path (ballistic and resting stretches give near-zero
values), narrowed to the smallest integer type that holds them, and
deflated (zlib). Decoding is exact: :func:`decode` returns the same float32
array that :func:`round_to_grid` made. Paths not on the grid (banks sampled
before it) are stored as raw float32, bit for bit.
"""

from __future__ import annotations

import io
import zlib

import numpy as np

from mwbx.codec.layout import CodecError
from mwbx.host_jit import host_jit

# Grid coordinates beyond this are not encoded (float64 holds them exactly, and
# float32 products of them with the step stay on the grid).
MAX_GRID = 1 << 23


def grid_step(e_com: float | None) -> float | None:
  """The grid step for a bound ``e_com`` (metres): every point moves at most
  half a step. None (no bound): no grid, float32 paths."""
  return None if e_com is None else 2.0 * float(e_com)


def round_to_grid(points: np.ndarray, step: float | None) -> np.ndarray:
  """f32[...] points (metres) rounded to the nearest grid point, non-finite ones
  as given; ``step`` None leaves them as they are."""
  points = np.asarray(points, np.float32)
  if step is None:
    return points
  q = np.round(points.astype(np.float64) / step)
  out = (q * step).astype(np.float32)
  return np.where(np.isfinite(points), out, points)


def _grid(points: np.ndarray, step: float) -> np.ndarray | None:
  """i64 grid coordinates of ``points`` if they are exactly grid points, else None."""
  if not np.all(np.isfinite(points)):
    return None
  q = np.round(points.astype(np.float64) / step)
  if q.size and np.abs(q).max() >= MAX_GRID:
    return None
  if not np.array_equal((q * step).astype(np.float32), points):
    return None
  return q.astype(np.int64)


def _narrow(values: np.ndarray) -> np.ndarray:
  for dtype in (np.int8, np.int16, np.int32):
    if values.size == 0 or (values.min() >= np.iinfo(dtype).min and values.max() <= np.iinfo(dtype).max):
      return values.astype(dtype)
  return values


def encode(points: np.ndarray, step: float | None) -> np.ndarray:
  """u8[n]: ``points`` (f32[W, P, ...]) as deflated grid coordinates: per path
  its first point, first step and then second differences along P; deflated
  raw float32 when they are not on the grid (or ``step`` is None)."""
  points = np.ascontiguousarray(points, np.float32)
  q = _grid(points, step) if points.ndim >= 2 and step is not None else None
  step = 0.0 if step is None else step
  buf = io.BytesIO()
  if q is None:
    kind = b"R"
    np.savez(buf, raw=points)
  else:
    kind = b"G"
    first = q[:, :1]
    steps = np.diff(q, axis=1)
    rest = np.concatenate([steps[:, :1], np.diff(steps, axis=1)], axis=1)  # P - 1 values per path
    np.savez(buf, first=_narrow(first), rest=_narrow(rest))
  head = kind + np.float64(step).tobytes()
  return np.frombuffer(head + zlib.compress(buf.getvalue(), 6), np.uint8)


def decode(data: np.ndarray) -> np.ndarray:
  """The f32 array :func:`encode` was given, bit for bit; CodecError if damaged."""
  raw = np.asarray(data, np.uint8).tobytes()
  if len(raw) < 9 or raw[:1] not in (b"G", b"R"):
    raise CodecError("COM polylines: not an encoded polyline block")
  step = float(np.frombuffer(raw[1:9], np.float64)[0])
  try:
    arrays = np.load(io.BytesIO(zlib.decompress(raw[9:])), allow_pickle=False)
    if raw[:1] == b"R":
      out = np.asarray(arrays["raw"], np.float32)
    else:
      first, rest = arrays["first"], arrays["rest"]
      if (first.ndim < 2 or first.shape[1] != 1 or rest.shape[:1] + rest.shape[2:] != first.shape[:1] + first.shape[2:]
          or rest.dtype.kind != "i"):
        raise CodecError("COM polylines: corrupt block (first point and differences disagree)")
      width = int(np.prod(first.shape[2:], dtype=np.int64))
      out = np.empty((first.shape[0], rest.shape[1] + 1) + first.shape[2:], np.float32)
      _integrate(np.ascontiguousarray(first, np.int64).reshape(first.shape[0], width),
                 np.ascontiguousarray(rest).reshape(rest.shape[0], rest.shape[1], width), step,
                 out.reshape(out.shape[0], out.shape[1], width))
  except CodecError:
    raise
  except Exception as err:  # noqa: BLE001 - zlib and np.load raise many kinds on damage
    raise CodecError(f"COM polylines: corrupt block ({type(err).__name__})") from None
  return out


@host_jit
def _integrate(first, rest, step, out):
  """Grid paths from their first points (i64[W, K]) and differences
  (int[W, P - 1, K]: the first step, then second differences), in metres:
  ``out`` f32[W, P, K] (one pass; float64(q) * step rounded to float32, as
  :func:`round_to_grid` made them)."""
  n_worlds, n_rest, width = rest.shape
  q = np.empty(width, np.int64)
  velocity = np.empty(width, np.int64)
  for w in range(n_worlds):
    for k in range(width):
      q[k] = first[w, k]
      velocity[k] = 0
      out[w, 0, k] = np.float32(np.float64(q[k]) * step)
    for p in range(n_rest):
      for k in range(width):
        velocity[k] += np.int64(rest[w, p, k])
        q[k] += velocity[k]
        out[w, p + 1, k] = np.float32(np.float64(q[k]) * step)
