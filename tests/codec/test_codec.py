"""Codec unit tests: layout, Rice codes, fit, decoder, store, against slow references."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mwbx.codec import (ChannelLayout, CodecBounds, CodecError, CompressedQposStore,
                        decode_world, encode_batch, encode_batch_checked, encode_world, rice)
from mwbx.qpos_store import RawQposStore
from mwbx.testing import codec_data as testing
from mwbx.codec import fit as fit_lib
from mwbx.codec import fit_kernels
from mwbx.codec.decode import decode_code
from mwbx.codec.stream import MODE_RAW, parse
import codec_reference as ref

BOUNDS = CodecBounds()
FPS = 120.0


@pytest.fixture(scope="module")
def boxes():
  model = testing.boxes_model(3, seed=1)
  qpos = testing.record_batch(model, 4, 300, seed=2)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  frame_count = np.array([300, 1, 0, 173])
  enc = encode_batch_checked(qpos, frame_count, layout, BOUNDS, FPS, float(model.opt.gravity[2]))
  return model, qpos, frame_count, layout, enc


@pytest.fixture(scope="module")
def chain():
  model = testing.chain_model()
  qpos = testing.record_batch(model, 2, 300, seed=3)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  enc = encode_batch_checked(qpos, np.array([300, 300]), layout, BOUNDS, FPS)
  return model, qpos, layout, enc


def _errors_reference(layout, decoded, true):
  """Largest error per kind, frame by frame, rotation through rotation matrices."""
  pos = max([np.abs(decoded[f, a:a + 3].astype(np.float64) - true[f, a:a + 3]).max()
             for a in layout.pos_adr for f in range(true.shape[0])], default=0.0)
  rot = max([ref.rotation_angle(decoded[f, a:a + 4], true[f, a:a + 4])
             for a in layout.rot_adr for f in range(true.shape[0])], default=0.0)
  scalar = max([abs(float(decoded[f, a]) - float(true[f, a]))
                for a in layout.scalar_adr for f in range(true.shape[0])], default=0.0)
  return pos, rot, scalar


# -- layout and bounds -------------------------------------------------------------


def test_layout_from_joints_covers_every_joint_type():
  model = testing.chain_model()
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  assert layout.pos_adr == (0,)
  assert layout.rot_adr == (3, 7)
  assert layout.scalar_adr == (11, 12, 13)
  assert ChannelLayout.from_json(layout.to_json()) == layout


def test_layout_and_bounds_reject_bad_input():
  with pytest.raises(CodecError, match="unknown MuJoCo joint type 7"):
    ChannelLayout.from_joints([7], [0], 1)
  with pytest.raises(CodecError, match="exactly once"):
    ChannelLayout(nq=4, scalar_adr=(0, 1, 2))
  with pytest.raises(CodecError, match="e_pos"):
    CodecBounds(e_pos=0.0)
  with pytest.raises(CodecError, match="e_rot"):
    CodecBounds(e_rot=float("nan"))


# -- Rice codes ----------------------------------------------------------------------

int_lists = st.lists(st.one_of(st.integers(-40, 40), st.integers(-2**51, 2**51)), max_size=150)


@settings(max_examples=60, deadline=None)
@given(int_lists, st.sampled_from([1, 2]))
def test_rice_matches_bitwise_reference_and_roundtrips(values, version):
  blob = rice.encode_ints(np.array(values, np.int64), version)
  assert blob == ref.rice_encode_reference(values, version)
  decoded, pos = rice.decode_ints(blob + b"tail", 0, "test", max_count=len(values),
                                  version=version)
  assert pos == len(blob)
  np.testing.assert_array_equal(decoded, np.array(values, np.int64))


def test_version_1_streams_still_decode(boxes, chain):
  """Streams written with the old escape format decode to the same frames."""
  from mwbx.codec.batch import decode_batch
  from mwbx.codec.stream import serialize
  for enc in (boxes[4], chain[3]):
    old = [serialize(parse(s), version=1) for s in enc.streams]
    assert all(s[4] == 1 for s in old) and all(s[4] == 2 for s in enc.streams)
    assert sum(map(len, enc.streams)) <= sum(map(len, old))
    data = np.frombuffer(b"".join(old), np.uint8)
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in old])])
    for got, s_old, s_new in zip(decode_batch(data, offsets), old, enc.streams):
      np.testing.assert_array_equal(decode_world(s_old), decode_world(s_new))
      np.testing.assert_array_equal(got, decode_world(s_new))


def test_rice_rejects_oversized_values_and_counts():
  with pytest.raises(CodecError, match="too large"):
    rice.encode_ints(np.array([2**60]))
  blob = rice.encode_ints(np.arange(10))
  with pytest.raises(CodecError, match="claims 10 values"):
    rice.decode_ints(blob, 0, "test", max_count=5)


# -- fit kernels ---------------------------------------------------------------------


def _window(x, p_s, s, t_end, e, step, quad):
  """Integer velocities keeping frames s+1..t_end within e (float64 loops)."""
  lo, hi = -np.inf, np.inf
  for t in range(s + 1, t_end + 1):
    tau = t - s
    r = x[t] - p_s - quad * tau * tau
    lo, hi = max(lo, (r - e) / (tau * step)), min(hi, (r + e) / (tau * step))
  return np.ceil(lo), np.floor(hi)


# The encoder's compiled fit and the JAX reference it is written after.
FITS = {"compiled": fit_kernels, "jax": fit_lib}


@pytest.mark.parametrize("fit", FITS)
@pytest.mark.parametrize("use_quad", [False, True])
def test_linear_fit_segments_are_within_bound_and_maximal(use_quad, fit):
  rng = np.random.default_rng(5)
  n, e, step, quad = 200, 1e-3, 1e-3 / 64, -3.4e-4
  t = np.arange(n)
  # A random walk, optionally on a parabola (more, shorter segments).
  x = np.cumsum(rng.normal(0, 2e-3, n)) + (quad * t * t if use_quad else 0.0)
  x = (x - x[0]).astype(np.float32)
  res = FITS[fit].fit_linear_batch(x[None, :, None], np.array([n], np.int32),
                                 np.array([e], np.float32), np.float32(step), np.float32(quad),
                                 np.int32(0), np.int32(0), gravity=False)
  ends = np.flatnonzero(np.asarray(res.ends[0]))
  vel = np.asarray(res.vel[0, :, 0])
  assert ends[-1] == n - 1
  s, p_s = 0, np.float32(0.0)
  f32 = np.float32
  for end in ends:
    # gravity=False fits a pure linear model; small slack covers float32 starts.
    lo, hi = _window(x.astype(np.float64), float(p_s), s, end, e * (1 + 1e-3), step, 0.0)
    assert lo <= vel[end] <= hi
    if end < n - 1:
      lo, hi = _window(x.astype(np.float64), float(p_s), s, end + 1, e * (1 - 1e-3), step, 0.0)
      assert lo > hi, "the greedy fit stopped although the segment could be extended"
    p_s = f32(p_s + f32(f32(end - s) * f32(vel[end])) * f32(step))
    s = end


@pytest.mark.parametrize("fit", FITS)
def test_rotation_fit_respects_angle_bound(fit):
  rng = np.random.default_rng(6)
  n = 150
  omega = rng.normal(0, 0.05, (n, 3)).cumsum(axis=0) * 0.1
  q = np.stack([ref.quat_exp(w) for w in np.cumsum(omega, axis=0)]).astype(np.float32)
  e = BOUNDS.e_rot * (1 - 1e-3)
  step = BOUNDS.e_rot / 64
  res = FITS[fit].fit_rotation_batch(q[None], np.array([n], np.int32), np.array([e], np.float32),
                                     np.float32(step), np.int32(5))
  ends = np.flatnonzero(np.asarray(res.ends[0]))
  vel = np.asarray(res.vel[0])
  s, q_s = 0, q[0].astype(np.float64)
  worst = 0.0
  for end in ends:
    for tau in range(1, end - s + 1):
      dec = ref.quat_mul(ref.quat_exp(tau * vel[end] * step), q_s)
      worst = max(worst, ref.rotation_angle(dec, q[s + tau]))
    q_s = ref.quat_mul(ref.quat_exp((end - s) * vel[end] * step), q_s)
    s = end
  assert worst <= BOUNDS.e_rot


@pytest.mark.parametrize("fit", FITS)
def test_rotation_fit_uses_the_whole_error_ball(fit):
  # A spin about z (on every velocity lattice) seen with a constant offset of
  # 0.8 e_rot about x from frame 1 on. Zero velocity about x keeps every frame
  # within the ball (radius e_rot); within the cube of half-width e_rot / sqrt(3)
  # no velocity about x can (|a - 0.8| and |8a - 0.8| <= 0.577 have no common a).
  n = fit_lib.EXACT_SPAN + 1
  e = BOUNDS.e_rot * (1 - 1e-3)
  step = BOUNDS.e_rot / 64
  t = np.arange(n)
  omega = np.stack([0.8 * BOUNDS.e_rot * (t > 0), 0 * t, 64 * step * t], -1)
  q = np.stack([ref.quat_exp(w) for w in omega]).astype(np.float32)
  res = FITS[fit].fit_rotation_batch(q[None], np.array([n], np.int32), np.array([e], np.float32),
                                     np.float32(step), np.int32(6))
  assert np.flatnonzero(np.asarray(res.ends[0])).tolist() == [n - 1]
  vel = np.asarray(res.vel[0, n - 1])
  worst = max(ref.rotation_angle(ref.quat_mul(ref.quat_exp(tau * vel * step), q[0]), q[tau])
              for tau in range(1, n))
  assert worst <= BOUNDS.e_rot


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 0.1))
def test_stored_frame0_is_where_the_fit_starts(components):
  # The encoder fits from the frame-0 value on its grid; the stream must store
  # exactly that grid point (renormalizing it could move it by a grid step).
  from mwbx.codec.stream import initial_codes, initial_steps, quantize_initial
  codes = quantize_initial("rot", np.array([components]), BOUNDS)
  grid = codes * initial_steps(BOUNDS)["rot"]
  stored = initial_codes(grid[None], ["rot"], BOUNDS).astype(np.int64)
  assert np.array_equal((stored >> 1) ^ -(stored & 1), codes)


# -- streams and the guarantee -------------------------------------------------------


def test_simulated_boxes_meet_bounds_frame_by_frame(boxes):
  _, qpos, frame_count, layout, enc = boxes
  assert np.all(enc.raw_channels == 0)
  for w, stream in enumerate(enc.streams):
    n = frame_count[w]
    decoded = decode_world(stream)
    assert decoded.shape == (n, layout.nq) and decoded.dtype == np.float32
    pos, rot, _ = _errors_reference(layout, decoded, qpos[w, :n])
    assert pos <= BOUNDS.e_pos and rot <= BOUNDS.e_rot * (1 + 1e-6)
    np.testing.assert_allclose(enc.max_error[w, :2], [pos, rot], rtol=1e-3, atol=1e-6)


def test_articulated_chain_meets_bounds(chain):
  _, qpos, layout, enc = chain
  for w, stream in enumerate(enc.streams):
    pos, rot, scalar = _errors_reference(layout, decode_world(stream), qpos[w])
    assert pos <= BOUNDS.e_pos and rot <= BOUNDS.e_rot * (1 + 1e-6)
    assert scalar <= BOUNDS.e_scalar


def test_vectorized_decoder_matches_frame_by_frame_reference(boxes, chain):
  for stream in boxes[4].streams + chain[3].streams:
    code = parse(stream)
    np.testing.assert_allclose(decode_code(code), ref.decode_reference(code), atol=2e-6)


def test_decoded_quaternions_are_unit(boxes):
  _, _, _, layout, enc = boxes
  decoded = decode_world(enc.streams[0])
  for a in layout.rot_adr:
    np.testing.assert_allclose(np.linalg.norm(decoded[:, a:a + 4], axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("start,stop", [(0, None), (5, 17), (250, 400), (-10, None), (40, 40)])
def test_time_range_decode_equals_slice(boxes, start, stop):
  stream = boxes[4].streams[0]
  np.testing.assert_array_equal(decode_world(stream, start, stop), decode_world(stream)[start:stop])


def test_compression_is_substantial_on_free_flight(boxes):
  _, qpos, _, _, enc = boxes
  assert 20 * len(enc.streams[0]) < qpos[0].nbytes


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_input_is_one_clear_error(value):
  model = testing.boxes_model(2, seed=3)
  qpos = testing.record(model, 64, seed=4)
  qpos[30:, 8] = value
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  batch = np.stack([testing.record(model, 64, seed=5), qpos])
  with pytest.raises(CodecError, match=rf"world 1 .* is {value} at frame 30, column 8"):
    encode_batch_checked(batch, np.array([64, 64]), layout, BOUNDS)
  # frames past a world's count are not part of it
  enc = encode_batch_checked(batch, np.array([64, 30]), layout, BOUNDS)
  np.testing.assert_array_equal(np.isfinite(decode_world(enc.streams[1])), True)


def test_encode_world_matches_batch_and_rejects_bad_shapes(boxes):
  _, qpos, _, layout, enc = boxes
  assert encode_world(qpos[0], layout, BOUNDS, FPS, -9.81) == enc.streams[0]
  assert encode_batch(qpos[:1], np.array([300]), layout, BOUNDS, FPS, -9.81) == enc.streams[:1]
  with pytest.raises(CodecError, match="nq="):
    encode_world(qpos[0, :, :5], layout, BOUNDS)
  with pytest.raises(CodecError, match="frame_count"):
    encode_batch(qpos, np.array([1, 2]), layout, BOUNDS)
  with pytest.raises(CodecError, match="frame_count entries"):
    encode_batch(qpos, np.array([1, 2, 3, 999]), layout, BOUNDS)


# -- the store -------------------------------------------------------------------------


def test_store_append_frames_state_restore(boxes):
  model, qpos, frame_count, layout, enc = boxes
  store = CompressedQposStore.from_model(model, BOUNDS, FPS)
  store.append(qpos[:2], frame_count[:2])
  store.append(qpos[2:], frame_count[2:])
  assert store.n_worlds == 4
  assert store.data.dtype == np.uint8 and store.offsets.dtype == np.int64
  for w in range(4):
    np.testing.assert_array_equal(store.row_frames(w), decode_world(enc.streams[w]))
  np.testing.assert_array_equal(store.row_frames(0, 10, 20), store.row_frames(0)[10:20])
  arrays, meta = store.state()
  again = CompressedQposStore.restore({k: v.copy() for k, v in arrays.items()}, meta)
  np.testing.assert_array_equal(again.row_frames(3), store.row_frames(3))
  stats = again.stats()
  assert stats["ratio_vs_float32"] > 10
  assert 0 < stats["max_error_pos_m"] <= BOUNDS.e_pos
  assert 0 < stats["max_error_rot_deg"] <= np.rad2deg(BOUNDS.e_rot)
  both = store.copy()
  both.extend(again)
  assert both.n_worlds == 8 and store.n_worlds == 4
  np.testing.assert_array_equal(both.row_frames(7), store.row_frames(3))
  # Several stores at once are as one after another, the store extended first included.
  many, one_by_one = store.take([1, 2]), store.take([1, 2])
  parts = [store.take([3]), again.copy(), store.empty(), store.take([0, 2])]
  many.extend(*parts)
  for part in parts:
    one_by_one.extend(part)
  assert many.n_worlds == 2 + 1 + 4 + 0 + 2
  for name, array in one_by_one.state()[0].items():
    np.testing.assert_array_equal(many.state()[0][name], array, err_msg=name)
  raw, raw_one_by_one = RawQposStore(qpos.shape[2]), RawQposStore(qpos.shape[2])
  raw.append(qpos[:1], frame_count[:1])
  raw_one_by_one.append(qpos[:1], frame_count[:1])
  raw_parts = [RawQposStore(qpos.shape[2]) for _ in range(3)]
  for k, part in enumerate(raw_parts):
    part.append(qpos[k:k + 2], frame_count[k:k + 2])
  raw.extend(*raw_parts)
  for part in raw_parts:
    raw_one_by_one.extend(part)
  np.testing.assert_array_equal(raw.offsets, raw_one_by_one.offsets)
  np.testing.assert_array_equal(raw.row_frames(6), qpos[3, :frame_count[3]])


def test_store_reports_corrupt_stream_with_its_row(boxes):
  model, qpos, frame_count, _, _ = boxes
  store = CompressedQposStore.from_model(model, BOUNDS, FPS)
  store.append(qpos[:1], frame_count[:1])
  store.data[store.offsets[1] // 2] ^= 0x10
  with pytest.raises(CodecError, match="row 0: corrupt stream"):
    store.row_frames(0)
  arrays, meta = store.state()
  arrays["offsets"] = arrays["offsets"] + 3
  with pytest.raises(CodecError, match="offsets"):
    CompressedQposStore.restore(arrays, meta)


# -- the batched writer and reader -------------------------------------------------------


def test_batch_writer_matches_per_world_streams(boxes):
  """Streams from the batched writer are byte for byte the per-world ones."""
  from mwbx.codec.batch import BatchCode, serialize_batch
  from mwbx.codec.stream import serialize
  _, _, _, _, enc = boxes
  codes = [parse(s) for s in enc.streams]
  assert [serialize(c) for c in codes] == enc.streams
  kinds = ("pos", "rot", "scalar")
  segs = {}
  for kind in kinds:
    parts = [c.segs[kind] for c in codes]
    segs[kind] = type(parts[0])(*(np.concatenate([getattr(p, f) for p in parts])
                                  for f in parts[0]._fields))
  batch = BatchCode(n_frames=np.array([c.n_frames for c in codes]), layout=codes[0].layout,
                    bounds=codes[0].bounds, fps=codes[0].fps, quanta=codes[0].quanta,
                    initial=np.stack([c.initial for c in codes]), segs=segs)
  assert serialize_batch(batch) == enc.streams


@pytest.mark.parametrize("start,stop", [(0, None), (3, 50), (-20, None)])
def test_batch_reader_matches_per_world_decoder(boxes, chain, start, stop):
  from mwbx.codec.batch import decode_batch
  for enc in (boxes[4], chain[3]):
    data = np.frombuffer(b"".join(enc.streams), np.uint8)
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in enc.streams])])
    for got, stream in zip(decode_batch(data, offsets, start, stop), enc.streams):
      np.testing.assert_array_equal(got, decode_world(stream, start, stop))


def test_batch_reader_falls_back_and_names_corrupt_world(boxes):
  from mwbx.codec.batch import decode_batch
  from mwbx.codec.splice import splice_stream
  model, qpos, frame_count, layout, enc = boxes
  # A child cut short keeps the parent's channels as raw columns: the batch
  # reader leaves that world to the per-world path.
  child = encode_batch(qpos[3:4], np.array([100]), layout, BOUNDS, FPS, -9.81)[0]
  keep = np.zeros(model.nq, bool)
  keep[:7] = True
  raw_world = splice_stream(np.frombuffer(child, np.uint8), np.frombuffer(enc.streams[0], np.uint8),
                            decode_world(enc.streams[0]), keep)
  assert parse(raw_world).modes[0] == MODE_RAW
  streams = enc.streams + [raw_world]
  data = np.frombuffer(b"".join(streams), np.uint8).copy()
  offsets = np.concatenate([[0], np.cumsum([len(s) for s in streams])])
  out = decode_batch(data, offsets)
  np.testing.assert_array_equal(out[-1], decode_world(streams[-1]))
  data[offsets[2] + 20] ^= 0x40
  with pytest.raises(CodecError, match="world 2: corrupt stream"):
    decode_batch(data, offsets)


def test_store_frames_of_rows(boxes):
  model, qpos, frame_count, _, enc = boxes
  store = CompressedQposStore.from_model(model, BOUNDS, FPS)
  store.append(qpos, frame_count)
  got = store.frames_of_rows([3, 0], 10, 40)
  np.testing.assert_array_equal(got[0], store.row_frames(3, 10, 40))
  np.testing.assert_array_equal(got[1], store.row_frames(0, 10, 40))


def test_slow_drift_after_a_huge_jump_is_fitted_not_stored_raw():
  """A jump (a reset of an unstable simulation) followed by slow drift: the
  predicted velocity is huge, which must not cost the fit its precision."""
  layout = ChannelLayout(nq=1, scalar_adr=(0,))
  # Drift of half a velocity quantum per frame: long segments sit between two
  # quantized velocities, where float32 rounding of (window - prediction) misleads.
  x = np.concatenate([np.zeros(10), np.full(5, 18.0), 7.8e-6 * np.arange(300)])
  enc = encode_batch_checked(x[None, :, None].astype(np.float32), np.array([x.size]), layout,
                             BOUNDS, FPS)
  assert enc.raw_channels[0] == 0
  decoded = decode_world(enc.streams[0])[:, 0]
  assert np.abs(decoded - x.astype(np.float32)).max() <= BOUNDS.e_scalar


# -- decoding a subset of objects ------------------------------------------------------


def test_channel_subset_decodes_exactly_those_columns(boxes, chain):
  from mwbx.codec.batch import decode_batch
  for enc, layout in ((boxes[4], boxes[3]), (chain[3], chain[2])):
    data = np.frombuffer(b"".join(enc.streams), np.uint8)
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in enc.streams])])
    for columns in ([0], [layout.rot_adr[-1] + 1], list(range(layout.nq - 1, layout.nq))):
      channels = layout.channels_for(columns)
      assert channels.sum() == 1
      adr = np.concatenate([np.asarray(a, np.int64)[None] + np.arange(w) for adrs, w in
                            ((layout.pos_adr, 3), (layout.rot_adr, 4), (layout.scalar_adr, 1))
                            for a in adrs])
      widths = [w for adrs, w in ((layout.pos_adr, 3), (layout.rot_adr, 4),
                                  (layout.scalar_adr, 1)) for _ in adrs]
      starts = np.cumsum([0] + widths[:-1])
      c = int(np.flatnonzero(channels)[0])
      cols = adr[starts[c]:starts[c] + widths[c]]
      others = np.setdiff1d(np.arange(layout.nq), cols)
      batch = decode_batch(data, offsets, 2, 40, channels)
      for got, stream in zip(batch, enc.streams):
        full = decode_world(stream, 2, 40)
        one = decode_world(stream, 2, 40, channels)
        np.testing.assert_array_equal(one[:, cols], full[:, cols])
        np.testing.assert_array_equal(one[:, others], 0.0)
        np.testing.assert_array_equal(got, one)
  with pytest.raises(CodecError, match="channels has 2 entries"):
    decode_world(boxes[4].streams[0], channels=[True, False])


def test_error_kernel_matches_numpy_errors():
  """eval_kernels.max_errors against the numpy reference, NaNs included."""
  from mwbx.codec import eval_kernels
  rng = np.random.default_rng(4)
  qpos = rng.normal(size=(3, 20, 8)).astype(np.float32)
  decoded = (qpos + rng.normal(scale=1e-3, size=qpos.shape)).astype(np.float32)
  qpos[1, 4, 0] = decoded[1, 4, 0] = np.nan      # NaN in both: exact
  qpos[2, 7, 7] = np.nan                          # NaN in one: unbounded
  frame_count = np.array([20, 11, 20])
  row_off = np.concatenate([[0], np.cumsum(frame_count)])
  rows = np.concatenate([decoded[w, :n] for w, n in enumerate(frame_count)])
  got = eval_kernels.max_errors(rows, row_off, qpos, frame_count, np.array([0, 1, 2]),
                           np.array([0, 3, 7]))
  for w, n in enumerate(frame_count):
    for c, (kind, a, width) in enumerate((("pos", 0, 3), ("rot", 3, 4), ("scalar", 7, 1))):
      want = ref.max_errors_reference(kind, decoded[w, :n, a:a + width][None],
                                      qpos[w, :n, a:a + width][None])[0]
      np.testing.assert_allclose(got[w, c], want, rtol=1e-12)
  assert np.isinf(got[2, 2]) and np.isfinite(got[1, 0])


def test_constant_channels_are_one_segment_within_the_bound(boxes, chain):
  """A channel that holds one value throughout (a body asleep: bitwise the
  same every frame, anywhere off the grid) is stored as one segment at
  velocity 0 without being fitted, and still meets the bound on every frame;
  the channels beside it are fitted as before. Edge cases: a world of two
  frames, one of one frame."""
  rng = np.random.default_rng(5)
  for model, qpos, layout in ((boxes[0], boxes[1], boxes[3]), (chain[0], chain[1], chain[2])):
    qpos = qpos.copy()
    held = {0: [0], 1: list(range(len(layout.pos_adr)))}  # world -> its channels held still
    for w, channels in held.items():
      for c in channels:  # the translation channel c and, for free joints, its rotation
        a = layout.pos_adr[c] if layout.pos_adr else layout.scalar_adr[c]
        width = 3 if layout.pos_adr else 1
        qpos[w, :, a:a + width] = qpos[w, 0, a:a + width] + rng.uniform(-0.3, 0.3, width).astype(np.float32)
        if layout.rot_adr:
          r = layout.rot_adr[c]
          qpos[w, :, r:r + 4] = qpos[w, 7, r:r + 4]
    frame_count = np.array([300, 300] + [2, 1][:len(qpos) - 2])
    enc = encode_batch_checked(qpos, frame_count, layout, BOUNDS, FPS, float(model.opt.gravity[2]))
    assert np.all(enc.raw_channels == 0)
    for w, stream in enumerate(enc.streams):
      n = frame_count[w]
      pos, rot, scalar = _errors_reference(layout, decode_world(stream), qpos[w, :n])
      assert pos <= BOUNDS.e_pos and rot <= BOUNDS.e_rot * (1 + 1e-6) and scalar <= BOUNDS.e_scalar
      code = parse(stream)
      for c in held.get(w, []):
        kinds = ("pos", "rot") if layout.rot_adr else ("scalar",)
        for kind in kinds:
          segs = code.segs[kind]
          first = int(segs.seg_count[:c].sum())
          assert segs.seg_count[c] == 1 and segs.lengths[first] == n - 1, (kind, c)
          np.testing.assert_array_equal(segs.vel[first], 0)
    moving = parse(enc.streams[0]).segs["rot" if layout.rot_adr else "scalar"].seg_count
    assert moving.max() > 1  # the others are fitted as ever


# Paths on which the compiled fit (float64) may cut other segments than the
# JAX reference (float32), where a frame sits within rounding of the bound.
FIT_AGREEMENT_MIN = 0.9


def test_compiled_fit_cuts_the_segments_of_the_jax_reference():
  model = testing.boxes_model(4, seed=3)
  qpos = testing.record_batch(model, 8, 400, seed=4)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  n = np.repeat(np.array([400, 399, 250, 77, 400, 2, 321, 400]), len(layout.pos_adr))
  pos = np.concatenate([qpos[:, :, a:a + 3] for a in layout.pos_adr]).astype(np.float32)
  pos = pos - pos[:, :1]
  rot = np.concatenate([qpos[:, :, a:a + 4] for a in layout.rot_adr]).astype(np.float32)
  e = np.full(pos.shape[0], BOUNDS.e_pos * (1 - 2.0**-6), np.float32)
  step, quad = np.float32(BOUNDS.e_pos / 64), np.float32(-9.81 / 2 / FPS**2)
  same = {}
  for kind, args, kwargs in (("pos", (pos, n, e, step, quad, np.int32(5), np.int32(100)), {"gravity": True}),
                             ("rot", (rot, n, e * 5, np.float32(BOUNDS.e_rot / 64), np.int32(5)), {})):
    fits = [getattr(FITS[name], f"fit_{'linear' if kind == 'pos' else 'rotation'}_batch")(*args, **kwargs)
            for name in ("compiled", "jax")]
    ends = [np.asarray(f.ends) for f in fits]
    vel = [np.where(e_[..., None], np.asarray(f.vel), 0) for e_, f in zip(ends, fits)]
    same[kind] = np.mean((ends[0] == ends[1]).all(axis=1) & (vel[0] == vel[1]).all(axis=(1, 2)))
    assert ends[0].sum() > 2 * ends[0].shape[0]  # the paths move: several segments each
    # where they differ, by a segment or two (a cut a frame earlier or later)
    assert np.abs(ends[0].sum(axis=1).astype(int) - ends[1].sum(axis=1)).max() <= 2
  assert min(same.values()) >= FIT_AGREEMENT_MIN, same
