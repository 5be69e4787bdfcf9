"""How the bank stores each world's recorded ``qpos`` frames.

:class:`QposStore` is the interface the bank, the sampler and refinement use;
:class:`RawQposStore` keeps float32 frames as they are, and
``mwbx.codec.CompressedQposStore`` keeps them compressed under error bounds
(the default). Pass either to :class:`mwbx.Sampler` (``store=``) to choose.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from mwbx.codec.splice import refined_frames


@runtime_checkable
class QposStore(Protocol):
  """The recorded ``qpos`` frames of every world of a bank, in bank row order.

  Attributes:
    kind: the name saved banks record (``raw``, ``codec``).
  """

  kind: str

  def append(self, qpos: np.ndarray, frame_count: np.ndarray) -> None:
    """Adds worlds: qpos f32[W, T, nq] (padded past each world's count), frame_count i32[W]."""

  def extend(self, *others: "QposStore") -> None:
    """Adds every world of other stores of the same kind and settings, as
    stored, in their order (copied once, however many)."""

  def copy(self) -> "QposStore":
    """An independent copy."""

  def empty(self) -> "QposStore":
    """A store with the same settings and no worlds."""

  def take(self, rows: np.ndarray) -> "QposStore":
    """A store (same settings) of the worlds at ``rows`` (i64[k]), in that order, as stored."""

  def refined(self, after: np.ndarray, first_frame: int, frame_count: np.ndarray, parent: int,
              parent_frames: np.ndarray, keep_qpos: np.ndarray) -> "QposStore":
    """A new store of refined worlds of the world at row ``parent``: frames
    ``0 … first_frame - 1`` its ``parent_frames`` (f32[T, nq], decoded), then
    ``after`` (f32[W, F, nq], padded; frame_count i32[W] counts from frame 0);
    their ``keep_qpos`` (bool[W, nq]) coordinates decode exactly to ``parent_frames``."""

  def row_frames(self, row: int, start: int = 0, stop: int | None = None,
             columns=None) -> np.ndarray:
    """f32[n, nq] frames ``start:stop`` of row ``row``; with ``columns`` the others are zero."""

  def frames_of_rows(self, rows=None, start: int = 0, stop: int | None = None, columns=None) -> list:
    """f32[n, nq] frames ``start:stop`` of each of ``rows`` (i64[k]; None:
    every row), in one pass where the store can; ``columns`` as :meth:`row_frames`."""

  def relaid(self, target: "QposStore", fill: np.ndarray) -> "QposStore":
    """Every world in ``target``'s settings (an empty store of a later scene
    version whose qpos starts with this one's, f32[nq'] ``fill`` for the new
    coordinates): stored coordinates decode exactly as before."""

  @property
  def n_worlds(self) -> int:
    """Worlds stored."""

  @property
  def nbytes(self) -> int:
    """Bytes held in memory."""

  def stats(self) -> dict:
    """Size and error figures for ``mwbx info``: ``stats_of(row_figures())``."""

  def row_figures(self) -> dict[str, np.ndarray]:
    """Per-world figures :meth:`stats` adds up (each an array with a row per world)."""

  @staticmethod
  def figures_of_saved(arrays: dict) -> dict[str, np.ndarray]:
    """:meth:`row_figures` of a saved store (:meth:`state`'s arrays) without
    its ``data``: a bank's stats need not read the streams."""

  def stats_of(self, figures: dict[str, np.ndarray]) -> dict:
    """:meth:`stats` of a store like this one (its layout, not its worlds)
    holding worlds of these :meth:`row_figures`."""

  def state(self) -> tuple[dict, dict]:
    """(arrays, JSON metadata) to save; :meth:`restore` reads them back."""

  @classmethod
  def restore(cls, arrays: dict, meta: dict) -> "QposStore":
    """The store saved by :meth:`state`."""


class RawQposStore:
  """``qpos`` frames of every world as one float32 array plus offsets.

  Implements :class:`QposStore` without compression (tests and benchmarks
  compare against it); ``mwbx.codec.CompressedQposStore`` is the other one.
  """

  kind = "raw"

  def __init__(self, nq: int, data: np.ndarray | None = None, offsets: np.ndarray | None = None):
    self.nq = nq
    self.data = np.zeros((0, nq), np.float32) if data is None else np.asarray(data, np.float32)
    self.offsets = np.zeros(1, np.int64) if offsets is None else np.asarray(offsets, np.int64)

  def append(self, qpos: np.ndarray, frame_count: np.ndarray) -> None:
    """Adds worlds: qpos f32[W, T, nq] (padded), frame_count i32[W]."""
    pieces = [qpos[w, :n] for w, n in enumerate(frame_count)]
    self.data = np.concatenate([self.data, *pieces]).astype(np.float32)
    self.offsets = np.concatenate([self.offsets, self.offsets[-1] + np.cumsum(frame_count)])

  def extend(self, *others: "RawQposStore") -> None:
    """Adds every world of other stores of the same kind, as stored."""
    stores = [self, *others]
    starts = np.cumsum([0] + [s.offsets[-1] for s in stores[:-1]])
    self.offsets = np.concatenate([self.offsets[:1]] + [s.offsets[1:] + k for s, k in zip(stores, starts)])
    self.data = np.concatenate([s.data for s in stores])

  def refined(self, after: np.ndarray, first_frame: int, frame_count: np.ndarray, parent: int,
              parent_frames: np.ndarray, keep_qpos: np.ndarray) -> "RawQposStore":
    """A new store of refined worlds: raw frames already hold the parent's
    values bit for bit where ``keep_qpos``, so nothing is spliced."""
    out = RawQposStore(self.nq)
    out.append(refined_frames(after, first_frame, parent_frames), frame_count)
    return out

  def copy(self) -> "RawQposStore":
    return RawQposStore(self.nq, self.data.copy(), self.offsets.copy())

  def relaid(self, target: "RawQposStore", fill: np.ndarray) -> "RawQposStore":
    """This store's worlds with ``target.nq`` columns, the new ones ``fill[nq:]``."""
    fill = np.asarray(fill, np.float32)
    data = np.concatenate([self.data, np.broadcast_to(fill[self.nq:], (len(self.data), target.nq - self.nq))], 1)
    return RawQposStore(target.nq, data, self.offsets.copy())

  def empty(self) -> "RawQposStore":
    return RawQposStore(self.nq)

  def take(self, rows: np.ndarray) -> "RawQposStore":
    rows = np.asarray(rows, np.int64).reshape(-1)
    lo, hi = self.offsets[rows], self.offsets[rows + 1]
    index = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)] + [np.zeros(0, np.int64)])
    return RawQposStore(self.nq, self.data[index], np.concatenate([[0], np.cumsum(hi - lo)]))

  def row_frames(self, row: int, start: int = 0, stop: int | None = None,
             columns=None) -> np.ndarray:
    """f32[n, nq] frames ``start:stop``; with ``columns`` the others are zero."""
    lo, hi = self.offsets[row], self.offsets[row + 1]
    out = self.data[lo:hi][start:stop]
    if columns is None:
      return out
    keep = np.zeros(self.nq, bool)
    keep[np.asarray(columns, np.int64)] = True
    return np.where(keep, out, np.float32(0))

  def frames_of_rows(self, rows=None, start: int = 0, stop: int | None = None, columns=None) -> list:
    rows = np.arange(self.n_worlds) if rows is None else np.asarray(rows, np.int64)
    return [self.row_frames(int(r), start, stop, columns=columns) for r in rows]

  @property
  def n_worlds(self) -> int:
    return len(self.offsets) - 1

  @property
  def nbytes(self) -> int:
    return int(self.data.nbytes + self.offsets.nbytes)

  def stats(self) -> dict:
    return self.stats_of(self.row_figures())

  def row_figures(self) -> dict[str, np.ndarray]:
    return self.figures_of_saved({"offsets": self.offsets})

  @staticmethod
  def figures_of_saved(arrays: dict) -> dict[str, np.ndarray]:
    return {"frames": np.diff(np.asarray(arrays["offsets"], np.int64).reshape(-1))}

  def stats_of(self, figures: dict[str, np.ndarray]) -> dict:
    worlds, frames = len(figures["frames"]), int(figures["frames"].sum())
    nbytes = frames * self.nq * 4 + 8 * (worlds + 1)  # float32 frames, int64 offsets
    return {"codec": "raw float32", "bytes": nbytes, "bytes_per_world": nbytes / max(1, worlds), "frames": frames}

  def state(self) -> tuple[dict, dict]:
    return {"data": self.data, "offsets": self.offsets}, {"kind": self.kind, "nq": self.nq}

  @classmethod
  def restore(cls, arrays: dict, meta: dict) -> "RawQposStore":
    return cls(meta["nq"], arrays.get("data"), arrays.get("offsets"))  # none: an empty store
