"""Encoder: the compiled fit over all worlds x channels, then per-world streams, verified.

The fit (:mod:`mwbx.codec.fit_kernels`) keeps a small safety margin on the
bound for the decoder's float32 evaluation; every stream
is then decoded with the real decoder and compared with the input, frame by
frame. A channel that misses its bound (float32 rounding on huge coordinates,
non-finite values from an unstable world) is stored raw instead, so the bound is
a guarantee checked on the decoded data.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np

from mwbx.codec import fit_kernels
from mwbx.codec import eval_kernels
from mwbx.codec.batch import BatchCode, parse_batch, serialize_batch
from mwbx.codec.decode import KIND_ID, decode_code, evaluate
from mwbx.codec.layout import ChannelLayout, CodecBounds, CodecError
from mwbx.codec.splice import ParentChannels
from mwbx.codec.stream import (DIM, MODE_FIT, MODE_RAW, WIDTH, Quanta, Segments, WorldCode,
                               initial_steps, parse, quantize_initial, serialize)
from mwbx.host_pool import LazyPool

# Fraction of each bound the fit keeps back for the decoder's float32 evaluation.
FIT_MARGIN = 2.0**-6
DEFAULT_GRAVITY = -9.81


class EncodedBatch(NamedTuple):
  """streams: one bytes per world; max_error: f64[W, 3] largest decoded error per
  world (translation metres, rotation radians, scalar joint units), measured on
  the decoded data; raw_channels: i64[W] channels stored uncompressed."""

  streams: list
  max_error: np.ndarray
  raw_channels: np.ndarray


def default_quanta(fps: float, gravity: float = DEFAULT_GRAVITY) -> Quanta:
  """Quantization for a recording rate; ``gravity``: vertical component, m/s**2."""
  return Quanta(quad=float(np.float32(0.5 * float(gravity) / float(fps) ** 2)))


# Paths per fit call: the calls of every kind are spread over a thread per core.
FIT_BATCH = 256


_FIT_POOL = LazyPool("mwbx-codec-fit")  # the fit's batches, a thread per core


def _columns(adrs: tuple[int, ...]) -> np.ndarray:
  return np.asarray(adrs, np.int64).reshape(-1)


class _FitJob(NamedTuple):
  """The fit of every path of one kind (see :func:`_fit_job`)."""

  kind: str
  batch: Callable[[np.ndarray], tuple]  # rows -> (path, frame, vel, flag) of those paths' segment ends
  batches: list  # i64[<= FIT_BATCH] path rows of each call, shortest paths first
  held: tuple  # (path, frame, vel, flag) of the constant paths: one segment each, no call


def _fit_job(kind: str, qpos: np.ndarray, adrs: tuple[int, ...], n: np.ndarray,
             initial: np.ndarray, finite: np.ndarray, e: float, step: float, quad: float,
             coarse: int, g_fp: int, skip: np.ndarray | None = None,
             constant: np.ndarray | None = None) -> _FitJob:
  """The fit of every path of one kind, FIT_BATCH paths per call.

  qpos: f32[W, T, k] recordings; adrs: the column of ``qpos`` where each
  channel of this kind starts (path p is channel ``p % C`` of world ``p // C``);
  n: i64[P] valid frames;
  initial: f64[P, width] frame-0 values on their grid (the fit starts there);
  finite: bool[P], paths with non-finite values are fitted as zeros (they are
  stored raw); skip: bool[P] paths not fitted (no segments); constant:
  bool[P] paths that hold their frame-0 value throughout, each one segment
  at velocity 0 from its stored frame 0 (what the fit finds for them, without
  the scan: a tower asleep is 195 such paths of 197). Each call returns
  the segment ends (path i64[S], frame i64[S]) of its paths with the velocity
  i64[S, D] and gravity flag bool[S] of each.
  """
  width = WIDTH[kind]
  t = qpos.shape[1]
  columns = _columns(adrs)

  def fit_batch(rows):
    m = rows.size
    t_fit = int(min(t, max(n[rows].max(), 1)))
    buf = np.zeros((m, t_fit, width), np.float32)
    eval_kernels.gather_paths(qpos, rows, columns.size, columns, initial, kind != "rot", finite, buf)
    e_paths = np.full(m, e)
    if kind == "rot":
      res = fit_kernels.fit_rotation_batch(buf, n[rows], e_paths, step, coarse)
      flag = None
    else:
      res = fit_kernels.fit_linear_batch(buf, n[rows], e_paths, step, quad, coarse, g_fp, gravity=kind == "pos")
      flag = res.flag
    p_idx, f_idx = np.nonzero(res.ends)
    vel = res.vel[p_idx, f_idx]
    flag = np.zeros(p_idx.size, bool) if flag is None else flag[p_idx, f_idx]
    return rows[p_idx], f_idx, vel, flag

  skip = np.zeros(n.size, bool) if skip is None else np.asarray(skip, bool)
  held = np.zeros(n.size, bool) if constant is None else constant & ~skip
  rows = np.flatnonzero(held)
  d = 3 if kind == "rot" else width
  held_ends = (rows, n[rows] - 1, np.zeros((rows.size, d), np.int64), np.zeros(rows.size, bool))
  if n.size == 0 or t == 0:
    return _FitJob(kind, fit_batch, [], held_ends)
  # Paths sorted by length so each call gathers only as many frames as its longest path.
  order = np.argsort(n, kind="stable")
  order = order[~(held | skip)[order]]
  return _FitJob(kind, fit_batch, [order[lo:lo + FIT_BATCH] for lo in range(0, order.size, FIT_BATCH)],
                 held_ends)


def _run_fits(jobs: Sequence[_FitJob]) -> list[tuple]:
  """Runs the calls of every kind's fit together, a thread per core (a
  call runs on one core: a small batch has one call per kind, and the
  kinds run side by side). Returns, per job, its segment ends (path i64[S],
  frame i64[S]) in path-major order with the velocity i64[S, D] and gravity
  flag bool[S] of each."""
  calls = [(j, rows) for j, job in enumerate(jobs) for rows in job.batches]
  if len(calls) > 1:
    results = list(_FIT_POOL.get().map(lambda call: jobs[call[0]].batch(call[1]), calls))
  else:
    results = [jobs[j].batch(rows) for j, rows in calls]
  out = []
  for j, job in enumerate(jobs):
    parts = ([job.held] if job.held[0].size else []) + [r for (k, _), r in zip(calls, results) if k == j]
    if not parts:
      d = 3 if job.kind == "rot" else WIDTH[job.kind]
      out.append((np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, d), np.int64), np.zeros(0, bool)))
      continue
    path, frame, vel, flag = (np.concatenate(p) for p in zip(*parts))
    back = np.lexsort((frame, path))
    out.append((path[back], frame[back], vel[back], flag[back]))
  return out


def _measure(code: WorldCode, stream: bytes, qpos_w: np.ndarray):
  """Decode ``stream`` and return per-channel errors (f64[C]) in channel order."""
  decoded = decode_code(parse(stream))
  kinds = np.array([KIND_ID[k] for k in code.kinds()], np.int64)
  return eval_kernels.max_errors(decoded, np.zeros(1, np.int64), np.ascontiguousarray(qpos_w[None]),
                            np.array([len(qpos_w)], np.int64), kinds,
                            np.asarray(code.addresses(), np.int64))[0]


def encode_batch_checked(qpos: np.ndarray, frame_count: np.ndarray, layout: ChannelLayout,
                         bounds: CodecBounds, fps: float = 120.0,
                         gravity: float = DEFAULT_GRAVITY,
                         quanta: Quanta | None = None,
                         parent: ParentChannels | None = None,
                         columns: np.ndarray | None = None) -> EncodedBatch:
  """Encode many worlds and report the largest decoded error of each.

  Refined worlds pass ``parent``: the channels it marks are not fitted; the
  parent's segments stand for them (a refinement's fit then costs what its
  active objects cost, not the scene), checked on the decoded data as the
  fitted ones are. The qpos columns of channels every world takes are not
  read at all: ``qpos`` may hold only the others (``columns``).

  Args:
    qpos: f32[W, T, nq] padded recordings (frames >= frame_count[w] ignored),
      or f32[W, T, k] holding only the qpos columns ``columns``.
    frame_count: i32[W] frames recorded per world.
    layout, bounds: channels and error bounds.
    fps: recording rate (frames per second).
    gravity: vertical gravity (m/s**2) for the global quadratic term.
    quanta: quantization override (defaults from ``fps`` and ``gravity``).
    parent: optional :class:`~mwbx.codec.splice.ParentChannels` (same
      layout, bounds and quanta).
    columns: optional i64[k] the qpos columns ``qpos`` holds, in order; at
      least :func:`fitted_columns` (default: every one).
  """
  qpos = np.asarray(qpos, np.float32)
  frame_count = np.asarray(frame_count, np.int64).reshape(-1)
  fresh = fitted_columns(layout, parent)
  held = np.arange(layout.nq) if columns is None else np.asarray(columns, np.int64).reshape(-1)
  if qpos.ndim != 3 or qpos.shape[2] != held.size:
    raise CodecError(f"qpos must be f32[W, T, {'nq=' if columns is None else ''}{held.size}], got shape"
                     f" {qpos.shape}")
  # where each qpos column sits in the array given (-1: not given, never read)
  at = np.full(layout.nq, -1, np.int64)
  at[held] = np.arange(held.size)
  if (at[fresh] < 0).any():
    raise CodecError(f"encode: qpos column {int(fresh[at[fresh] < 0][0])} is fitted but not given")
  num_w, num_t, _ = qpos.shape
  if frame_count.shape != (num_w,):
    raise CodecError(f"frame_count must have shape ({num_w},), got {frame_count.shape}")
  if np.any(frame_count < 0) or np.any(frame_count > num_t):
    raise CodecError(f"frame_count entries must be in [0, {num_t}]")
  if not (np.isfinite(fps) and fps > 0):
    raise CodecError(f"fps must be a finite number > 0, got {fps!r}")
  recorded = np.arange(num_t)[None, :] < frame_count[:, None]  # [W, T]
  # Columns every refined world takes from its parent are the parent's decoded frames.
  bad = recorded[:, :, None] & ~np.isfinite(qpos[:, :, at[fresh]] if fresh.size < held.size else qpos)
  if bad.any():
    w, f, c = (int(i[0]) for i in np.nonzero(bad))
    c = int(fresh[c])
    raise CodecError(
        f"qpos of world {w} (of this batch) is {qpos[w, f, at[c]]} at frame {f}, column {c}: the codec"
        f" stores finite values only (cut the recording before frame {f}, as the sampler does"
        f" for a world that went unstable)")
  quanta = quanta or default_quanta(fps, gravity)
  steps = dict(zip(("pos", "rot", "scalar"), quanta.steps(bounds)))
  # The fits take the bounds themselves (the rotation fit its ball radius),
  # less a margin for float32 rounding.
  bound = {"pos": bounds.e_pos, "rot": bounds.e_rot, "scalar": bounds.e_scalar}
  kinds = (("pos", layout.pos_adr), ("rot", layout.rot_adr), ("scalar", layout.scalar_adr))
  as_stored = lambda b: tuple(np.float32(x) for x in (b.e_pos, b.e_rot, b.e_scalar))  # float32 in a stream
  if parent is not None and (parent.code.quanta != quanta or as_stored(parent.code.bounds) != as_stored(bounds)
                             or parent.take.shape != (num_w, layout.n_channels)):
    raise CodecError("encode: the parent's stream was coded with other codec settings")
  inputs, jobs = [], []
  first_channel = 0
  # Channels every world takes from its parent are never read: their columns may hold anything.
  everywhere = np.zeros(layout.n_channels, bool) if parent is None else _taken_in_every_world(parent, layout)
  for kind, adrs in kinds:
    width = WIDTH[kind]
    take = (None if parent is None else
            parent.take[:, first_channel:first_channel + len(adrs)].reshape(-1))
    read = ~everywhere[first_channel:first_channel + len(adrs)]
    first_channel += len(adrs)
    columns = _columns(adrs)
    given = np.maximum(at[columns], 0)  # a channel not given is taken whole: its values are not used
    n = np.repeat(frame_count, len(adrs))
    finite = np.ones((num_w, len(adrs)), bool)
    finite[:, read] = eval_kernels.finite_paths(qpos, frame_count, given[read], width)
    finite = finite.reshape(-1)
    constant = np.zeros((num_w, len(adrs)), bool)
    constant[:, read] = eval_kernels.constant_paths(qpos, frame_count, given[read], width)
    constant = constant.reshape(-1) & finite
    # Frame 0 is stored on a grid; the fit starts from that stored value (a channel
    # not read starts from the parent's: _with_parent_segments).
    frame0 = np.zeros((num_w, len(adrs), width), np.float32)
    if num_t:
      frame0[:, read] = qpos[:, 0][:, given[read][:, None] + np.arange(width)]
    initial = quantize_initial(kind, frame0.reshape(-1, width), bounds) * initial_steps(bounds)[kind]
    initial[n == 0] = 0.0
    inputs.append((kind, adrs, columns, n, finite, initial, take))
    jobs.append(_fit_job(kind, qpos, given, n, initial, finite, bound[kind] * (1 - FIT_MARGIN), steps[kind],
                         quanta.quad, quanta.coarse()[kind], quanta.g_fp(bounds), skip=take,
                         constant=constant))
  per_kind = {}
  for (kind, adrs, columns, n, finite, initial, take), (p_idx, f_idx, vel, flag) in zip(inputs, _run_fits(jobs)):
    seg_per_path = np.bincount(p_idx, minlength=n.size)
    first = np.ones(p_idx.size, bool)
    first[1:] = p_idx[1:] != p_idx[:-1]
    prev = np.where(first, 0, np.concatenate([[0], f_idx[:-1]]))
    lengths = f_idx - prev
    if take is not None and take.any():
      seg_per_path, lengths, vel, flag = _with_parent_segments(
          kind, take, len(adrs), parent, frame_count, seg_per_path, lengths, vel, flag, initial)
    per_kind[kind] = dict(columns=columns, finite=finite, seg=seg_per_path, initial=initial,
                          seg_off=np.concatenate([[0], np.cumsum(seg_per_path)]),
                          lengths=lengths, vel=vel, flag=flag,
                          n_ch=len(adrs))
  streams, max_err = [None] * num_w, np.zeros((num_w, 3))
  raw_count = np.zeros(num_w, np.int64)
  bound_vec = np.concatenate([np.full(k["n_ch"], bound[name]) for name, k in per_kind.items()])
  # A channel taken from the parent decodes to the parent's stored frames (held past its end
  # within a quantum): the parent's bound is its bound, so only the fitted channels are checked.
  taken = None if parent is None else np.asarray(parent.take, bool)
  slow = _encode_fast(qpos, at, frame_count, layout, bounds, fps, quanta, per_kind, bound_vec,
                      streams, max_err, taken)
  for w in slow:
    n_w = int(frame_count[w])
    qpos_w = _whole_world(qpos, w, n_w, held, layout.nq)
    raw_ok = np.concatenate([per_kind[name]["finite"][w * k["n_ch"]:(w + 1) * k["n_ch"]]
                             for name, k in per_kind.items()])
    modes = np.where(raw_ok, MODE_FIT, MODE_RAW).astype(np.uint8)
    if n_w <= 1:
      modes[:] = MODE_FIT
    for _ in range(2):
      code = _world_code(qpos_w, w, layout, bounds, fps, quanta, per_kind, modes)
      try:
        stream = serialize(code)
      except CodecError:  # a velocity off its lattice (int32 overflow in the fit)
        modes = np.full_like(modes, MODE_RAW)
        code = _world_code(qpos_w, w, layout, bounds, fps, quanta, per_kind, modes)
        stream = serialize(code)
      errs = _measure(code, stream, qpos_w)
      if taken is not None:
        errs = np.where(taken[w], 0.0, errs)
      bad = ~(errs <= bound_vec)
      if not np.any(bad):
        break
      modes = np.where(bad, MODE_RAW, modes).astype(np.uint8)
    else:
      raise CodecError(f"world {w}: raw channels still exceed the bound")  # pragma: no cover
    streams[w] = stream
    raw_count[w] = int(np.sum(modes == MODE_RAW))
    off = 0
    for j, (name, k) in enumerate(per_kind.items()):
      part = errs[off:off + k["n_ch"]]
      off += k["n_ch"]
      max_err[w, j] = float(part.max()) if part.size else 0.0
  return EncodedBatch(streams, max_err, raw_count)


def _with_parent_segments(kind, take, n_ch, parent, frame_count, seg, lengths, vel, flag, initial):
  """The fitted segments of one kind (path-major: path p is channel p % n_ch of
  world p // n_ch) with the parent's in the paths of ``take`` (bool[P]), and
  their frame-0 values the parent's (``initial`` f64[P, width], in place)."""
  first_channel = {"pos": 0, "rot": len(parent.code.layout.pos_adr),
                   "scalar": len(parent.code.layout.pos_adr) + len(parent.code.layout.rot_adr)}[kind]
  held = {}  # frames -> the parent's channels held to that length
  offsets = np.concatenate([[0], np.cumsum(seg)])
  parts, counts = [], seg.copy()
  width = WIDTH[kind]
  for p in range(take.size):
    if take[p]:
      w, c = divmod(p, n_ch)
      n_w = int(frame_count[w])
      if n_w not in held:
        held[n_w] = parent.segments(kind, n_w)
      part = held[n_w][first_channel + c]
      initial[p] = parent.code.initial[first_channel + c, :width]
    else:
      lo, hi = offsets[p], offsets[p + 1]
      part = (lengths[lo:hi], vel[lo:hi], flag[lo:hi])
    counts[p] = len(part[0])
    parts.append(part)
  dim = vel.shape[1] if vel.ndim == 2 else DIM[kind]
  return (counts, np.concatenate([q[0] for q in parts]).astype(np.int64),
          np.concatenate([np.reshape(q[1], (-1, dim)) for q in parts]).astype(np.int64),
          np.concatenate([q[2] for q in parts]).astype(bool))


def _channel_spans(layout: ChannelLayout) -> tuple[np.ndarray, np.ndarray]:
  """(first qpos column i64[C], width i64[C]) of each channel, in channel
  order (translations, rotations, scalars: as ``addresses()`` lists them)."""
  kinds = (("pos", layout.pos_adr), ("rot", layout.rot_adr), ("scalar", layout.scalar_adr))
  starts = np.array([a for _, adrs in kinds for a in adrs], np.int64)
  widths = np.array([WIDTH[kind] for kind, adrs in kinds for _ in adrs], np.int64)
  return starts, widths


def _columns_of(starts: np.ndarray, widths: np.ndarray, channels: np.ndarray) -> np.ndarray:
  """i64[k] the qpos columns of the ``channels`` (bool[C]) chosen, in channel order."""
  return np.concatenate([np.arange(a, a + w) for a, w in zip(starts[channels], widths[channels])]
                        + [np.zeros(0, np.int64)])


def fitted_columns(layout: ChannelLayout, parent: ParentChannels | None) -> np.ndarray:
  """i64[k] the qpos columns :func:`encode_batch_checked` reads: every one,
  less those of channels every refined world takes from ``parent``."""
  if parent is None:
    return np.arange(layout.nq)
  return _columns_of(*_channel_spans(layout), ~_taken_in_every_world(parent, layout))


def _taken_in_every_world(parent: ParentChannels, layout: ChannelLayout) -> np.ndarray:
  """bool[C]: the channels every world takes from its parent (none where
  ``parent.take`` does not fit the layout: the settings check reports that)."""
  take = parent.take
  if take.ndim != 2 or take.shape[0] == 0 or take.shape[1] != layout.n_channels:
    return np.zeros(layout.n_channels, bool)
  return take.all(axis=0)


def _encode_fast(qpos, at, frame_count, layout, bounds, fps, quanta, per_kind, bound_vec, streams,
                 max_err, taken=None) -> np.ndarray:
  """All worlds with finite data through the batched writer and reader.

  Fills ``streams`` and ``max_err`` for the worlds whose decoded data meet the
  bound on every channel (``taken``: bool[W, C] channels not checked; ``at``:
  i64[nq] where each qpos column sits in ``qpos``, -1 where not given);
  returns the other worlds (for the per-world path).
  """
  num_w = frame_count.size
  n_ch = layout.n_channels
  finite = np.stack([k["finite"].reshape(num_w, k["n_ch"]).all(axis=1)
                     for k in per_kind.values()]).all(axis=0)
  initial = np.zeros((num_w, n_ch, 4))
  c = 0
  for kind, k in per_kind.items():
    width, n_k = WIDTH[kind], k["n_ch"]
    initial[:, c:c + n_k, :width] = k["initial"].reshape(num_w, n_k, width)
    c += n_k
  segs = {kind: Segments(k["seg"].astype(np.int64), k["lengths"].astype(np.int64),
                         k["vel"].reshape(-1, DIM[kind]).astype(np.int64), k["flag"].astype(bool))
          for kind, k in per_kind.items()}
  code = BatchCode(n_frames=frame_count, layout=layout, bounds=bounds, fps=float(fps),
                   quanta=quanta, initial=initial, segs=segs)
  try:
    fast = serialize_batch(code)
  except CodecError:  # a velocity off its lattice: let the per-world path sort it out
    return np.arange(num_w)
  sizes = np.array([len(b) for b in fast], np.int64)
  data = np.frombuffer(b"".join(fast), np.uint8)
  offsets = np.concatenate([[0], np.cumsum(sizes)])
  parsed, parsed_worlds = parse_batch(data, offsets)
  channel_kinds = parsed.channel_kinds()
  mine = qpos if parsed_worlds.size == num_w else qpos[parsed_worlds]
  starts, widths = _channel_spans(layout)
  if taken is not None and taken.all(axis=0).any():
    # Channels every world takes from its parent are neither decoded nor checked:
    # the check runs on the other channels' columns alone, packed side by side.
    checked = ~taken.all(axis=0)
    columns = _columns_of(starts, widths, checked)
    addresses = np.zeros(n_ch, np.int64)
    addresses[checked] = np.concatenate([[0], np.cumsum(widths[checked])[:-1]])
    kinds = np.where(checked, channel_kinds, eval_kernels.NOT_CHECKED)
    out, row_off = evaluate(parsed.n_frames, parsed.initial, parsed.segs, channel_kinds, addresses, columns.size,
                            parsed.quanta, parsed.bounds, channels=checked)
    mine = mine if np.array_equal(at[columns], np.arange(mine.shape[2])) else np.ascontiguousarray(
        mine[:, :, at[columns]])
  else:
    kinds, addresses = channel_kinds, starts
    if not np.array_equal(at, np.arange(layout.nq)):  # every column given (each is fitted), in another order
      mine = np.ascontiguousarray(mine[:, :, at])
    out, row_off = evaluate(parsed.n_frames, parsed.initial, parsed.segs, kinds, addresses, layout.nq,
                            parsed.quanta, parsed.bounds)
  world_err = np.full((num_w, n_ch), np.inf)
  world_err[parsed_worlds] = eval_kernels.max_errors(out, row_off, mine, frame_count[parsed_worlds], kinds,
                                                     addresses)
  if taken is not None:
    world_err[taken] = 0.0
  ok = finite & np.all(world_err <= bound_vec[None, :], axis=1)
  c = 0
  for j, (kind, k) in enumerate(per_kind.items()):
    if k["n_ch"]:
      max_err[:, j] = world_err[:, c:c + k["n_ch"]].max(axis=1)
    c += k["n_ch"]
  for w in np.flatnonzero(ok):
    streams[w] = fast[w]
  return np.flatnonzero(~ok)


def _whole_world(qpos, w: int, n_w: int, held: np.ndarray, nq: int) -> np.ndarray:
  """f32[n_w, nq] world ``w``'s recorded frames with every qpos column
  (zero where ``qpos``, holding columns ``held``, does not give one)."""
  if held.size == nq:
    return qpos[w, :n_w]
  out = np.zeros((n_w, nq), np.float32)
  out[:, held] = qpos[w, :n_w]
  return out


def _world_code(qpos_w, w, layout, bounds, fps, quanta, per_kind, modes) -> WorldCode:
  """World ``w``'s code from its frames ``qpos_w`` (f32[n, nq]) and the batch's fits."""
  n_w = len(qpos_w)
  n_ch = layout.n_channels
  initial = np.zeros((n_ch, 4))
  raw, segs = {}, {}
  c = 0
  for kind, k in per_kind.items():
    width, n_k = WIDTH[kind], k["n_ch"]
    data = qpos_w[:, k["columns"][:, None] + np.arange(width)].transpose(1, 0, 2)
    initial[c:c + n_k, :width] = k["initial"][w * n_k:(w + 1) * n_k]
    kind_modes = modes[c:c + n_k]
    for j in np.flatnonzero(kind_modes == MODE_RAW):
      raw[c + int(j)] = data[j]
    fitted = np.flatnonzero(kind_modes == MODE_FIT) + w * n_k
    if n_w >= 2:
      lo, hi = k["seg_off"][fitted], k["seg_off"][fitted + 1]
      seg_count = hi - lo
      idx = np.repeat(lo - np.cumsum(seg_count) + seg_count, seg_count) + np.arange(
          int(seg_count.sum()))
    else:
      seg_count = np.zeros(fitted.size, np.int64)
      idx = np.zeros(0, np.int64)
    segs[kind] = Segments(seg_count.astype(np.int64), k["lengths"][idx].astype(np.int64),
                          k["vel"][idx].reshape(idx.size, DIM[kind]),
                          k["flag"][idx].astype(bool))
    c += n_k
  if any(np.any(s.lengths < 1) for s in segs.values()):
    raise CodecError(f"world {w}: the fit produced an empty segment")  # pragma: no cover
  return WorldCode(n_frames=n_w, layout=layout, bounds=bounds, fps=float(fps), quanta=quanta,
                   modes=modes, initial=initial, raw=raw, segs=segs)


def encode_batch(qpos: np.ndarray, frame_count: np.ndarray, layout: ChannelLayout,
                 bounds: CodecBounds, fps: float = 120.0,
                 gravity: float = DEFAULT_GRAVITY) -> list[bytes]:
  """One verified stream per world; see ``encode_batch_checked``."""
  return encode_batch_checked(qpos, frame_count, layout, bounds, fps, gravity).streams


def encode_world(qpos: np.ndarray, layout: ChannelLayout, bounds: CodecBounds,
                 fps: float = 120.0, gravity: float = DEFAULT_GRAVITY) -> bytes:
  """Encode one world's recording ``qpos: f32[T, nq]`` into a verified stream."""
  qpos = np.asarray(qpos, np.float32)
  if qpos.ndim != 2:
    raise CodecError(f"qpos must be f32[T, nq], got shape {qpos.shape}")
  return encode_batch(qpos[None], np.array([qpos.shape[0]]), layout, bounds, fps, gravity)[0]
