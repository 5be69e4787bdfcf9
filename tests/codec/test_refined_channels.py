"""Refined worlds compress only what changed: channels of objects a refined
world did not touch are the parent's own stored segments (not a new fit), so
they decode to the parent's frames bit for bit, and every channel still
decodes within the codec's bounds of its input."""

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.codec import CodecBounds, CompressedQposStore
from mwbx.codec import encode as encode_lib
from mwbx.codec.splice import ParentChannels
from mwbx.codec.stream import MODE_FIT, MODE_RAW, parse
from mwbx.testing.codec_data import record

BOUNDS = CodecBounds()
FPS = 120.0
PARENT_FRAMES = 90

# Three free boxes, a ball joint and an arm of a hinge and a slide: every
# channel kind (pos, rot, scalar).
MJCF = """<mujoco>
  <option timestep="0.0020833333333333333"/>
  <worldbody>
    <geom type="plane" size="20 20 0.1"/>
    <body name="box0" pos="-1 0 1"><freejoint/><geom type="box" size="0.1 0.08 0.06" density="500"/></body>
    <body name="box1" pos="0 0 1.5"><freejoint/><geom type="box" size="0.06 0.1 0.12" density="500"/></body>
    <body name="box2" pos="1 0 0.7"><freejoint/><geom type="box" size="0.15 0.05 0.05" density="500"/></body>
    <body name="knob" pos="0 2 1"><joint type="ball" damping="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/></body>
    <body name="arm" pos="0 -2 1"><joint name="hinge" type="hinge" axis="0 1 0" damping="0.01"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      <body name="slider" pos="0.3 0 0"><joint name="slide" type="slide" axis="1 0 0" range="-0.1 0.1"/>
        <geom type="sphere" size="0.05"/></body></body>
  </worldbody>
</mujoco>
"""
# qpos columns of each object (whole joints).
OBJECTS = {"box0": np.arange(0, 7), "box1": np.arange(7, 14), "box2": np.arange(14, 21),
           "knob": np.arange(21, 25), "arm": np.arange(25, 27)}


@pytest.fixture(scope="module")
def model():
  m = mujoco.MjModel.from_xml_string(MJCF)
  assert m.nq == 27
  return m


@pytest.fixture(scope="module")
def parent(model):
  """A store of two worlds; the parent (row 1) thrown and tumbling for 90 frames."""
  store = CompressedQposStore.from_model(model, BOUNDS, FPS)
  worlds = np.stack([record(model, PARENT_FRAMES, FPS, seed=11), record(model, PARENT_FRAMES, FPS, seed=1)])
  store.append(worlds, np.array([PARENT_FRAMES, PARENT_FRAMES]))
  assert store.raw_channels.sum() == 0
  return store, 1, store.row_frames(1)


def keep_mask(model, kept):
  keep = np.zeros(model.nq, bool)
  for name in kept:
    keep[OBJECTS[name]] = True
  return keep


def child(model, parent_frames, n, kept, seed):
  """A refined world of ``n`` frames: the objects of ``kept`` on the parent's
  decoded frames (held at its last frame past its end), the others on a
  trajectory of their own. Returns (qpos f32[n, nq], keep bool[nq])."""
  q = record(model, n, FPS, seed=seed)
  keep = keep_mask(model, kept)
  held = parent_frames[np.minimum(np.arange(n), len(parent_frames) - 1)]
  q[:, keep] = held[:, keep]
  return q, keep


def padded(frames):
  out = np.zeros((len(frames), max(len(f) for f in frames), frames[0].shape[1]), np.float32)
  for i, f in enumerate(frames):
    out[i, :len(f)] = f
  return out


def rotation_angle(a, b):
  """Angle (rad) between the rotations of quaternion rows a and b, either sign, f64."""
  a = np.asarray(a, np.float64)
  b = np.asarray(b, np.float64)
  a = a / np.linalg.norm(a, axis=-1, keepdims=True)
  b = b / np.linalg.norm(b, axis=-1, keepdims=True)
  w = np.sum(a * b, axis=-1)  # the scalar part of conj(a) * b
  v = (a[..., :1] * b[..., 1:] - b[..., :1] * a[..., 1:] - np.cross(a[..., 1:], b[..., 1:]))
  return 2 * np.arctan2(np.linalg.norm(v, axis=-1), np.abs(w))


def channel_errors(layout, decoded, true):
  """Largest error over the frames per kind: (pos m, rot rad, scalar)."""
  d, t = np.asarray(decoded, np.float64), np.asarray(true, np.float64)
  pos = max([np.abs(d[:, a:a + 3] - t[:, a:a + 3]).max() for a in layout.pos_adr], default=0.0)
  rot = max([rotation_angle(d[:, a:a + 4], t[:, a:a + 4]).max() for a in layout.rot_adr], default=0.0)
  scalar = max([np.abs(d[:, a] - t[:, a]).max() for a in layout.scalar_adr], default=0.0)
  return np.array([pos, rot, scalar])


def assert_kept(layout, got, frames, keep, spliced_raw=False, what=""):
  """Kept columns equal the parent's frames bit for bit; where they were
  spliced as raw columns the decoder renormalizes quaternions, which may move
  a component by an ulp (as tests/refinement/test_refine_kernels.py allows)."""
  rot = np.zeros(layout.nq, bool)
  for a in layout.rot_adr:
    rot[a:a + 4] = True
  exact = keep & ~rot if spliced_raw else keep
  np.testing.assert_array_equal(got[:, exact], frames[:, exact], err_msg=what)
  np.testing.assert_allclose(got[:, keep], frames[:, keep], rtol=0, atol=1.2e-7, err_msg=what)


def assert_within_bounds(layout, decoded, true, what=""):
  err = channel_errors(layout, decoded, true)
  assert err[0] <= BOUNDS.e_pos and err[1] <= BOUNDS.e_rot * (1 + 1e-6) and err[2] <= BOUNDS.e_scalar, (what, err)


# Children of the parent: (frames, kept objects, seed).
CHILDREN = [
    (PARENT_FRAMES, ("box1", "box2", "knob", "arm"), 21),  # one object refined
    (PARENT_FRAMES, ("box0", "arm"), 22),
    (130, ("box0", "box1", "knob"), 23),  # runs on past the parent's end
    (PARENT_FRAMES, (), 24),  # nothing kept
    (PARENT_FRAMES, tuple(OBJECTS), 25),  # everything kept
    (60, ("box1", "arm"), 26),  # cut short: spliced
]


@pytest.fixture(scope="module")
def refined(model, parent):
  store, row, frames = parent
  made = [child(model, frames, n, kept, seed) for n, kept, seed in CHILDREN]
  qpos = padded([q for q, _ in made])
  counts = np.array([n for n, _, _ in CHILDREN], np.int32)
  keep = np.stack([k for _, k in made])
  out = store.refined(qpos, 0, counts, row, frames, keep)
  return out, qpos, counts, keep


def test_children_decode_within_bounds_and_keep_the_parent_exactly(model, parent, refined):
  """Every child's every channel is within the bounds of its input; kept
  channels are the parent's decoded frames bit for bit over the parent's
  span (the child cut short is spliced raw: quaternions to an ulp)."""
  store, row, frames = parent
  out, qpos, counts, keep = refined
  assert out.n_worlds == len(CHILDREN)
  np.testing.assert_array_equal(out.frame_count, counts)
  decoded = out.frames_of_rows(None)
  for w, (n, kept, _) in enumerate(CHILDREN):
    got = decoded[w]
    assert got.shape == (n, model.nq)
    np.testing.assert_array_equal(got, out.row_frames(w))
    assert_within_bounds(out.layout, got, qpos[w, :n], f"child {w}")
    span = min(n, PARENT_FRAMES)
    assert_kept(out.layout, got[:span], frames[:span], keep[w], n < PARENT_FRAMES, f"child {w}")
    # The store's recorded error bound covers this world's.
    assert (out.max_error[w] <= [BOUNDS.e_pos, BOUNDS.e_rot * (1 + 1e-6), BOUNDS.e_scalar]).all()
    assert (out.max_error[w] >= store.max_error[row]).all()


def test_children_given_from_their_restart_frame_store_the_same_bytes(model, parent):
  """Frames from the restart on (the parent's before it) code exactly as the
  whole frames do, though only the fitted channels' columns are filled."""
  store, row, frames = parent
  first = 20
  chosen = [CHILDREN[i] for i in (0, 1, 4)]  # each keeps the arm: its channels are never read
  made = [child(model, frames, n, kept, seed) for n, kept, seed in chosen]
  qpos = padded([q for q, _ in made])
  qpos[:, :first] = frames[:first]  # the children share the parent's frames before the restart
  counts = np.array([n for n, _, _ in chosen], np.int32)
  keep = np.stack([k for _, k in made])
  assert keep.all(axis=0).any() and not keep.all()
  whole = store.refined(qpos, 0, counts, row, frames, keep)
  given = qpos[:, first:].copy()
  given[:, :, keep.all(axis=0)] = np.nan  # never read
  after = store.refined(given, first, counts, row, frames, keep)
  np.testing.assert_array_equal(after.data, whole.data)
  np.testing.assert_array_equal(after.max_error, whole.max_error)
  with pytest.raises(mwbx.codec.CodecError, match="column 3 is fitted but not given"):
    encode_lib.encode_batch_checked(qpos[:, :, :3], counts, store.layout, BOUNDS, FPS, columns=np.arange(3))


def test_longer_child_holds_the_parent_past_its_end(model, parent, refined):
  """A child running past the parent's end decodes its kept channels to the
  parent's last frame (within the bounds) after the parent's span."""
  _, _, frames = parent
  out, qpos, counts, keep = refined
  w = 2
  got = out.row_frames(w)
  cols = keep[w]
  tail = got[PARENT_FRAMES:, :]
  held = np.broadcast_to(frames[-1], (len(tail), model.nq))
  assert_within_bounds(out.layout, np.where(cols, tail, held), held, "held tail")
  # The kept channels come from the parent verbatim, fitted, not raw.
  code = parse(out.stream(w))
  adrs = np.asarray(code.addresses())
  assert all(code.modes[c] == MODE_FIT for c in np.flatnonzero(cols[adrs]))


def test_refined_channels_are_the_fit_of_the_child_alone(model, parent, refined):
  """Channels a child refined decode as the same child encoded without a
  parent: skipping the kept paths does not shift the others' segments."""
  out, qpos, counts, keep = refined
  plain = out.empty()
  plain.append(qpos, counts)
  for w in range(len(CHILDREN)):
    np.testing.assert_array_equal(out.row_frames(w)[:, ~keep[w]], plain.row_frames(w)[:, ~keep[w]],
                                  err_msg=f"child {w}")
  # Nothing kept: the very stream of a plain encoding.
  np.testing.assert_array_equal(out.stream(3), plain.stream(3))


def test_take_marks_whole_fitted_channels_of_long_enough_children(model, parent, refined):
  """ParentChannels takes kept channels the parent fitted, for children at
  least as long as it; the child cut short takes none."""
  store, row, _ = parent
  _, _, counts, keep = refined
  reuse = ParentChannels.of(store.stream(row), keep, counts)
  adrs = np.asarray(reuse.code.addresses())
  assert reuse.take.shape == (len(CHILDREN), len(adrs))
  expected = keep[:, adrs] & (counts >= PARENT_FRAMES)[:, None]
  np.testing.assert_array_equal(reuse.take, expected)


def _count_fitted_paths(monkeypatch):
  """Patches the codec's fit to record, per call, the paths of each kind it fits."""
  seen = []
  real = encode_lib._run_fits

  def spy(jobs):
    seen.append({job.kind: int(sum(len(rows) for rows in job.batches)) for job in jobs})
    return real(jobs)

  monkeypatch.setattr(encode_lib, "_run_fits", spy)
  return seen


def test_fit_cost_grows_with_the_refined_objects(model, parent, monkeypatch):
  """Children keeping all but one object fit only that object's channels:
  one translation and one rotation for a box, one scalar for a hinge, not
  the scene's 3 + 4 + 2 per child."""
  store, row, frames = parent
  made = [child(model, frames, PARENT_FRAMES, [o for o in OBJECTS if o != "box2"], 31),
          child(model, frames, PARENT_FRAMES + 20, [o for o in OBJECTS if o != "box0"], 32),
          child(model, frames, PARENT_FRAMES, [o for o in OBJECTS if o != "knob"], 33)]
  qpos = padded([q for q, _ in made])
  counts = np.array([PARENT_FRAMES, PARENT_FRAMES + 20, PARENT_FRAMES], np.int32)
  keep = np.stack([k for _, k in made])
  seen = _count_fitted_paths(monkeypatch)
  out = store.refined(qpos, 0, counts, row, frames, keep)
  assert seen == [{"pos": 2, "rot": 3, "scalar": 0}], seen
  for w in range(3):
    got = out.row_frames(w)
    assert_within_bounds(out.layout, got, qpos[w, :counts[w]], f"child {w}")
    np.testing.assert_array_equal(got[:PARENT_FRAMES, keep[w]], frames[:, keep[w]])
  seen.clear()
  store.empty().append(qpos, counts)  # the same worlds without a parent fit every channel
  assert seen == [{"pos": 9, "rot": 12, "scalar": 6}], seen


def test_parent_with_raw_channels_falls_back_to_splicing(model, parent):
  """A parent that stores some channels raw (itself a child cut short) is
  refined again: its raw channels are spliced, its fitted ones taken; both
  decode to its frames exactly, and the rest stays within the bounds."""
  store, row, frames = parent
  short, keep = child(model, frames, 60, ("box1", "arm"), 41)
  cut = store.refined(short[None], 0, np.array([60]), row, frames, keep[None])
  code = parse(cut.stream(0))
  adrs = np.asarray(code.addresses())
  raw = np.asarray(code.modes) == MODE_RAW
  np.testing.assert_array_equal(raw, keep[adrs])  # box1's and the arm's channels are raw
  both = store.copy()
  both.extend(cut)
  grand_row, grand_frames = both.n_worlds - 1, both.row_frames(both.n_worlds - 1)
  np.testing.assert_array_equal(grand_frames, cut.row_frames(0))
  kids = [child(model, grand_frames, 60, ("box1", "box2"), 42),  # raw box1, fitted box2
          child(model, grand_frames, 80, ("arm", "knob", "box0"), 43)]  # longer, raw arm
  qpos = padded([q for q, _ in kids])
  counts = np.array([60, 80], np.int32)
  keep2 = np.stack([k for _, k in kids])
  reuse = ParentChannels.of(both.stream(grand_row), keep2, counts)
  np.testing.assert_array_equal(reuse.take, keep2[:, adrs] & ~raw[None, :])
  out = both.refined(qpos, 0, counts, grand_row, grand_frames, keep2)
  for w, n in enumerate(counts):
    got = out.row_frames(w)
    assert_within_bounds(out.layout, got, qpos[w, :n], f"grandchild {w}")
    span = min(n, 60)
    assert_kept(out.layout, got[:span], grand_frames[:span], keep2[w], True, f"grandchild {w}")


def test_refinement_end_to_end_keeps_inactive_objects_exactly(quickstart_config, monkeypatch):
  """mwbx.refine of one object of a quickstart world: every child's inactive
  objects decode to the parent's stored frames bit for bit, its recorded
  errors are within the config's bounds, and the fit handles only the
  channels of the active objects of children at least as long as the parent."""
  config = quickstart_config.with_overrides(end_time=1.5, chunk_size=4)
  bank = mwbx.sample(config, 4, jax.random.key(3), backend="native")
  parent_id = 1
  parent_frames = bank.qpos_frames(parent_id)
  seen = _count_fitted_paths(monkeypatch)
  new = mwbx.refine(bank, parent_id, "ball", t_min=1.0, n_samples=4, key=jax.random.key(5), backend="native")
  assert new.n_worlds == bank.n_worlds + 4
  model = bank.model
  qpos_of = {}
  for name, bodies in bank.objects.items():
    cols = []
    for body in bodies:
      b = model.body(body)
      for j in range(int(b.jntnum[0])):
        jnt = int(b.jntadr[0]) + j
        width = {0: 7, 1: 4, 2: 1, 3: 1}[int(model.jnt_type[jnt])]
        cols.extend(range(int(model.jnt_qposadr[jnt]), int(model.jnt_qposadr[jnt]) + width))
    qpos_of[name] = np.array(cols, np.int64)
  children = new.children(parent_id)
  assert len(children) == 4
  e = config.codec
  bound = np.array([e.e_pos, np.deg2rad(e.e_rot_deg) * (1 + 1e-6), e.e_scalar])
  expected_pos_fits = 0
  n_pos = len(new.qpos_store.layout.pos_adr)
  for cid in children:
    lineage = new.lineage[str(cid)]
    assert "ball" in lineage["active"]
    inactive = [o for o in bank.objects if o not in lineage["active"]]
    assert inactive  # the quickstart's other objects: some stay untouched here
    q = new.qpos_frames(int(cid))
    span = min(len(q), len(parent_frames))
    for name in inactive:
      np.testing.assert_array_equal(q[:span, qpos_of[name]], parent_frames[:span, qpos_of[name]],
                                    err_msg=f"world {cid}, object {name}")
    row = int(np.flatnonzero(new.world_ids == cid)[0])
    assert (new.qpos_store.max_error[row] <= bound).all(), new.qpos_store.max_error[row]
    long_enough = len(q) >= len(parent_frames)
    expected_pos_fits += len(lineage["active"]) if long_enough else n_pos
  # Each quickstart object is one free joint: one translation channel each.
  assert all(len(cols) == 7 for cols in qpos_of.values())
  assert expected_pos_fits < len(children) * n_pos  # some child reuses the parent's channels
  assert sum(s.get("pos", 0) for s in seen) == expected_pos_fits, (seen, expected_pos_fits)
  assert sum(s.get("rot", 0) for s in seen) == expected_pos_fits, (seen, expected_pos_fits)
