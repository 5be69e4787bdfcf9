"""Splicing streams: a refined world keeps the parent's coded channels for
the objects the refinement never touched, so their stored path is exact.

A refined world's frames are the parent's decoded frames for those objects.
The raw store keeps them bit for bit. Re-compressing decoded data would move
it by up to the error bound again, so for the compressed store the refined
world is encoded as usual and then the coded channels (joints) of untouched
objects are replaced by the parent's own channels: verbatim when both worlds
have the same number of frames, else as raw float32 columns of the parent's
decoded values (held past the parent's last frame).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mwbx.codec.decode import normalize
from mwbx.codec.layout import CodecError
from mwbx.codec.stream import (KINDS, MODE_FIT, MODE_RAW, WIDTH, Segments, WorldCode, channel_starts,
                               gravity_increment, lattice_exponent, parse, serialize)


def _channel_segments(code, kind: str):
  """Per fitted channel of ``kind`` (layout order): (lengths, vel, flags) slices."""
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


def _raw_that_decodes_to(values: np.ndarray, rotation: bool) -> np.ndarray:
  """f32[n, width] raw column values whose decoding is exactly ``values``.

  The decoder renormalizes raw quaternions, which can move a unit quaternion
  by one ulp; for such rows a neighbour within ±1 ulp per component that
  decodes back to the row is stored instead.
  """
  values = np.asarray(values, np.float32)
  if not rotation:
    return values.copy()
  decode = lambda x: normalize(x.astype(np.float64)).astype(np.float32)
  out = values.copy()
  steps = np.array(np.meshgrid(*[[-1, 0, 1]] * 4, indexing="ij")).reshape(4, -1).T
  for row in np.flatnonzero(np.any(decode(values) != values, axis=1)):
    y = values[row]
    up, down = np.nextafter(y, np.float32(np.inf)), np.nextafter(y, np.float32(-np.inf))
    cand = np.where(steps > 0, up, np.where(steps < 0, down, y)).astype(np.float32)
    ok = np.flatnonzero(np.all(decode(cand) == y, axis=1))
    if ok.size:
      out[row] = cand[ok[0]]
  return out


def _extended(channel, extra: int, kind: str, code):
  """A parent channel's (lengths, vel, flags) held for ``extra`` more frames.

  The extra segment's velocity is the lattice point nearest zero (the
  lattice depends on the segment's length and the gravity increment of a
  ballistic previous segment), so the hold drifts by less than one
  displacement quantum; the parent's own frames decode exactly as before.
  """
  lengths, vel, flags = channel
  if extra == 0 or len(lengths) == 0:
    return channel
  coarse = code.quanta.coarse()[kind]
  m = int(lattice_exponent(np.array([extra]), coarse)[0])
  base = vel[-1].copy()
  if kind == "pos":
    all_len = np.concatenate([lengths, [extra]])
    all_flags = np.concatenate([flags, [False]])
    first = channel_starts(np.array([len(all_len)]))
    base[-1] += gravity_increment(all_flags, all_len, first, code.quanta.g_fp(code.bounds))[-1]
  step = 1 << m
  new_vel = base + np.round(-base / step).astype(np.int64) * step
  return (np.concatenate([lengths, [extra]]), np.concatenate([vel, new_vel[None]]),
          np.concatenate([flags, [False]]))


def splice_stream(new_stream: np.ndarray, parent_stream: np.ndarray, parent_frames: np.ndarray,
                  keep_qpos: np.ndarray, parent_channel=None) -> bytes:
  """A refined world's stream with the parent's channels where ``keep_qpos``.

  Args:
    new_stream: u8[n] stream of the refined world as encoded.
    parent_stream: u8[m] stream of the parent world.
    parent_frames: f32[T, nq] the parent's decoded frames, in the new
      stream's qpos layout.
    keep_qpos: bool[nq] qpos coordinates whose channel comes from the parent
      (whole channels: a free joint's translation and rotation are separate).
    parent_channel: optional i64[C] per channel of the new stream, the
      parent's channel holding the same coordinates (-1: none), when the
      parent was coded in an earlier scene version's layout
      (:func:`channel_map`); default: the same layout, channel for channel.
  """
  new = parse(new_stream)
  parent = parse(parent_stream)
  same_layout = parent_channel is None
  if parent.quanta != new.quanta or parent.bounds != new.bounds or (same_layout and parent.layout != new.layout):
    raise CodecError("splice: the parent's stream was coded with other codec settings")
  kinds, adrs = new.kinds(), new.addresses()
  source = list(range(len(kinds))) if same_layout else [int(c) for c in parent_channel]
  take = [bool(keep_qpos[a]) and source[c] >= 0 for c, a in enumerate(adrs)]
  n = new.n_frames
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
        p = source[c]
        raw.pop(c, None)
        initial[c] = parent.initial[p]
        if n >= parent.n_frames and parent.modes[p] == MODE_FIT:
          modes[c] = MODE_FIT
          parts.append(_extended(theirs[p], n - parent.n_frames, kind, parent))
        else:
          modes[c] = MODE_RAW
          idx = np.minimum(np.arange(n), len(parent_frames) - 1)
          raw[c] = _raw_that_decodes_to(parent_frames[idx, adrs[c]:adrs[c] + WIDTH[kind]], kind == "rot")
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


def channel_map(new_layout, old_layout) -> np.ndarray:
  """i64[C_new]: per channel of ``new_layout`` (stream order), the channel of
  ``old_layout`` coding the same qpos coordinates, -1 where none does. A later
  scene version that appends objects after the bank's keeps the old qpos as
  its prefix, so every old channel has its twin.

  Args:
    new_layout, old_layout: :class:`mwbx.codec.layout.ChannelLayout`.
  """
  def order(layout):
    return [(k, int(a)) for k in KINDS for a in getattr(layout, f"{k}_adr")]
  old = {entry: c for c, entry in enumerate(order(old_layout))}
  return np.array([old.get(entry, -1) for entry in order(new_layout)], np.int64)


class ParentChannels(NamedTuple):
  """Channels refined worlds take from their parent's stream instead of a fit
  (:func:`mwbx.codec.encode.encode_batch_checked`'s ``parent``).

  Attributes:
    code: the parent's parsed stream (:func:`mwbx.codec.stream.parse`), in
      the refined worlds' layout.
    take: bool[W, C] per refined world and channel (stream order): the
      parent's segments, held past its last frame, stand for the channel.
  """

  code: WorldCode
  take: np.ndarray

  @classmethod
  def of(cls, parent_stream: np.ndarray, keep_qpos: np.ndarray, frame_count: np.ndarray) -> "ParentChannels":
    """The channels of ``keep_qpos`` (bool[W, nq]) each refined world can take
    verbatim: fitted in the parent, and the world at least as long as it
    (frame_count: i[W]); the others are fitted (and spliced raw if kept)."""
    code = parse(parent_stream)
    adrs = np.asarray(code.addresses(), np.int64)
    fitted = np.asarray(code.modes) == MODE_FIT
    long_enough = np.asarray(frame_count)[:, None] >= code.n_frames
    take = np.asarray(keep_qpos, bool)[:, adrs] & fitted[None, :] & long_enough
    return cls(code, take)

  def segments(self, kind: str, n_frames: int) -> dict:
    """Per fitted channel of ``kind``: the parent's (lengths, vel, flags),
    held to ``n_frames`` frames."""
    extra = n_frames - self.code.n_frames
    return {c: _extended(seg, extra, kind, self.code) for c, seg in _channel_segments(self.code, kind).items()}


def refined_frames(after: np.ndarray, first_frame: int, parent_frames: np.ndarray,
                   columns: np.ndarray | None = None) -> np.ndarray:
  """Refined worlds' whole frames: the parent's (``parent_frames`` f32[T, nq])
  before ``first_frame``, then ``after`` (f32[W, F, nq]).

  Returns:
    f32[W, first_frame + F, nq]; with ``columns`` (i64[k]) f32[W, first_frame
    + F, k], those columns alone (a tower's 64 children are 230 MB whole, a
    few MB in the columns of the objects they refine).
  """
  columns = slice(None) if columns is None else np.asarray(columns, np.int64)
  picked = after[:, :, columns]
  out = np.empty((len(after), first_frame + after.shape[1], picked.shape[2]), np.float32)
  out[:, :first_frame] = parent_frames[:first_frame, columns]
  out[:, first_frame:] = picked
  return out
