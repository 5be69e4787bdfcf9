"""A bank's contact events: each world's contact episodes, compact and ragged.

An **episode** is a maximal run of recorded frames in which two actors touch
(:mod:`mwbx.events.detect`): one row ``(a, b, first, last)`` with actor
indices ``a < b`` and frame numbers at the bank's record rate. A world's rows
are consecutive, sorted by ``(a, b, first)``; how often two actors touched is
how many rows they have. Past a world's last recorded frame its last frame
holds (the world came to rest): an episode ending there goes on.

Example::

  record = bank.events
  rows = record.world(bank.row_of(7))   # i32[n, 4] of world 7
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import zlib

import numpy as np

from mwbx.errors import MwbxError

EVENTS_VERSION = 1  # the record's layout; a bank's manifest names it
ROW = {"a": 0, "b": 1, "first": 2, "last": 3}  # columns of a row


class EventRecord(NamedTuple):
  """Contact episodes of W worlds.

  Attributes:
    rows: i32[N, 4] ``(a, b, first, last)`` per episode (:data:`ROW`), the
      worlds' rows one after the other.
    counts: i32[W] episodes per world.
  """

  rows: np.ndarray
  counts: np.ndarray

  @classmethod
  def empty(cls, n_worlds: int = 0) -> "EventRecord":
    return cls(np.zeros((0, 4), np.int32), np.zeros(n_worlds, np.int32))

  @classmethod
  def from_worlds(cls, worlds: Sequence[np.ndarray]) -> "EventRecord":
    """One record of per-world episode rows (each i32[n, 4])."""
    counts = np.array([len(w) for w in worlds], np.int32)
    rows = np.concatenate([np.asarray(w, np.int32).reshape(-1, 4) for w in worlds]) if worlds else None
    return cls(rows if rows is not None else np.zeros((0, 4), np.int32), counts)

  @property
  def n_worlds(self) -> int:
    return len(self.counts)

  @property
  def nbytes(self) -> int:
    return int(self.rows.nbytes + self.counts.nbytes)

  @property
  def offsets(self) -> np.ndarray:
    """i64[W + 1] where each world's rows start."""
    return np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)])

  def world_of_rows(self) -> np.ndarray:
    """i64[N] the world (bank row) of each episode."""
    return np.repeat(np.arange(self.n_worlds), self.counts)

  def world(self, row: int) -> np.ndarray:
    """i32[n, 4] the episodes of one world (bank row)."""
    offsets = self.offsets
    return self.rows[offsets[row]:offsets[row + 1]]

  def take(self, worlds) -> "EventRecord":
    """The record of bank rows ``worlds`` (i64[k], in that order)."""
    worlds = np.asarray(worlds, np.int64)
    offsets = self.offsets
    pieces = [self.rows[offsets[w]:offsets[w + 1]] for w in worlds.tolist()]
    rows = np.concatenate(pieces) if pieces else np.zeros((0, 4), np.int32)
    return EventRecord(rows.astype(np.int32, copy=False), self.counts[worlds].astype(np.int32))

  @classmethod
  def concat(cls, records: Sequence["EventRecord"]) -> "EventRecord":
    return cls(np.concatenate([r.rows for r in records]).astype(np.int32, copy=False),
               np.concatenate([r.counts for r in records]).astype(np.int32, copy=False))

  def arrays(self) -> dict[str, np.ndarray]:
    """The arrays a shard stores (checksummed with the others): ``events_rows``
    packed (:func:`pack`), ``events_counts`` as they are."""
    return {"events_rows": pack(self.rows), "events_counts": np.ascontiguousarray(self.counts, np.int32)}

  @classmethod
  def from_arrays(cls, arrays: dict, n_worlds: int, where: str = "bank") -> "EventRecord":
    """A shard's record, checked (MwbxError naming ``where`` if the arrays disagree)."""
    counts = np.asarray(arrays["events_counts"])
    n_rows = int(counts.sum(dtype=np.int64)) if counts.ndim == 1 else -1
    try:
      rows = unpack(np.asarray(arrays["events_rows"]), n_rows)
    except (ValueError, zlib.error) as err:
      raise MwbxError(f"{where}: corrupt contact events ({err})") from None
    if counts.shape != (n_worlds,) or (counts < 0).any() \
        or (rows.size and (rows[:, ROW["a"]] >= rows[:, ROW["b"]]).any()):
      raise MwbxError(f"{where}: corrupt contact events (rows {rows.shape}, counts {counts.shape} for"
                      f" {n_worlds} worlds)")
    return cls(rows, counts.astype(np.int32, copy=False))


def pack(rows: np.ndarray) -> np.ndarray:
  """u8[n] episode rows as a shard keeps them: one byte giving the width of
  a number (2 bytes below 65,536, else 4), then zlib of the columns one after
  the other, the last frame kept as the run's length (``last - first``), so
  alike numbers sit together: about 2.4 bytes an episode on quickstart."""
  rows = np.asarray(rows, np.int64).reshape(-1, 4)
  columns = rows.T.copy()
  columns[ROW["last"]] -= columns[ROW["first"]]
  wide = columns.size and int(columns.max()) >= (1 << 16)
  data = columns.astype(np.int32 if wide else np.uint16)
  return np.frombuffer(bytes([data.itemsize]) + zlib.compress(data.tobytes(), 6), np.uint8).copy()


def unpack(blob: np.ndarray, n_rows: int) -> np.ndarray:
  """i32[n_rows, 4] episode rows from :func:`pack`'s bytes (ValueError if they do not hold that many)."""
  blob = np.asarray(blob, np.uint8).reshape(-1)
  if blob.size < 1 or int(blob[0]) not in (2, 4) or n_rows < 0:
    raise ValueError("unknown packing")
  dtype = np.uint16 if int(blob[0]) == 2 else np.int32
  columns = np.frombuffer(zlib.decompress(blob[1:].tobytes()), dtype)
  if columns.size != 4 * n_rows:
    raise ValueError(f"{columns.size // 4} episodes stored, {n_rows} counted")
  rows = columns.reshape(4, n_rows).T.astype(np.int32)
  rows[:, ROW["last"]] += rows[:, ROW["first"]]
  return np.ascontiguousarray(rows)


def merge(parts: Sequence[tuple[tuple[str, ...], "EventRecord | None"]]):
  """One record of several, each with the actor names its indices refer to
  (banks of different scene versions name different actors).

  Returns:
    (actor names: the first part's, then names only later parts have;
    the record, its rows relabelled to those names), or ((), None) if any
    part has no record.
  """
  if not parts or any(record is None for _, record in parts):
    return (), None
  names: list[str] = list(parts[0][0])
  records = []
  for actors, record in parts:
    for name in actors:
      if name not in names:
        names.append(name)
    if tuple(actors) == tuple(names[:len(actors)]):
      records.append(record)
      continue
    mapping = np.array([names.index(n) for n in actors], np.int32)
    rows = record.rows.copy()
    a, b = mapping[rows[:, ROW["a"]]], mapping[rows[:, ROW["b"]]]
    rows[:, ROW["a"]], rows[:, ROW["b"]] = np.minimum(a, b), np.maximum(a, b)
    # Each world's rows stay sorted by (a, b, first).
    world = np.repeat(np.arange(record.n_worlds), record.counts)
    order = np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0], world))
    records.append(EventRecord(rows[order], record.counts))
  return tuple(names), EventRecord.concat(records)
