"""A bank's contact events decoded when first used, not when the bank opens.

Decoding every shard's packed episodes (:func:`mwbx.events.record.pack`) is
most of the time a lazily opened bank takes to open (4,000 four-second
quickstart worlds: 0.14 s of 0.16 s), yet ``mwbx info``, box, geometry and
orientation queries never read an episode. :class:`LazyEvents` stands in for
the :class:`~mwbx.events.record.EventRecord`: what it can tell from the
shards' small headers it tells at once (each world's episode count, the bytes
the record will take, its ticks), and the first use of anything else (rows,
strengths, a world's episodes) decodes the whole record once and keeps it.
Taking and merging records stays lazy. A corrupt shard is named at that first
use, as a lazily read path is.

Example::

  events = bank.events              # a LazyEvents for a bank opened lazily
  events.counts.sum()               # episodes in the bank: nothing decoded
  events.world(0)                   # decodes the record, then i32[n, 4]
"""

from __future__ import annotations

import threading
from typing import Callable

import numpy as np


class LazyEvents:
  """An :class:`~mwbx.events.record.EventRecord` decoded on first use.

  Args:
    decode: returns the record (called at most once).
    counts: returns i32[W] each world's episode count without decoding rows.
    ticks_per_frame: the record's ticks to a frame.
    with_impulse: returns how many episodes have a known impulse, or None
      when only the decoded strengths can tell.
  """

  def __init__(self, decode: Callable, counts: Callable[[], np.ndarray], ticks_per_frame: int,
               with_impulse: Callable[[], int | None] = lambda: None):
    self._decode, self._counts, self._with_impulse = decode, counts, with_impulse
    self.ticks_per_frame = int(ticks_per_frame)
    self._record = None
    self._lock = threading.Lock()

  def record(self):
    """The decoded :class:`~mwbx.events.record.EventRecord` (decoded once)."""
    with self._lock:
      if self._record is None:
        self._record = self._decode()
        # What decoding needed (the shards' parts) is let go.
        self._decode = self._with_impulse = None
        self._counts = self._record.counts
      return self._record

  @property
  def decoded(self) -> bool:
    return self._record is not None

  @property
  def counts(self) -> np.ndarray:
    """i32[W] episodes per world."""
    with self._lock:
      if not callable(self._counts):
        return self._counts
      counts = np.asarray(self._counts(), np.int32)
      if self._record is None:
        self._counts = counts
      return counts

  @property
  def n_worlds(self) -> int:
    return len(self.counts)

  @property
  def nbytes(self) -> int:
    """Bytes the decoded record takes: i32 rows of 4, i32 counts, f32 strengths of 2."""
    return int(24 * episodes(self) + 4 * self.n_worlds)

  @property
  def offsets(self) -> np.ndarray:
    """i64[W + 1] where each world's rows start."""
    return np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)])

  def take(self, worlds) -> "LazyEvents":
    """The record of bank rows ``worlds``, still undecoded."""
    worlds = np.asarray(worlds, np.int64)
    return LazyEvents(lambda: self.record().take(worlds), lambda: self.counts[worlds], self.ticks_per_frame)

  def __getattr__(self, name):  # rows, strength, world(), in_ticks(), ...: the decoded record's
    if name.startswith("__") or name in ("_decode", "_counts", "_with_impulse", "_record", "_lock"):
      raise AttributeError(name)
    return getattr(self.record(), name)

  def __repr__(self) -> str:
    return f"LazyEvents({self.n_worlds} worlds, {'decoded' if self.decoded else 'not decoded'})"


def impulses_known(record) -> int:
  """How many episodes of ``record`` (an EventRecord or LazyEvents) have a
  known impulse: from the shards' headers where they say, else decoded."""
  known = known_without_decoding(record)
  return known if known is not None else _impulses_known(record.record())


def known_without_decoding(record) -> int | None:
  """:func:`impulses_known` where it needs no decoding, else None."""
  if isinstance(record, LazyEvents):
    with record._lock:
      pending = record._with_impulse if record._record is None else None
    if pending is not None:
      return pending()
    record = record.record()
  return _impulses_known(record)


def _impulses_known(record) -> int:
  """Episodes of a decoded EventRecord whose impulse is not NaN."""
  return int((~np.isnan(record.impulse)).sum())


def episodes(record) -> int:
  """How many episodes ``record`` (an EventRecord or LazyEvents) holds, without decoding."""
  return int(np.asarray(record.counts).sum(dtype=np.int64))
