"""Writing refined worlds into the bank's qpos store so that objects the
refinement never touched keep their stored path exactly.

A refined world's frames are the parent's decoded frames for those objects.
The raw store keeps them bit for bit. Re-compressing decoded data would move
it by up to the error bound again, so for the compressed store the refined
world is encoded as usual and then the coded channels (joints) of untouched
objects are replaced by the parent's own channels: verbatim when both worlds
have the same number of frames, else as raw float32 columns of the parent's
decoded values (held past the parent's last frame).
"""

from __future__ import annotations

import numpy as np

from mwbx.errors import MwbxError


def _channel_segments(code, kind: str):
  """Per fitted channel of ``kind`` (layout order): (lengths, vel, flags) slices."""
  from mwbx.codec.stream import MODE_FIT
  seg = code.segs[kind]
  kinds = code.kinds()
  chans = [c for c, k in enumerate(kinds) if k == kind]
  out, start, i = {}, 0, 0
  for c in chans:
    if code.modes[c] != MODE_FIT:
      continue
    n = int(seg.seg_count[i])
    out[c] = (seg.lengths[start:start + n], seg.vel[start:start + n], seg.flags[start:start + n])
    start += n
    i += 1
  return out


def splice_stream(new_stream: np.ndarray, parent_stream: np.ndarray, parent_frames: np.ndarray,
                  keep_qpos: np.ndarray) -> bytes:
  """A refined world's stream with the parent's channels where ``keep_qpos``.

  Args:
    new_stream: u8[n] stream of the refined world as encoded.
    parent_stream: u8[m] stream of the parent world.
    parent_frames: f32[T, nq] the parent's decoded frames.
    keep_qpos: bool[nq] qpos coordinates whose channel comes from the parent
      (whole channels: a free joint's translation and rotation are separate).
  """
  from mwbx.codec.stream import KINDS, MODE_FIT, MODE_RAW, WIDTH, Segments, parse, serialize
  new = parse(new_stream)
  parent = parse(parent_stream)
  if parent.quanta != new.quanta or parent.layout != new.layout or parent.bounds != new.bounds:
    raise MwbxError("refine: the parent's stream was coded with other codec settings")
  kinds, adrs = new.kinds(), new.addresses()
  take = [bool(keep_qpos[a]) for a in adrs]
  n = new.n_frames
  same_length = parent.n_frames == n
  modes = np.array(new.modes, np.uint8)
  initial = np.array(new.initial)
  raw = dict(new.raw)
  segs = {}
  for kind in KINDS:
    mine, theirs = _channel_segments(new, kind), _channel_segments(parent, kind)
    parts = []
    for c, k in enumerate(kinds):
      if k != kind:
        continue
      if take[c]:
        raw.pop(c, None)
        initial[c] = parent.initial[c]
        if same_length and parent.modes[c] == MODE_FIT:
          modes[c] = MODE_FIT
          parts.append(theirs[c])
        else:
          modes[c] = MODE_RAW
          idx = np.minimum(np.arange(n), len(parent_frames) - 1)
          raw[c] = parent_frames[idx, adrs[c]:adrs[c] + WIDTH[kind]].astype(np.float32)
      elif modes[c] == MODE_FIT:
        parts.append(mine[c])
    dim = new.segs[kind].vel.shape[1]
    segs[kind] = Segments(
        seg_count=np.array([len(p[0]) for p in parts], np.int64),
        lengths=np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64),
        vel=np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, dim), np.int64),
        flags=np.concatenate([p[2] for p in parts]) if parts else np.zeros(0, bool))
  code = type(new)(n_frames=n, layout=new.layout, bounds=new.bounds, fps=new.fps, quanta=new.quanta,
                   modes=modes, initial=initial, raw=raw, segs=segs)
  return serialize(code)


def store_refined(template, qpos: np.ndarray, frame_count: np.ndarray, parent_world: int,
                  parent_frames: np.ndarray, keep_qpos: np.ndarray):
  """A qpos store of the template's kind holding the refined worlds.

  Args:
    template: the bank's qpos store (raw or compressed).
    qpos: f32[W, F, nq] refined frames (padded), frame_count: i32[W].
    parent_world: bank row of the parent (its stream is reused).
    parent_frames: f32[T, nq] the parent's decoded frames.
    keep_qpos: bool[W, nq] coordinates that follow the parent exactly.
  """
  store = template
  if getattr(store, "kind", "raw") == "raw":
    from mwbx.bank import RawQposStore
    out = RawQposStore(store.nq)
    out.append(qpos, frame_count)
    return out
  from mwbx.codec import CompressedQposStore
  out = CompressedQposStore(store.layout, store.bounds, store.fps, store.gravity, store.n_bodies)
  out.append(qpos, frame_count)
  if not keep_qpos.any():
    return out
  parent_stream = template.stream(parent_world)
  streams = [splice_stream(out.stream(w), parent_stream, parent_frames, keep_qpos[w])
             if keep_qpos[w].any() else out.stream(w).tobytes() for w in range(out.n_worlds)]
  sizes = np.array([len(s) for s in streams], np.int64)
  out.data = np.frombuffer(b"".join(streams), np.uint8).copy()
  out.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
  parent_err = template.max_error[parent_world]
  out.max_error = np.maximum(out.max_error, parent_err[None, :])
  return out
