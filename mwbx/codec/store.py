"""``CompressedQposStore``: the bank's qpos storage, one verified stream per world.

All streams live in one ``uint8`` array with ``int64`` offsets, so saving the
store is saving two arrays. Worlds are compressed chunk by chunk as they are
appended; frames are decoded on demand (a time range decodes only its frames).
"""

from __future__ import annotations

import numpy as np

from mwbx.codec.batch import decode_batch
from mwbx.codec.decode import decode_world
from mwbx.codec.encode import DEFAULT_GRAVITY, encode_batch_checked, fitted_columns
from mwbx.codec.layout import ChannelLayout, CodecBounds, CodecError
from mwbx.codec.splice import ParentChannels, channel_map, refined_frames, splice_stream


class CompressedQposStore:
  """qpos frames of every world, compressed under ``bounds``.

  Attributes:
    layout, bounds: channels and error bounds of every stream.
    fps: recording rate (frames per second); gravity: vertical m/s**2.
    n_bodies: bodies per world, for the bits-per-body-frame figure.
    data: u8[N] all streams back to back; offsets: i64[W + 1].
    frame_count: i64[W] frames per world.
    max_error: f64[W, 3] largest decoded error per world (translation m,
      rotation rad, scalar joint units), measured when the world was encoded.
    raw_channels: i64[W] channels per world stored uncompressed (non-finite
      values from an unstable world, or a fit that missed its bound).
  """

  kind = "codec"

  def __init__(self, layout: ChannelLayout, bounds: CodecBounds, fps: float = 120.0,
               gravity: float = DEFAULT_GRAVITY, n_bodies: int | None = None,
               arrays: dict | None = None):
    self.layout = layout
    self.bounds = bounds
    self.fps = float(fps)
    self.gravity = float(gravity)
    # Without a count, each free/ball/hinge/slide joint stands for one body.
    self.n_bodies = int(n_bodies) if n_bodies else max(
        1, len(layout.rot_adr) + len(layout.scalar_adr))
    arrays = arrays or {}
    self.data = np.asarray(arrays.get("data", np.zeros(0, np.uint8)), np.uint8).reshape(-1)
    self.offsets = np.asarray(arrays.get("offsets", np.zeros(1, np.int64)), np.int64).reshape(-1)
    w = self.offsets.size - 1
    self.frame_count = np.asarray(arrays.get("frame_count", np.zeros(w, np.int64)),
                                  np.int64).reshape(-1)
    self.max_error = np.asarray(arrays.get("max_error", np.zeros((w, 3))),
                                np.float64).reshape(-1, 3)
    self.raw_channels = np.asarray(arrays.get("raw_channels", np.zeros(w, np.int64)),
                                   np.int64).reshape(-1)
    self._check()

  @classmethod
  def from_model(cls, model, bounds: CodecBounds, fps: float = 120.0,
                 n_bodies: int | None = None) -> "CompressedQposStore":
    """Store for a ``mujoco.MjModel``: layout from its joints, gravity from its options."""
    layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
    if n_bodies is None:
      n_bodies = len(set(np.asarray(model.jnt_bodyid).tolist()))
    return cls(layout, bounds, fps, gravity=float(model.opt.gravity[2]), n_bodies=n_bodies)

  def _check(self):
    w = self.offsets.size - 1
    if (w < 0 or self.offsets[0] != 0 or np.any(np.diff(self.offsets) < 0)
        or self.offsets[-1] != self.data.size):
      raise CodecError(f"compressed qpos store: offsets do not match {self.data.size} data bytes")
    for name in ("frame_count", "max_error", "raw_channels"):
      if len(getattr(self, name)) != w:
        raise CodecError(f"compressed qpos store: {name} has {len(getattr(self, name))} rows, "
                         f"expected {w}")

  # -- the qpos-store protocol ----------------------------------------------------

  def append(self, qpos: np.ndarray, frame_count: np.ndarray, parent: ParentChannels | None = None,
             columns: np.ndarray | None = None) -> None:
    """Compresses and adds worlds: qpos f32[W, T, nq] (padded), frame_count i32[W];
    ``parent``: channels refined worlds take from their parent's stream;
    ``columns``: the qpos columns ``qpos`` holds if not all (as
    :func:`mwbx.codec.encode.encode_batch_checked`)."""
    res = encode_batch_checked(qpos, frame_count, self.layout, self.bounds, self.fps,
                               self.gravity, parent=parent, columns=columns)
    sizes = np.array([len(s) for s in res.streams], np.int64)
    self.data = np.concatenate([self.data, np.frombuffer(b"".join(res.streams), np.uint8)])
    self.offsets = np.concatenate([self.offsets, self.offsets[-1] + np.cumsum(sizes)])
    self.frame_count = np.concatenate([self.frame_count, np.asarray(frame_count, np.int64)])
    self.max_error = np.concatenate([self.max_error, res.max_error])
    self.raw_channels = np.concatenate([self.raw_channels, res.raw_channels])

  def extend(self, *others: "CompressedQposStore") -> None:
    """Adds every world of other compressed stores with the same layout and
    bounds, in their order (copied once, however many)."""
    if any(o.layout != self.layout or o.bounds != self.bounds or o.fps != self.fps for o in others):
      raise CodecError("compressed qpos stores differ in layout, bounds or fps")
    stores = [self, *others]
    starts = np.cumsum([0] + [int(s.offsets[-1]) for s in stores[:-1]])
    self.offsets = np.concatenate([self.offsets[:1]] + [s.offsets[1:] + k for s, k in zip(stores, starts)])
    self.data = np.concatenate([s.data for s in stores])
    self.frame_count = np.concatenate([s.frame_count for s in stores])
    self.max_error = np.concatenate([s.max_error for s in stores])
    self.raw_channels = np.concatenate([s.raw_channels for s in stores])

  def copy(self) -> "CompressedQposStore":
    return CompressedQposStore(self.layout, self.bounds, self.fps, self.gravity, self.n_bodies,
                               self._arrays(copy=True))

  def empty(self) -> "CompressedQposStore":
    return CompressedQposStore(self.layout, self.bounds, self.fps, self.gravity, self.n_bodies)

  def take(self, rows: np.ndarray) -> "CompressedQposStore":
    rows = np.asarray(rows, np.int64).reshape(-1)
    data, offsets = self._gather(rows)
    arrays = {"data": data, "offsets": offsets,
              "frame_count": self.frame_count[rows], "max_error": self.max_error[rows],
              "raw_channels": self.raw_channels[rows]}
    return CompressedQposStore(self.layout, self.bounds, self.fps, self.gravity, self.n_bodies,
                               arrays)

  def _gather(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u8[n], i64[k + 1]) the streams of ``rows`` back to back, and their offsets."""
    lo, hi = self.offsets[rows], self.offsets[rows + 1]
    index = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)] + [np.zeros(0, np.int64)])
    return self.data[index], np.concatenate([[0], np.cumsum(hi - lo)]).astype(np.int64)

  def refined(self, after: np.ndarray, first_frame: int, frame_count: np.ndarray, parent: int,
              parent_frames: np.ndarray, keep_qpos: np.ndarray) -> "CompressedQposStore":
    """A new store (same settings) of refined worlds of the parent at row ``parent``.

    The channels of ``keep_qpos`` are the parent's own segments (not fitted
    again: the cost grows with the refined objects, not the scene), so they
    decode to the parent's stored frames exactly; where the parent stored a
    channel raw, or a refined world is shorter than it, the world is encoded
    as usual and the parent's channels spliced in
    (:func:`mwbx.codec.splice.splice_stream`).

    Args:
      after: f32[W, F, nq] refined frames from ``first_frame`` on (padded);
        before it they are the parent's. frame_count: i32[W] from frame 0.
      parent: row of the parent world in this store.
      parent_frames: f32[T, nq] the parent's decoded frames.
      keep_qpos: bool[W, nq] coordinates that follow the parent exactly.
    """
    out = self.empty()
    if not keep_qpos.any():
      out.append(refined_frames(after, first_frame, parent_frames), frame_count)
      return out
    parent_stream = self.stream(parent)
    reuse = ParentChannels.of(parent_stream, keep_qpos, frame_count)
    # Only the channels some world fits are read (the encoder's contract): a
    # refinement's frames cost what its active objects hold, not the scene.
    fitted = fitted_columns(self.layout, reuse)
    out.append(refined_frames(after, first_frame, parent_frames, fitted), frame_count, parent=reuse,
               columns=fitted)
    kept = keep_qpos[:, np.asarray(reuse.code.addresses(), np.int64)]
    rest = np.flatnonzero((kept & ~reuse.take).any(axis=1))  # kept channels not taken whole
    if rest.size:
      streams = [out.stream(w).tobytes() for w in range(out.n_worlds)]
      for w in rest:
        streams[w] = splice_stream(out.stream(w), parent_stream, parent_frames, keep_qpos[w])
      out._set_streams(streams)
    out.max_error = np.maximum(out.max_error, self.max_error[parent][None, :])
    return out

  def relaid(self, target: "CompressedQposStore", fill: np.ndarray,
             chunk: int = 256) -> "CompressedQposStore":
    """Every world in ``target``'s layout (a later scene version's, whose qpos
    starts with this one's): each world is coded with its new coordinates
    held at ``fill`` (f32[nq']), then its stored channels are spliced in
    verbatim (:func:`mwbx.codec.splice.splice_stream`), so they decode
    exactly as before.
    """
    if target.bounds != self.bounds or target.fps != self.fps:
      raise CodecError("relaid: the target store has other error bounds or fps")
    mapping = channel_map(target.layout, self.layout)
    old = np.flatnonzero(mapping >= 0)
    if len(old) != len(self.layout.pos_adr) + len(self.layout.rot_adr) + len(self.layout.scalar_adr):
      raise CodecError("relaid: the target layout does not start with this store's qpos")
    fill = np.asarray(fill, np.float32)
    keep = np.zeros(target.layout.nq, bool)
    keep[:self.layout.nq] = True
    out = target.empty()
    for lo in range(0, self.n_worlds, chunk):
      rows = np.arange(lo, min(self.n_worlds, lo + chunk))
      counts = self.frame_count[rows]
      held = np.broadcast_to(fill, (len(rows), int(counts.max()), len(fill)))
      part = target.empty()
      part.append(held, counts)  # the old channels are replaced below: code them held too
      frames = held.copy()  # the decoded frames, for channels the splice copies raw
      for i, f in enumerate(self.frames_of_rows(rows)):
        frames[i, :len(f), :self.layout.nq] = f
      part._set_streams([splice_stream(part.stream(i), self.stream(int(r)), frames[i, :counts[i]], keep, mapping)
                         for i, r in enumerate(rows)])
      part.max_error = np.maximum(part.max_error, self.max_error[rows])
      out.extend(part)
    return out

  def _set_streams(self, streams: list[bytes]) -> None:
    """Replaces every world's stream (same worlds, same order) by ``streams``."""
    sizes = np.array([len(s) for s in streams], np.int64)
    self.data = np.frombuffer(b"".join(streams), np.uint8).copy()
    self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

  def stream(self, world: int) -> np.ndarray:
    """u8[n] the stored stream of one world."""
    if not 0 <= world < self.n_worlds:
      raise CodecError(f"world {world} out of range [0, {self.n_worlds})")
    return self.data[self.offsets[world]:self.offsets[world + 1]]

  def row_frames(self, row: int, start: int = 0, stop: int | None = None,
             columns=None) -> np.ndarray:
    """Decoded frames ``start:stop`` of one row, f32[n, nq].

    columns: optional qpos columns; only the channels holding them are decoded
    (other channels' columns stay zero).
    """
    channels = None if columns is None else self.layout.channels_for(columns)
    try:
      return decode_world(self.stream(row), start, stop, channels)
    except CodecError as err:
      raise CodecError(f"compressed qpos of row {row}: {err}") from None

  def frames_of_rows(self, rows=None, start: int = 0, stop: int | None = None,
                   columns=None) -> list:
    """Decoded frames ``start:stop`` of many rows at once (all by default).

    One pass over their streams; returns one f32[n, nq] per row. columns: as
    ``row_frames``.
    """
    channels = None if columns is None else self.layout.channels_for(columns)
    rows = np.arange(self.n_worlds) if rows is None else np.asarray(rows, np.int64)
    if rows.size and (rows.min() < 0 or rows.max() >= self.n_worlds):
      raise CodecError(f"rows out of range [0, {self.n_worlds})")
    data, offsets = self._gather(rows)
    try:
      return decode_batch(data, offsets, start, stop, channels)
    except CodecError as err:
      raise CodecError(f"compressed qpos: {err}") from None

  @property
  def n_worlds(self) -> int:
    return self.offsets.size - 1

  @property
  def nbytes(self) -> int:
    return int(sum(a.nbytes for a in self._arrays().values()))

  def stats(self) -> dict[str, float | int | str]:
    return self.stats_of(self.row_figures())

  def row_figures(self) -> dict[str, np.ndarray]:
    return self.figures_of_saved(self._arrays())

  @staticmethod
  def figures_of_saved(arrays: dict) -> dict[str, np.ndarray]:
    return {"stream_bytes": np.diff(np.asarray(arrays["offsets"], np.int64).reshape(-1)),
            "frame_count": np.asarray(arrays["frame_count"], np.int64).reshape(-1),
            "max_error": np.asarray(arrays["max_error"], np.float64).reshape(-1, 3),
            "raw_channels": np.asarray(arrays["raw_channels"], np.int64).reshape(-1)}

  def stats_of(self, figures: dict[str, np.ndarray]) -> dict[str, float | int | str]:
    worlds = len(figures["frame_count"])
    frames = int(figures["frame_count"].sum())
    stream = int(figures["stream_bytes"].sum())
    raw_bytes = frames * self.layout.nq * 4
    body_frames = frames * self.n_bodies
    err = figures["max_error"].max(axis=0) if worlds else np.zeros(3)
    # In memory as the constructor holds them: the streams, int64 offsets (one more than
    # the worlds), int64 frame counts and raw channel counts, float64 errors (three a world).
    nbytes = stream + 8 * (worlds + 1) + (8 + 3 * 8 + 8) * worlds
    return {
        "codec": "mwbx spline/Rice",
        "bytes": nbytes,
        "stream_bytes": stream,
        "bytes_per_world": stream / max(1, worlds),
        "frames": frames,
        "bits_per_body_frame": 8.0 * stream / max(1, body_frames),
        "ratio_vs_float32": raw_bytes / max(1, stream),
        "bound_pos_m": self.bounds.e_pos,
        "bound_rot_deg": float(np.rad2deg(self.bounds.e_rot)),
        "bound_scalar": self.bounds.e_scalar,
        "max_error_pos_m": float(err[0]),
        "max_error_rot_deg": float(np.rad2deg(err[1])),
        "max_error_scalar": float(err[2]),
        "raw_channels": int(figures["raw_channels"].sum()),
    }

  def _arrays(self, copy: bool = False) -> dict[str, np.ndarray]:
    arrays = {"data": self.data, "offsets": self.offsets, "frame_count": self.frame_count,
              "max_error": self.max_error, "raw_channels": self.raw_channels}
    return {k: v.copy() for k, v in arrays.items()} if copy else arrays

  def state(self) -> tuple[dict[str, np.ndarray], dict]:
    meta = {"kind": self.kind, "layout": self.layout.to_json(), "bounds": self.bounds.to_json(),
            "fps": self.fps, "gravity": self.gravity, "n_bodies": self.n_bodies}
    return self._arrays(), meta

  @classmethod
  def restore(cls, arrays: dict[str, np.ndarray], meta: dict) -> "CompressedQposStore":
    try:
      return cls(ChannelLayout.from_json(meta["layout"]), CodecBounds.from_json(meta["bounds"]),
                 float(meta["fps"]), float(meta["gravity"]), int(meta["n_bodies"]),
                 {k: np.asarray(v) for k, v in arrays.items()})
    except (KeyError, TypeError, ValueError) as err:
      if isinstance(err, CodecError):
        raise
      raise CodecError(f"compressed qpos store: bad saved metadata ({err})") from None
