"""Slow, obvious references for the codec tests (plain Python loops)."""

from __future__ import annotations

import math

import numpy as np

from mwbx.codec import rice


def rice_encode_reference(values, version: int = 2) -> bytes:
  """Same format as ``rice.encode_ints``, written bit by bit."""
  values = [int(v) for v in values]
  out = bytearray(rice.write_varint(len(values)))
  if not values:
    return bytes(out)
  qmax = rice.QMAX_V1 if version == 1 else rice.QMAX
  us = [(v << 1) if v >= 0 else ((-v) << 1) - 1 for v in values]
  blocks = [us[i:i + rice.BLOCK] for i in range(0, len(us), rice.BLOCK)]

  def exp_golomb(x):  # order 0: N zeros, then the N + 1 bits of x + 1
    bits = format(x + 1, "b")
    return "0" * (len(bits) - 1) + bits

  def value_bits(u, k):
    q = u >> k
    if q < qmax:
      return q + 1 + k
    return qmax + 1 + 64 if version == 1 else qmax + len(exp_golomb(q - qmax)) + k

  ks = []
  for block in blocks:
    k0 = (sum(block) // len(block) + 1).bit_length() - 1
    candidates = sorted({min(max(k0 + d, 0), rice.KMAX) for d in (-1, 0, 1)})
    costs = [sum(value_bits(u, k) for u in block) for k in candidates]
    ks.append(candidates[costs.index(min(costs))])
  kbits = "".join(format(k, "05b") for k in ks)
  unary, rem, esc = [], [], bytearray()
  for i, u in enumerate(us):
    k = ks[i // rice.BLOCK]
    q = u >> k
    low = format(u & ((1 << k) - 1), f"0{k}b") if k else ""
    if q < qmax:
      unary.append("1" * q + "0")
      rem.append(low)
    elif version == 1:
      unary.append("1" * qmax + "0")
      esc += u.to_bytes(8, "little")
    else:
      unary.append("1" * qmax)
      rem.append(exp_golomb(q - qmax) + low)
  unary = "".join(unary)
  rem = "".join(rem)

  def to_bytes(bits: str) -> bytes:
    bits += "0" * (-len(bits) % 8)
    return bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8))

  out += to_bytes(kbits)
  out += rice.write_varint(len(unary))
  out += to_bytes(unary)
  out += to_bytes(rem)
  out += bytes(esc)
  return bytes(out)


def quat_mul(a, b):
  aw, ax, ay, az = a
  bw, bx, by, bz = b
  return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                   aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def quat_exp(omega):
  theta = math.sqrt(sum(float(w) ** 2 for w in omega))
  if theta < 1e-12:
    return np.array([1.0, 0.5 * omega[0], 0.5 * omega[1], 0.5 * omega[2]])
  s = math.sin(theta / 2) / theta
  return np.array([math.cos(theta / 2), s * omega[0], s * omega[1], s * omega[2]])


def rotation_angle(q1, q2) -> float:
  """Angle between two rotations through rotation matrices (sign-free)."""

  def mat(q):
    q = np.asarray(q, np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])

  r = mat(q1).T @ mat(q2)
  # arccos is ill-conditioned near 0: use the skew part as well.
  skew = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
  return math.atan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(r) - 1.0))


def decode_reference(code) -> np.ndarray:
  """Frame-by-frame decode of a parsed stream (``stream.WorldCode``), float64."""
  n, lay = code.n_frames, code.layout
  out = np.zeros((n, lay.nq))
  steps = dict(zip(("pos", "rot", "scalar"), code.quanta.steps(code.bounds)))
  kinds, adrs = code.kinds(), code.addresses()
  seg_index = {"pos": 0, "rot": 0, "scalar": 0}
  chan_index = {"pos": 0, "rot": 0, "scalar": 0}
  for c, (kind, adr) in enumerate(zip(kinds, adrs)):
    width = {"pos": 3, "rot": 4, "scalar": 1}[kind]
    if code.modes[c] == 1:
      for f in range(n):
        v = code.raw[c][f].astype(np.float64)
        out[f, adr:adr + width] = v / np.linalg.norm(v) if kind == "rot" else v
      continue
    segs = code.segs[kind]
    count = int(segs.seg_count[chan_index[kind]]) if n >= 2 else 0
    chan_index[kind] += 1
    value = code.initial[c, :width].astype(np.float64)
    if kind == "rot" and n:
      value = value / np.linalg.norm(value)
    if n:
      out[0, adr:adr + width] = value
    frame = 0
    for _ in range(count):
      k = seg_index[kind]
      seg_index[kind] += 1
      length, vel = int(segs.lengths[k]), segs.vel[k].astype(np.float64)
      for tau in range(1, length + 1):
        if kind == "rot":
          v = quat_mul(quat_exp(tau * vel * steps[kind]), value)
        else:
          v = value + tau * vel * steps[kind]
          if kind == "pos" and segs.flags[k]:
            v[2] += code.quanta.quad * tau * tau
        out[frame + tau, adr:adr + width] = v
      value = out[frame + length, adr:adr + width].copy()
      frame += length
  return out


def max_errors_reference(kind: str, decoded: np.ndarray, true: np.ndarray) -> np.ndarray:
  """Per channel largest error over frames (numpy, float64); decoded/true: f[C, n, width].

  Translation and scalars: largest coordinate difference; rotation: angle of
  conj(decoded) (x) normalize(true). NaN in both is exact, NaN in one infinite.
  """
  if decoded.shape[1] == 0:
    return np.zeros(decoded.shape[0])
  d = decoded.astype(np.float64)
  x = true.astype(np.float64)
  if kind == "rot":
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
      x = np.where(norm > 0, x / norm, x)
    aw, ax, ay, az = np.moveaxis(d * np.array([1.0, -1.0, -1.0, -1.0]), -1, 0)
    bw, bx, by, bz = np.moveaxis(x, -1, 0)
    rel = np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                    aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw],
                   axis=-1)
    err = 2.0 * np.arctan2(np.linalg.norm(rel[..., 1:], axis=-1), np.abs(rel[..., 0]))
    both_nan = np.isnan(d).any(axis=-1) & np.isnan(x).any(axis=-1)
  else:
    both_nan = np.isnan(d) & np.isnan(x)
    err = np.where(both_nan, 0.0, np.abs(d - x)).max(axis=-1)
    both_nan = np.zeros(err.shape, bool)
  err = np.where(both_nan, 0.0, np.where(np.isnan(err), np.inf, err))
  return err.max(axis=1)
