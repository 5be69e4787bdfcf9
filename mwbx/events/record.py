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

import lzma
import zlib

import numpy as np

from mwbx.errors import MwbxError
from mwbx.events import lazy

EVENTS_VERSION = 3  # the record's layout; a bank's manifest names it (see :func:`EventRecord.from_arrays`)
ROW = {"a": 0, "b": 1, "first": 2, "last": 3}  # columns of a row
STRENGTH = {"peak_force": 0, "impulse": 1}  # columns of ``strength``: N, N·s
STORED_ARRAYS = ("events_counts", "events_rows", "events_strength")  # a shard's arrays of the record (:func:`pack`)

# A strength is kept as the nearest power of RATIO above FLOOR (within
# STRENGTH_RELATIVE_ERROR; below FLOOR it reads 0): a u16 code, alike for
# alike episodes, where a float's low mantissa bits are noise no compressor squeezes.
STRENGTH_RELATIVE_ERROR = 0.009
_STRENGTH_RATIO = (1.0 + STRENGTH_RELATIVE_ERROR) ** 2
_STRENGTH_FLOOR = 1e-9  # N or N·s
_STRENGTH_CODE = {"zero": 0, "nan": 1, "first_power": 2}  # u16 codes; FLOOR · RATIO^k is code k + 2
# Raw LZMA2, no container: the small integer streams below squeeze 35 % more
# than with zlib; literal contexts off (lc=0) suit bytes that are digits of numbers.
_LZMA_FILTERS = [{"id": lzma.FILTER_LZMA2, "preset": 6, "lc": 0, "lp": 0, "pb": 0}]


def end_ticks(frame_count: np.ndarray, ticks_per_frame: int) -> np.ndarray:
  """i64[W] each world's last tick: its last recorded frame's (it holds after)."""
  return (np.asarray(frame_count, np.int64) - 1) * int(ticks_per_frame)


def _no_strength(n: int) -> np.ndarray:
  return np.full((n, 2), np.nan, np.float32)


def strength_codes(strength) -> np.ndarray:
  """u16[n, 2] the codes of f32[n, 2] strengths (:data:`STRENGTH_RELATIVE_ERROR`)."""
  s = np.asarray(strength, np.float64).reshape(-1, 2)
  with np.errstate(divide="ignore", invalid="ignore"):
    power = np.round(np.log(np.maximum(s, _STRENGTH_FLOOR) / _STRENGTH_FLOOR) / np.log(_STRENGTH_RATIO))
  codes = np.clip(power + _STRENGTH_CODE["first_power"], _STRENGTH_CODE["first_power"], 0xFFFF)
  codes = np.where(s < _STRENGTH_FLOOR, _STRENGTH_CODE["zero"], codes)
  return np.where(np.isnan(s), _STRENGTH_CODE["nan"], codes).astype(np.uint16)


def strength_values(codes) -> np.ndarray:
  """f32[n, 2] the strengths :func:`strength_codes` coded."""
  codes = np.asarray(codes, np.int64)
  values = _STRENGTH_FLOOR * _STRENGTH_RATIO ** (codes - _STRENGTH_CODE["first_power"]).astype(np.float64)
  values = np.where(codes == _STRENGTH_CODE["zero"], 0.0, values)
  return np.where(codes == _STRENGTH_CODE["nan"], np.nan, values).astype(np.float32)


def kept_strength(strength) -> np.ndarray:
  """f32[n, 2] ``strength`` as a record keeps it: within
  :data:`STRENGTH_RELATIVE_ERROR` (NaN stays NaN; below 1e-9 reads 0)."""
  return strength_values(strength_codes(strength))


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
    return end_ticks(frame_count, self.ticks_per_frame)

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

  def arrays(self, frame_count: np.ndarray) -> dict[str, np.ndarray]:
    """The arrays a shard stores (checksummed with the others), each packed
    (:func:`pack`): ``events_counts``, ``events_rows``, ``events_strength``;
    ``frame_count`` i64[W] the worlds' recorded frames (an episode lasting to
    the world's end is stored as such)."""
    return pack(self, frame_count)

  @classmethod
  def from_arrays(cls, arrays: dict, n_worlds: int, where: str = "bank", ticks_per_frame: int = 1,
                  version: int = EVENTS_VERSION) -> "EventRecord":
    """A shard's record, checked (MwbxError naming ``where`` if the arrays
    disagree). ``arrays`` holds the shard's ``frame_count`` too. Versions:
    3 (:func:`pack`); 2, rows and strengths zlib'd in world order, strengths as
    bfloat16; 1, as 2 in frames and without ``events_strength`` (none known)."""
    try:
      if version >= 3:
        counts = _unpack_counts(arrays["events_counts"], n_worlds)
        rows, order = _unpack_rows(arrays["events_rows"], counts, end_ticks(arrays["frame_count"], ticks_per_frame))
        strength = _unpack_strength(arrays["events_strength"], order)
      else:
        counts = np.asarray(arrays["events_counts"])
        n_rows = int(counts.sum(dtype=np.int64)) if counts.ndim == 1 else -1
        rows = _unpack_rows_v2(np.asarray(arrays["events_rows"]), n_rows)
        strength = (_unpack_strength_v2(arrays["events_strength"], len(rows)) if "events_strength" in arrays
                    else _no_strength(len(rows)))
    except (ValueError, KeyError, zlib.error, lzma.LZMAError) as err:
      raise MwbxError(f"{where}: corrupt contact events ({err})") from None
    if counts.shape != (n_worlds,) or (counts < 0).any() \
        or (rows.size and (rows[:, ROW["a"]] >= rows[:, ROW["b"]]).any()) or strength.shape != (len(rows), 2) \
        or int(ticks_per_frame) < 1:
      raise MwbxError(f"{where}: corrupt contact events (rows {rows.shape}, counts {counts.shape}, strength"
                      f" {strength.shape} for {n_worlds} worlds, {ticks_per_frame} ticks a frame)")
    return cls(rows, counts.astype(np.int32, copy=False), strength.astype(np.float32, copy=False),
               int(ticks_per_frame))


def stored_counts(arrays: dict, n_worlds: int, where: str = "bank", version: int = EVENTS_VERSION) -> np.ndarray:
  """i32[W] a shard's episodes per world from its ``events_counts`` alone (the
  rows and strengths not decoded); MwbxError naming ``where`` if corrupt."""
  try:
    counts = _unpack_counts(arrays["events_counts"], n_worlds) if version >= 3 else np.asarray(arrays["events_counts"])
  except (ValueError, KeyError, lzma.LZMAError) as err:
    raise MwbxError(f"{where}: corrupt contact events ({err})") from None
  if counts.shape != (n_worlds,) or (counts < 0).any():
    raise MwbxError(f"{where}: corrupt contact events (counts {counts.shape} for {n_worlds} worlds)")
  return counts.astype(np.int32)


def stored_impulses_known(arrays: dict, n_rows: int, where: str = "bank", version: int = EVENTS_VERSION) -> int:
  """How many of a shard's ``n_rows`` episodes have a known impulse, from its
  ``events_strength`` alone (the rows not decoded); MwbxError naming ``where`` if corrupt."""
  if version < 2 or "events_strength" not in arrays:
    return 0  # version 1 kept no strengths
  try:
    if version >= 3:
      peak, relative = _unpack_columns(arrays["events_strength"], 2, n_rows)
      return int(((peak + relative) % (1 << 16) != _STRENGTH_CODE["nan"]).sum())
    return int((~np.isnan(_unpack_strength_v2(arrays["events_strength"], n_rows)[:, STRENGTH["impulse"]])).sum())
  except (ValueError, zlib.error, lzma.LZMAError) as err:
    raise MwbxError(f"{where}: corrupt contact events ({err})") from None


# A record as a shard keeps it (version 3). Each world's rows are sorted by
# pair, so a row is stored as its pair, the ticks since the pair's previous
# episode ended (since 0 for its first), and its length (0 for one lasting to
# the world's end, else length + 1); strengths as codes, the impulse's
# relative to the peak force's. The numbers are stored column by column, each
# column's bytes low plane then high, the time and strength columns in the
# order of _stored_order (rows alike in pair and rank, of all worlds,
# together): most of what LZMA squeezes is alike numbers side by side.
_ALIKE_RANKS = 3  # a pair's episodes from the 3rd on are alike enough to be stored together


def pack(record: EventRecord, frame_count: np.ndarray) -> dict[str, np.ndarray]:
  """``events_counts``, ``events_rows``, ``events_strength``: u8 blobs of
  ``record`` (quickstart: about 3.7 bytes an episode with its strength)."""
  rows = np.asarray(record.rows, np.int64).reshape(-1, 4)
  counts = np.asarray(record.counts, np.int64)
  order, same_pair = _stored_order(rows, counts)
  since = rows[:, ROW["first"]].copy()
  since[1:][same_pair[1:]] -= rows[:-1, ROW["last"]][same_pair[1:]]
  # "To the world's end" only for a pair's last episode: a later one counts from this one's last.
  pair_last = np.append(~same_pair[1:], True)
  to_end = pair_last & (rows[:, ROW["last"]] == np.repeat(record.end_ticks(frame_count), counts))
  length = np.where(to_end, 0, rows[:, ROW["last"]] - rows[:, ROW["first"]] + 1)
  codes = strength_codes(record.strength).astype(np.int64)[order]
  relative = (codes[:, STRENGTH["impulse"]] - codes[:, STRENGTH["peak_force"]]) % (1 << 16)
  return {"events_counts": _pack_columns(counts[None]),
          "events_rows": _pack_columns(np.stack([rows[:, ROW["a"]], rows[:, ROW["b"]], since[order], length[order]])),
          "events_strength": _pack_columns(np.stack([codes[:, STRENGTH["peak_force"]], relative]))}


def _stored_order(rows: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(i64[N] the rows' stored order: by pair, rank within the world's
  episodes of the pair (capped at :data:`_ALIKE_RANKS`), world; bool[N] each
  row has the pair of the row before it in the same world)."""
  n = len(rows)
  world = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
  same_pair = np.zeros(n, bool)
  same_pair[1:] = ((rows[1:, ROW["a"]] == rows[:-1, ROW["a"]]) & (rows[1:, ROW["b"]] == rows[:-1, ROW["b"]])
                   & (world[1:] == world[:-1]))
  run_start = np.flatnonzero(~same_pair)
  rank = np.arange(n) - np.repeat(run_start, np.diff(np.append(run_start, n)))
  return np.lexsort((world, np.minimum(rank, _ALIKE_RANKS), rows[:, ROW["b"]], rows[:, ROW["a"]])), same_pair


def _pack_columns(columns: np.ndarray) -> np.ndarray:
  """u8 blob of i64[k, n]: a byte giving the width of a number (2: all in
  [0, 65536), else 4), then LZMA of the columns' byte planes."""
  columns = np.asarray(columns, np.int64)
  width = 2 if columns.size == 0 or (columns.min() >= 0 and columns.max() < 1 << 16) else 4
  data = columns.astype(np.uint16 if width == 2 else np.int32)
  planes = data.view(np.uint8).reshape(len(data), -1, width).transpose(0, 2, 1)
  packed = lzma.compress(np.ascontiguousarray(planes).tobytes(), format=lzma.FORMAT_RAW, filters=_LZMA_FILTERS)
  return np.frombuffer(bytes([width]) + packed, np.uint8).copy()


def _unpack_columns(blob, k: int, n: int) -> np.ndarray:
  """i64[k, n] from :func:`_pack_columns`'s bytes (ValueError if they do not hold that many)."""
  blob = np.asarray(blob, np.uint8).reshape(-1)
  if blob.size < 1 or int(blob[0]) not in (2, 4):
    raise ValueError("unknown packing")
  width = int(blob[0])
  raw = np.frombuffer(lzma.decompress(blob[1:].tobytes(), format=lzma.FORMAT_RAW, filters=_LZMA_FILTERS), np.uint8)
  if raw.size != k * n * width:
    raise ValueError(f"{raw.size // max(k * width, 1)} numbers stored where {n} were counted")
  planes = np.ascontiguousarray(raw.reshape(k, width, n).transpose(0, 2, 1))
  return planes.view(np.uint16 if width == 2 else np.int32).reshape(k, n).astype(np.int64)


def _unpack_counts(blob, n_worlds: int) -> np.ndarray:
  return _unpack_columns(blob, 1, n_worlds)[0]


def _unpack_rows(blob, counts: np.ndarray, world_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(i32[N, 4] rows, i64[N] their stored order) from :func:`pack`'s
  ``events_rows``; ``world_end`` i64[W] each world's last tick."""
  counts = np.asarray(counts, np.int64)
  n = int(counts.sum())
  a, b, since_stored, length_stored = _unpack_columns(blob, 4, n)
  rows = np.zeros((n, 4), np.int64)
  rows[:, ROW["a"]], rows[:, ROW["b"]] = a, b
  order, same_pair = _stored_order(rows, counts)
  since, length = np.empty(n, np.int64), np.empty(n, np.int64)
  since[order], length[order] = since_stored, length_stored
  # first = the previous episode's last + since, last = first + length - 1:
  # a running sum restarted at each pair's first episode.
  step = since.copy()
  step[1:][same_pair[1:]] += length[:-1][same_pair[1:]] - 1
  total = np.cumsum(step)
  run_start = np.flatnonzero(~same_pair)
  rows[:, ROW["first"]] = total - np.repeat(total[run_start] - step[run_start], np.diff(np.append(run_start, n)))
  rows[:, ROW["last"]] = np.where(length == 0, np.repeat(np.asarray(world_end, np.int64), counts),
                                  rows[:, ROW["first"]] + length - 1)
  return rows.astype(np.int32), order


def _unpack_strength(blob, order: np.ndarray) -> np.ndarray:
  """f32[N, 2] from :func:`pack`'s ``events_strength``, stored in ``order`` (its rows')."""
  peak, relative = _unpack_columns(blob, 2, len(order))
  codes = np.empty((len(order), 2), np.int64)
  codes[order, STRENGTH["peak_force"]] = peak
  codes[order, STRENGTH["impulse"]] = (peak + relative) % (1 << 16)
  return strength_values(codes)


def _unpack_rows_v2(blob: np.ndarray, n_rows: int) -> np.ndarray:
  """i32[n_rows, 4] of events version 1 or 2: a byte giving the width (2 or
  4), then zlib of the columns, ``last`` as ``last - first``."""
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


def _unpack_strength_v2(blob: np.ndarray, n_rows: int) -> np.ndarray:
  """f32[n_rows, 2] of events version 2: each float's top two bytes (bfloat16), byte planes, zlib'd."""
  raw = np.frombuffer(zlib.decompress(np.asarray(blob, np.uint8).tobytes()), np.uint8)
  if raw.size != 4 * n_rows:
    raise ValueError(f"{raw.size // 4} strengths stored, {n_rows} counted")
  top = np.ascontiguousarray(raw.reshape(2, -1).T).view(np.uint16).reshape(-1)
  return (top.astype(np.uint32) << 16).view(np.float32).reshape(n_rows, 2)


def merge(parts: Sequence[tuple[tuple[str, ...], "EventRecord | None"]]):
  """One record of several, each with the actor names its indices refer to
  (banks of different scene versions name different actors).

  Returns:
    (actor names: the first part's, then names only later parts have;
    the record, its rows relabelled to those names), or ((), None) if any
    part has no record. Parts not decoded yet (:class:`~mwbx.events.lazy.LazyEvents`)
    give a record decoded when first used.
  """
  if not parts or any(record is None for _, record in parts):
    return (), None
  names: list[str] = []
  for actors, _ in parts:
    names.extend(name for name in actors if name not in names)
  names = tuple(names)
  records = [record for _, record in parts]
  if not any(isinstance(record, lazy.LazyEvents) for record in records):
    return names, _merged(parts, names)

  def with_impulse():
    known = [lazy.known_without_decoding(record) for record in records]
    return None if None in known else sum(known)

  return names, lazy.LazyEvents(lambda: _merged(parts, names),
                                lambda: np.concatenate([np.asarray(r.counts, np.int32) for r in records]),
                                int(np.lcm.reduce([record.ticks_per_frame for record in records])), with_impulse)


def _merged(parts, names: tuple[str, ...]) -> EventRecord:
  """:func:`merge`'s record, decoded."""
  ticks = int(np.lcm.reduce([record.ticks_per_frame for _, record in parts]))
  records = []
  for actors, record in parts:
    record = record.in_ticks(ticks)
    if tuple(actors) == names[:len(actors)]:
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
  return EventRecord.concat(records)
