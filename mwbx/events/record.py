"""A bank's contact events: each world's contact episodes, compact and ragged.

An **episode** is a maximal run of physics steps in which two actors touch
(:mod:`mwbx.events.steps`; :mod:`mwbx.events.detect` on stored frames where
an engine cannot report its steps): one row ``(a, b, first, last)`` with
actor indices ``a < b`` and times in **ticks**, ``ticks_per_frame`` to a
recorded frame (the physics steps per frame; 1 in banks whose events were
found on the stored frames before steps were recorded), with its strength:
the largest normal contact force and the normal impulse it delivered. A
world's rows are consecutive, sorted by ``(a, b, first)``; how often two
actors touched is how many rows they have. Past a world's last recorded frame
its last frame holds (the world came to rest): an episode ending there goes on.

Example::

  record = bank.events
  rows = record.world(bank.row_of(7))   # i32[n, 4] of world 7
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import zlib

import numpy as np

from mwbx.errors import MwbxError

EVENTS_VERSION = 2  # the record's layout; a bank's manifest names it (1: frames, no strength)
ROW = {"a": 0, "b": 1, "first": 2, "last": 3}  # columns of a row
STRENGTH = {"peak_force": 0, "impulse": 1}  # columns of ``strength``: N, N·s


# Strength is kept to 7 bits of mantissa (within 0.8 %): a float's top two bytes, bfloat16.
STRENGTH_MANTISSA_BITS = 7


def _no_strength(n: int) -> np.ndarray:
  return np.full((n, 2), np.nan, np.float32)


def kept_strength(strength) -> np.ndarray:
  """f32[n, 2] ``strength`` as a record keeps it: each float's mantissa cut to
  :data:`STRENGTH_MANTISSA_BITS` bits (within 0.8 %; NaN stays NaN)."""
  bits = np.ascontiguousarray(strength, np.float32).reshape(-1, 2).view(np.uint32)
  drop = np.uint32((1 << (23 - STRENGTH_MANTISSA_BITS)) - 1)
  return (bits & ~drop).view(np.float32)


def pack_strength(strength: np.ndarray) -> np.ndarray:
  """u8[k] a record's strength as a shard keeps it: the top two bytes of each
  (kept) float, byte planes one after the other, zlib'd."""
  top = (kept_strength(strength).view(np.uint32) >> 16).astype(np.uint16).reshape(-1)
  planes = top.view(np.uint8).reshape(-1, 2).T
  return np.frombuffer(zlib.compress(planes.tobytes(), 6), np.uint8).copy()


def unpack_strength(blob: np.ndarray, n_rows: int) -> np.ndarray:
  """f32[n_rows, 2] from :func:`pack_strength`'s bytes (ValueError if they do not hold that many)."""
  raw = np.frombuffer(zlib.decompress(np.asarray(blob, np.uint8).tobytes()), np.uint8)
  if raw.size != 4 * n_rows:
    raise ValueError(f"{raw.size // 4} strengths stored, {n_rows} counted")
  top = np.ascontiguousarray(raw.reshape(2, -1).T).view(np.uint16).reshape(-1)
  return (top.astype(np.uint32) << 16).view(np.float32).reshape(n_rows, 2)


class EventRecord(NamedTuple):
  """Contact episodes of W worlds.

  Attributes:
    rows: i32[N, 4] ``(a, b, first, last)`` per episode (:data:`ROW`), the
      worlds' rows one after the other; first and last in ticks.
    counts: i32[W] episodes per world.
    strength: f32[N, 2] per episode its largest normal contact force (N)
      and the normal impulse it delivered (N·s) (:data:`STRENGTH`); NaN
      where the record was found on stored frames.
    ticks_per_frame: ticks to a recorded frame: tick ``k`` is at
      ``k / (record_fps · ticks_per_frame)`` s.
  """

  rows: np.ndarray
  counts: np.ndarray
  strength: np.ndarray
  ticks_per_frame: int = 1

  @classmethod
  def empty(cls, n_worlds: int = 0, ticks_per_frame: int = 1) -> "EventRecord":
    return cls(np.zeros((0, 4), np.int32), np.zeros(n_worlds, np.int32), _no_strength(0), ticks_per_frame)

  @classmethod
  def from_worlds(cls, worlds: Sequence[np.ndarray], strengths: Sequence[np.ndarray] | None = None,
                  ticks_per_frame: int = 1) -> "EventRecord":
    """One record of per-world episode rows (each i32[n, 4]) and, optionally,
    their strengths (each f32[n, 2]; NaN without)."""
    counts = np.array([len(w) for w in worlds], np.int32)
    rows = np.concatenate([np.asarray(w, np.int32).reshape(-1, 4) for w in worlds]) if worlds else None
    rows = rows if rows is not None else np.zeros((0, 4), np.int32)
    strength = (kept_strength(np.concatenate([np.asarray(s, np.float32).reshape(-1, 2) for s in strengths]))
                if strengths is not None and len(strengths) else _no_strength(len(rows)))
    return cls(rows, counts, strength, ticks_per_frame)

  @property
  def peak_force(self) -> np.ndarray:
    """f32[N] each episode's largest normal contact force, N (NaN: unknown)."""
    return self.strength[:, STRENGTH["peak_force"]]

  @property
  def impulse(self) -> np.ndarray:
    """f32[N] each episode's normal impulse, N·s (NaN: unknown)."""
    return self.strength[:, STRENGTH["impulse"]]

  def in_ticks(self, ticks_per_frame: int) -> "EventRecord":
    """This record with ``ticks_per_frame`` ticks to a frame (a multiple of
    its own: a frame-based record's frame ``f`` becomes tick ``f · k``)."""
    if ticks_per_frame == self.ticks_per_frame:
      return self
    scale, rest = divmod(int(ticks_per_frame), int(self.ticks_per_frame))
    if rest or scale < 1:
      raise MwbxError(f"contact events: {self.ticks_per_frame} ticks to a frame do not divide {ticks_per_frame}")
    rows = self.rows.copy()
    rows[:, 2:] *= scale
    return self._replace(rows=rows, ticks_per_frame=int(ticks_per_frame))

  def end_ticks(self, frame_count: np.ndarray) -> np.ndarray:
    """i64[W] each world's last tick: its last recorded frame's (it holds after)."""
    return (np.asarray(frame_count, np.int64) - 1) * self.ticks_per_frame

  @property
  def n_worlds(self) -> int:
    return len(self.counts)

  @property
  def nbytes(self) -> int:
    return int(self.rows.nbytes + self.counts.nbytes + self.strength.nbytes)

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
    index = np.concatenate([np.arange(offsets[w], offsets[w + 1]) for w in worlds.tolist()]
                           + [np.zeros(0, np.int64)])
    return self._replace(rows=self.rows[index].astype(np.int32, copy=False),
                         counts=self.counts[worlds].astype(np.int32), strength=self.strength[index])

  @classmethod
  def concat(cls, records: Sequence["EventRecord"]) -> "EventRecord":
    """One record of several, in the finest ticks any of them has."""
    ticks = int(np.lcm.reduce([r.ticks_per_frame for r in records])) if records else 1
    records = [r.in_ticks(ticks) for r in records]
    return cls(np.concatenate([r.rows for r in records]).astype(np.int32, copy=False),
               np.concatenate([r.counts for r in records]).astype(np.int32, copy=False),
               np.concatenate([r.strength for r in records]).astype(np.float32, copy=False), ticks)

  def arrays(self) -> dict[str, np.ndarray]:
    """The arrays a shard stores (checksummed with the others): ``events_rows``
    and ``events_strength`` packed (:func:`pack`, :func:`pack_strength`), ``events_counts`` as they are."""
    return {"events_rows": pack(self.rows), "events_counts": np.ascontiguousarray(self.counts, np.int32),
            "events_strength": pack_strength(self.strength)}

  @classmethod
  def from_arrays(cls, arrays: dict, n_worlds: int, where: str = "bank", ticks_per_frame: int = 1) -> "EventRecord":
    """A shard's record, checked (MwbxError naming ``where`` if the arrays
    disagree); a shard without ``events_strength`` (events version 1) has none."""
    counts = np.asarray(arrays["events_counts"])
    n_rows = int(counts.sum(dtype=np.int64)) if counts.ndim == 1 else -1
    try:
      rows = unpack(np.asarray(arrays["events_rows"]), n_rows)
      strength = (unpack_strength(arrays["events_strength"], len(rows)) if "events_strength" in arrays
                  else _no_strength(len(rows)))
    except (ValueError, zlib.error) as err:
      raise MwbxError(f"{where}: corrupt contact events ({err})") from None
    if counts.shape != (n_worlds,) or (counts < 0).any() \
        or (rows.size and (rows[:, ROW["a"]] >= rows[:, ROW["b"]]).any()) or strength.shape != (len(rows), 2) \
        or int(ticks_per_frame) < 1:
      raise MwbxError(f"{where}: corrupt contact events (rows {rows.shape}, counts {counts.shape}, strength"
                      f" {strength.shape} for {n_worlds} worlds, {ticks_per_frame} ticks a frame)")
    return cls(rows, counts.astype(np.int32, copy=False), strength.astype(np.float32, copy=False),
               int(ticks_per_frame))


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
  ticks = int(np.lcm.reduce([record.ticks_per_frame for _, record in parts]))
  parts = [(actors, record.in_ticks(ticks)) for actors, record in parts]
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
    records.append(record._replace(rows=rows[order], strength=record.strength[order]))
  return tuple(names), EventRecord.concat(records)
