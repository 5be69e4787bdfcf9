"""The codec guarantee under widely varying motion, and decoder fuzzing."""

import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mwbx.codec import (ChannelLayout, CodecBounds, CodecError, decode_world,
                        encode_batch_checked)
from mwbx.testing import codec_data as testing

import codec_reference as ref

FPS = 120.0
GRAVITY = -9.81
# Two free bodies, a ball joint, a hinge and a slide: every channel kind.
LAYOUT = ChannelLayout.from_joints([0, 0, 1, 3, 2], [0, 7, 14, 18, 19], 20)
LINEAR = ("ballistic", "bounce", "rolling", "resting", "jitter", "far_away")
ROTATION = ("spin", "tumble", "resting", "jitter", "flip_every_frame")
SCALAR = ("ramp", "swing", "jitter", "constant")


def _translation(kind: str, n: int, rng) -> np.ndarray:
  t = np.arange(n) / FPS
  x0 = rng.uniform(-3, 3, 3)
  v0 = rng.normal(0, 4, 3)
  if kind == "ballistic":
    x = x0 + v0 * t[:, None]
    x[:, 2] += 0.5 * GRAVITY * t * t
  elif kind == "bounce":  # semi-implicit Euler with a restitution floor
    x = np.zeros((n, 3))
    p, v = x0.copy(), v0.copy()
    p[2] = abs(p[2])
    for f in range(n):
      x[f] = p
      for _ in range(4):
        v[2] += GRAVITY / (4 * FPS)
        p += v / (4 * FPS)
        if p[2] < 0:
          p[2], v[2] = -p[2], -0.7 * v[2]
          v[:2] *= 0.9
  elif kind == "rolling":
    x = x0 + v0 * t[:, None] * np.exp(-t)[:, None]
    x[:, 2] = x0[2]
  elif kind == "resting":
    x = x0 + rng.normal(0, 1e-6, (n, 3))
  elif kind == "jitter":
    x = x0 + rng.normal(0, rng.choice([1e-4, 2e-3, 5e-2]), (n, 3))
  else:  # far from the origin: float32 spacing is a visible fraction of the bound
    x = x0 * 300 + v0 * t[:, None]
  return x


def _rotation(kind: str, n: int, rng) -> np.ndarray:
  q0 = rng.normal(size=4)
  q0 /= np.linalg.norm(q0)
  if kind == "spin":
    omega = rng.normal(0, 1, 3) * rng.choice([1.0, 20.0, 300.0])
    q = np.array([ref.quat_mul(ref.quat_exp(omega * f / FPS), q0) for f in range(n)])
  elif kind == "tumble":  # angular velocity precessing about z
    omega0 = rng.normal(0, 8, 3)
    q, cur = [], q0
    for f in range(n):
      q.append(cur)
      c, s = np.cos(3 * f / FPS), np.sin(3 * f / FPS)
      w = np.array([c * omega0[0] - s * omega0[1], s * omega0[0] + c * omega0[1], omega0[2]])
      cur = ref.quat_mul(ref.quat_exp(w / FPS), cur)
    q = np.array(q).reshape(n, 4)
  elif kind == "resting":
    q = q0 + rng.normal(0, 1e-6, (n, 4))
  elif kind == "jitter":
    q = q0 + rng.normal(0, rng.choice([1e-3, 3e-2]), (n, 4))
  else:
    q = rng.normal(size=(n, 4))
  q = q.reshape(n, 4)
  # Random sign flips and norms: q and -q are the same rotation.
  return q * rng.choice([-1.0, 1.0], (n, 1)) * rng.uniform(0.9, 1.1, (n, 1))


def _scalar(kind: str, n: int, rng) -> np.ndarray:
  t = np.arange(n) / FPS
  if kind == "ramp":
    return rng.normal() + rng.normal(0, 5) * t
  if kind == "swing":
    return np.sin(rng.uniform(1, 15) * t) * rng.uniform(0.1, 3)
  if kind == "jitter":
    return rng.normal(0, 1e-2, n)
  return np.full(n, rng.normal())


def _world(n: int, kinds, seed: int) -> np.ndarray:
  rng = np.random.default_rng(seed)
  qpos = np.zeros((n, LAYOUT.nq))
  lin, rot, sca = kinds
  for j, adr in enumerate(LAYOUT.pos_adr):
    qpos[:, adr:adr + 3] = _translation(lin[j], n, rng)
  for j, adr in enumerate(LAYOUT.rot_adr):
    qpos[:, adr:adr + 4] = _rotation(rot[j], n, rng)
  for j, adr in enumerate(LAYOUT.scalar_adr):
    qpos[:, adr] = _scalar(sca[j], n, rng)
  return qpos.astype(np.float32)


def _angles(decoded: np.ndarray, true: np.ndarray) -> np.ndarray:
  """Rotation angle per frame, via the dot product of normalized quaternions."""
  d = decoded.astype(np.float64)
  t = true.astype(np.float64) / np.linalg.norm(true, axis=-1, keepdims=True)
  dot = np.clip(np.abs(np.sum(d * t, axis=-1)), 0.0, 1.0)
  return 2.0 * np.arccos(dot)


def _check_guarantee(qpos, n, stream, bounds):
  decoded = decode_world(stream)
  true = qpos[:n].astype(np.float64)
  assert decoded.shape == (n, LAYOUT.nq)
  for adr in LAYOUT.pos_adr:
    assert np.all(np.abs(decoded[:, adr:adr + 3] - true[:, adr:adr + 3]) <= bounds.e_pos)
  for adr in LAYOUT.rot_adr:
    np.testing.assert_allclose(np.linalg.norm(decoded[:, adr:adr + 4], axis=-1), 1, atol=1e-6)
    # arccos near 1 loses precision: allow the float32 rounding of the output.
    assert np.all(_angles(decoded[:, adr:adr + 4], true[:, adr:adr + 4]) <= bounds.e_rot + 1e-3 *
                  bounds.e_rot + 1e-3)
  for adr in LAYOUT.scalar_adr:
    assert np.all(np.abs(decoded[:, adr] - true[:, adr]) <= bounds.e_scalar)
  return decoded


world_kinds = st.tuples(st.lists(st.sampled_from(LINEAR), min_size=2, max_size=2),
                        st.lists(st.sampled_from(ROTATION), min_size=3, max_size=3),
                        st.lists(st.sampled_from(SCALAR), min_size=2, max_size=2))
lengths = st.one_of(st.sampled_from([0, 1, 2, 3]), st.integers(4, 250), st.just(2000))
bounds_st = st.sampled_from([CodecBounds(), CodecBounds(1e-4, 1e-3, 1e-4),
                             CodecBounds(1e-2, 0.05, 1e-2)])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=lengths, kinds=world_kinds, seed=st.integers(0, 2**31), bounds=bounds_st)
def test_decoded_error_never_exceeds_bound(n, kinds, seed, bounds):
  qpos = _world(n, kinds, seed)
  enc = encode_batch_checked(qpos[None], np.array([n]), LAYOUT, bounds, FPS, GRAVITY)
  _check_guarantee(qpos, n, enc.streams[0], bounds)
  assert np.all(enc.max_error[0] <= [bounds.e_pos, bounds.e_rot, bounds.e_scalar])


def test_batch_of_mixed_lengths_meets_bound_per_world():
  rng = np.random.default_rng(11)
  counts = np.array([0, 1, 37, 240, 5, 240])
  qpos = np.zeros((counts.size, 240, LAYOUT.nq), np.float32)
  kinds = []
  for w, n in enumerate(counts):
    k = ([rng.choice(LINEAR) for _ in range(2)], [rng.choice(ROTATION) for _ in range(3)],
         [rng.choice(SCALAR) for _ in range(2)])
    kinds.append(k)
    qpos[w, :n] = _world(int(n), k, w)
    qpos[w, n:] = 1e9  # padding must be ignored
  enc = encode_batch_checked(qpos, counts, LAYOUT, CodecBounds(), FPS, GRAVITY)
  for w, n in enumerate(counts):
    _check_guarantee(qpos[w], n, enc.streams[w], CodecBounds())


# -- fuzzing the decoder ---------------------------------------------------------------


@pytest.fixture(scope="module")
def valid_streams():
  model = testing.chain_model()
  qpos = testing.record_batch(model, 2, 90, seed=8)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  enc = encode_batch_checked(qpos, np.array([90, 2]), layout, CodecBounds(), FPS)
  return enc.streams


def _decode_or_codec_error(data: bytes):
  try:
    out = decode_world(data)
  except CodecError:
    return None
  assert out.dtype == np.float32 and out.ndim == 2
  return out


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400))
def test_random_bytes_raise_codec_error(data):
  with pytest.raises(CodecError):
    decode_world(data)
  with pytest.raises(CodecError):
    decode_world(b"MWQC\x01" + data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, 1), flips=st.lists(st.integers(0, 10**6), min_size=1, max_size=4))
def test_bit_flips_are_detected(valid_streams, which, flips):
  data = bytearray(valid_streams[which])
  for f in flips:
    data[(f // 8) % len(data)] ^= 1 << (f % 8)
  if bytes(data) == valid_streams[which]:
    return  # flips cancelled out
  with pytest.raises(CodecError):
    decode_world(bytes(data))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, 1), cut=st.integers(0, 10**6))
def test_truncated_streams_raise_codec_error(valid_streams, which, cut):
  data = valid_streams[which]
  with pytest.raises(CodecError):
    decode_world(data[:cut % len(data)])


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, 1), edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)),
                                               min_size=1, max_size=6))
def test_corruption_behind_a_valid_crc_never_crashes(valid_streams, which, edits):
  """With the CRC recomputed, the parser's own checks must reject or decode safely."""
  data = bytearray(valid_streams[which][:-4])
  for pos, value in edits:
    data[pos % len(data)] = value
  data += struct.pack("<I", zlib.crc32(data))
  _decode_or_codec_error(bytes(data))
