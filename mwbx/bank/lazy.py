"""Bank arrays read from their shards on demand.

A bank opened lazily (the default of :meth:`mwbx.Bank.load`) reads the
manifest and each shard's small arrays (ids, flags, metrics, ...) at once;
the two big ones stay on disk until used:

- :class:`LazyRows` stands in for ``bank.com`` (f32[W, P, B, 3]): indexing
  reads and decodes only the shards holding the rows asked for, and
  :meth:`LazyRows.blocks` walks the bank a shard at a time, so queries run in
  the memory of one shard (:func:`mwbx.queries.evaluate_each`).
- :class:`LazyQposStore` stands in for ``bank.qpos_store``: ``frames(row)``
  reads the one shard holding that world.

Each piece is read by a loader that checks the shard's checksums, so a
corrupt shard is named when it is first read. A few decoded pieces are kept
(``CACHED_PIECES``, least recently used). Both classes keep a row map
(piece, row within the piece), so taking, dropping and concatenating rows,
as :class:`mwbx.Bank` does, stays lazy; in-memory arrays and stores (new
worlds) are pieces too.
"""

from __future__ import annotations

import collections
import threading
from typing import Iterator

import numpy as np

from mwbx import host_pool

# Decoded pieces each lazy array keeps (least recently used first out).
CACHED_PIECES = 2
# Reads the pieces of one request, a thread per core.
_READERS = host_pool.LazyPool("mwbx-shard-read")


class _Pieces:
  """Pieces (an object, or a loader called once per use) with a small LRU
  cache, and per piece an optional companion loader (a small summary stored
  beside it, e.g. the COM paths' boxes)."""

  def __init__(self, sources: list, companions: list | None = None):
    self.sources = list(sources)
    self.companions = list(companions) if companions is not None else [None] * len(self.sources)
    self._cache: collections.OrderedDict = collections.OrderedDict()
    self._lock = threading.Lock()

  def companion(self, p: int, compute):
    """The companion of piece ``p``: its loader's value, else ``compute(piece)``."""
    loader = self.companions[p]
    return loader() if loader is not None else compute(self.get(p))

  def get(self, p: int):
    source = self.sources[p]
    if not callable(source):
      return source
    with self._lock:
      if p in self._cache:
        self._cache.move_to_end(p)
        return self._cache[p]
    value = source()
    with self._lock:
      self._cache[p] = value
      while len(self._cache) > CACHED_PIECES:
        self._cache.popitem(last=False)
    return value


class _RowMap:
  """Which piece and which row of it each bank row is."""

  def __init__(self, pieces: _Pieces, piece: np.ndarray, local: np.ndarray):
    self.pieces = pieces
    self.piece = np.asarray(piece, np.int32)
    self.local = np.asarray(local, np.int64)

  @classmethod
  def of(cls, sources: list, counts: list[int], companions: list | None = None) -> "_RowMap":
    counts = np.asarray(counts, np.int64)
    piece = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
    local = np.concatenate([np.arange(n) for n in counts]) if len(counts) else np.zeros(0, np.int64)
    return cls(_Pieces(sources, companions), piece, local)

  def take(self, rows) -> "_RowMap":
    rows = np.asarray(rows, np.int64).reshape(-1)
    return _RowMap(self.pieces, self.piece[rows], self.local[rows])

  @staticmethod
  def concat(maps: list["_RowMap"]) -> "_RowMap":
    sources, companions, piece, local = [], [], [], []
    for m in maps:
      piece.append(m.piece + len(sources))
      local.append(m.local)
      sources.extend(m.pieces.sources)
      companions.extend(m.pieces.companions)
    return _RowMap(_Pieces(sources, companions), np.concatenate(piece), np.concatenate(local))

  def groups(self, rows: np.ndarray) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(piece, positions in ``rows``, local rows) for the pieces ``rows`` touch, in piece order."""
    pieces = self.piece[rows]
    # One stable sort, not a pass over the rows per piece (thousands of shards).
    order = np.arange(pieces.size) if np.all(pieces[1:] >= pieces[:-1]) else np.argsort(pieces, kind="stable")
    starts = np.flatnonzero(np.diff(pieces[order])) + 1
    for where in np.split(order, starts) if pieces.size else ():
      yield int(pieces[where[0]]), where, self.local[rows[where]]


class LazyRows:
  """An array of rows (shape [W, ...]) read from shards on demand.

  Reads like the numpy array it stands for: ``shape``, ``dtype``, ``len``,
  ``a[i]``, ``a[rows]``, ``a[i, j]``, ``np.asarray(a)`` (every row: the whole
  array in memory). :meth:`blocks` is the bounded-memory way through it.

  Args:
    sources: per piece, an array or a loader returning one.
    counts: rows per piece.
    row_shape: the shape of one row; dtype: the element type.
    companions: per piece, None or a loader of a summary stored beside it
      (:meth:`companions`).
  """

  def __init__(self, sources: list, counts: list[int], row_shape: tuple, dtype, rowmap: _RowMap | None = None,
               companions: list | None = None):
    self._map = rowmap if rowmap is not None else _RowMap.of(sources, counts, companions)
    self.row_shape = tuple(row_shape)
    self.dtype = np.dtype(dtype)
    self._all = None
    self._companions_stored = None

  @classmethod
  def of(cls, array: np.ndarray) -> "LazyRows":
    """An in-memory array as a one-piece LazyRows."""
    return cls([np.asarray(array)], [len(array)], array.shape[1:], array.dtype)

  @property
  def shape(self) -> tuple:
    return (len(self._map.piece),) + self.row_shape

  @property
  def ndim(self) -> int:
    return 1 + len(self.row_shape)

  @property
  def nbytes(self) -> int:
    """Bytes of the decoded array (what ``np.asarray`` would hold)."""
    return int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize

  def __len__(self) -> int:
    return len(self._map.piece)

  def __repr__(self) -> str:
    return f"LazyRows(shape={self.shape}, dtype={self.dtype}, pieces={len(self._map.pieces.sources)})"

  def rows(self, rows, out: np.ndarray | None = None) -> np.ndarray:
    """[k, ...] the given rows (i64[k]), in that order (written into ``out``
    when given, an array of that shape and dtype). Rows of several pieces are
    read a piece per core at once (reading a shard's files, checking and
    inflating them let go of the GIL)."""
    rows = np.asarray(rows, np.int64).reshape(-1)
    if out is None:
      out = np.empty((rows.size,) + self.row_shape, self.dtype)
    if self._all is not None:
      np.take(self._all, rows, axis=0, out=out)
      return out

    def fill(group):  # each piece fills its own rows of ``out``
      p, where, local = group
      piece = self._map.pieces.get(p)
      if _is_run(where) and _is_run(local):  # a piece's rows in order: one copy, no temporary
        out[where[0]:where[0] + where.size] = piece[local[0]:local[0] + local.size]
      else:
        out[where] = piece[local]

    groups = list(self._map.groups(rows))
    if len(groups) > 1:
      for _ in _READERS.get().map(fill, groups):
        pass
    else:
      for group in groups:
        fill(group)
    return out

  def __getitem__(self, key):
    """numpy indexing: the rows the first index names are read, then the whole
    index is applied to them (so ``a[rows, frames]`` pairs like numpy's)."""
    rest = ()
    if isinstance(key, tuple):
      key, rest = key[0], key[1:]
    n = len(self)
    if isinstance(key, (int, np.integer)):
      k = int(key) + n if key < 0 else int(key)
      if not 0 <= k < n:
        raise IndexError(f"row {key} out of range for {n} rows")
      out = self.rows([k])[0]
      return out[rest] if rest else out
    if isinstance(key, slice):
      out = self.rows(np.arange(n)[key])
      return out[(slice(None),) + rest] if rest else out
    index = np.asarray(key)
    if index.dtype == bool:
      index = np.flatnonzero(index)
    index = np.where(index < 0, index + n, index)
    wanted, position = np.unique(index, return_inverse=True)
    return self.rows(wanted)[(position.reshape(index.shape),) + rest]

  def __array__(self, dtype=None, copy=None):
    out = self.rows(np.arange(len(self)))
    return out if dtype is None else out.astype(dtype)

  @property
  def is_materialized(self) -> bool:
    """Whether every row is in memory (:meth:`materialized` was called)."""
    return self._all is not None

  def materialized(self) -> np.ndarray:
    """Every row in memory, read once and kept (this object is immutable)."""
    if self._all is None:
      self._all = np.asarray(self)
    return self._all

  def companions_stored(self) -> bool:
    """Whether every piece read from disk has its companion stored beside it
    (in-memory pieces compute theirs cheaply)."""
    if self._companions_stored is None:  # (the row map never changes: asked once)
      pieces = self._map.pieces
      used = np.flatnonzero(np.bincount(self._map.piece, minlength=len(pieces.sources)))
      self._companions_stored = all(pieces.companions[p] is not None or not callable(pieces.sources[p])
                                    for p in used)
    return self._companions_stored

  def companions(self, compute) -> list[tuple[np.ndarray, np.ndarray, object]]:
    """(i64[k] bank rows, i64[k] their rows in the piece, the piece's companion)
    for every piece holding rows, in piece order: each companion read (a piece
    per core), or ``compute(piece array)`` for a piece without one (which reads
    and decodes it)."""
    rows = np.arange(len(self))
    groups = list(self._map.groups(rows))
    get = lambda group: self._map.pieces.companion(group[0], compute)
    values = list(_READERS.get().map(get, groups)) if len(groups) > 1 else [get(g) for g in groups]
    return [(rows[where], local, value) for (_, where, local), value in zip(groups, values)]

  def blocks(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(i64[k] bank rows, [k, ...] their values) a piece at a time: every row once."""
    rows = np.arange(len(self))
    for p, where, local in self._map.groups(rows):
      yield rows[where], self._map.pieces.get(p)[local]

  def take(self, rows) -> "LazyRows":
    return LazyRows([], [], self.row_shape, self.dtype, self._map.take(rows))

  @staticmethod
  def concat(arrays: list) -> "LazyRows":
    """One LazyRows of arrays and LazyRows of the same row shape, in order."""
    lazy = [a if isinstance(a, LazyRows) else LazyRows.of(np.asarray(a)) for a in arrays]
    first = lazy[0]
    return LazyRows([], [], first.row_shape, first.dtype, _RowMap.concat([a._map for a in lazy]))


def take_rows(array, rows):
  """``array[rows]`` that stays lazy for a :class:`LazyRows`."""
  return array.take(rows) if isinstance(array, LazyRows) else array[rows]


def concat_rows(arrays: list):
  """``np.concatenate(arrays)`` that stays lazy if any is a :class:`LazyRows`."""
  if any(isinstance(a, LazyRows) for a in arrays):
    return LazyRows.concat(arrays)
  return np.concatenate(arrays)


def concat_stores(stores: list):
  """One store of the worlds of ``stores`` (same kind), in order; lazy if any
  of them is a :class:`LazyQposStore`, else a concrete copy."""
  if any(isinstance(s, LazyQposStore) for s in stores):
    maps = [_store_map(s) for s in stores]
    return LazyQposStore(stores[0].kind, [], [], lambda: sum(s.nbytes for s in stores), _RowMap.concat(maps))
  out = stores[0].copy()
  out.extend(*stores[1:])
  return out


def _store_map(store) -> _RowMap:
  """The row map of a lazy store, or a one-piece map of a copy of a concrete one."""
  return store._map if isinstance(store, LazyQposStore) else _RowMap.of([store.copy()], [store.n_worlds])


class LazyQposStore:
  """A :class:`~mwbx.qpos_store.QposStore` whose shards are read on demand.

  ``frames`` reads the one shard holding the world; ``take``, ``copy`` and
  ``extend`` stay lazy; ``stats`` reads each shard's small arrays (where its
  loader has ``figures`` and ``empty``); ``state``, ``refined`` and anything
  else build the concrete store of the rows held (every shard they touch).

  Args:
    kind: the stores' kind; sources: per piece, a store or a loader returning
      one; counts: worlds per piece; nbytes: bytes the pieces take on disk, or
      a function counting them (called when first asked: a stat per file).
  """

  def __init__(self, kind: str, sources: list, counts: list[int], nbytes=0, rowmap: _RowMap | None = None):
    self.kind = kind
    self._map = rowmap if rowmap is not None else _RowMap.of(sources, counts)
    self._nbytes = nbytes

  def _with(self, rowmap: _RowMap) -> "LazyQposStore":
    return LazyQposStore(self.kind, [], [], self._nbytes, rowmap)

  def concrete(self):
    """The concrete store of the rows held, in order (reads their shards)."""
    rows = np.arange(self.n_worlds)
    parts = []
    for p, _, local in self._map.groups(rows):
      piece = self._map.pieces.get(p)
      whole = local.size == piece.n_worlds and _is_run(local) and int(local[0]) == 0
      parts.append(piece if whole else piece.take(local))  # a whole piece is read, not copied row by row
    store = (parts[0] if parts else self._map.pieces.get(0)).empty()  # pieces stay as cached
    store.extend(*parts)
    if not np.all(np.diff(self._map.piece) >= 0):  # rows not in piece order: reorder
      order = np.concatenate([where for _, where, _ in self._map.groups(rows)])
      store = store.take(np.argsort(order))
    return store

  # -- the QposStore protocol -----------------------------------------------------

  def append(self, qpos, frame_count) -> None:
    store = self._map.pieces.get(0).empty()
    store.append(qpos, frame_count)
    self.extend(store)

  def extend(self, *others) -> None:
    self._map = _RowMap.concat([self._map] + [_store_map(other) for other in others])

  def copy(self) -> "LazyQposStore":
    return self._with(self._map.take(np.arange(self.n_worlds)))

  def empty(self):
    return self._map.pieces.get(0).empty()

  def take(self, rows) -> "LazyQposStore":
    return self._with(self._map.take(rows))

  def refined(self, after, first_frame, frame_count, parent, parent_frames, keep_qpos):
    p, local = int(self._map.piece[parent]), int(self._map.local[parent])
    return self._map.pieces.get(p).refined(after, first_frame, frame_count, local, parent_frames, keep_qpos)

  def row_frames(self, row: int, start: int = 0, stop: int | None = None, columns=None) -> np.ndarray:
    p, local = int(self._map.piece[row]), int(self._map.local[row])
    return self._map.pieces.get(p).row_frames(local, start, stop, columns)

  def frames_of_rows(self, rows=None, start: int = 0, stop: int | None = None, **kwargs):
    rows = np.arange(self.n_worlds) if rows is None else np.asarray(rows, np.int64)
    return self.take(rows).concrete().frames_of_rows(None, start, stop, **kwargs)

  @property
  def n_worlds(self) -> int:
    return len(self._map.piece)

  @property
  def nbytes(self) -> int:
    """Bytes of the stored streams on disk (none of them is in memory until read)."""
    if callable(self._nbytes):
      self._nbytes = int(self._nbytes())
    return int(self._nbytes)

  def stats(self) -> dict:
    """The concrete store's stats, from each piece's per-world figures: a
    shard's from its small arrays (a loader's ``figures``), without reading
    its streams."""
    figures, like = [], None
    for p, _, local in self._map.groups(np.arange(self.n_worlds)):
      source = self._map.pieces.sources[p]
      if hasattr(source, "figures"):
        piece, like = source.figures(), source.empty() if like is None else like
      else:
        store = self._map.pieces.get(p)
        piece, like = store.row_figures(), store if like is None else like
      figures.append({name: values[local] for name, values in piece.items()})
    if like is None:  # no worlds
      return self.empty().stats()
    return like.stats_of({name: np.concatenate([f[name] for f in figures]) for name in figures[0]})

  def relaid(self, target, fill):
    return self.concrete().relaid(target, fill)

  def state(self) -> tuple[dict, dict]:
    return self.concrete().state()

  @classmethod
  def restore(cls, arrays: dict, meta: dict):
    raise TypeError("LazyQposStore is made by Bank.load; restore the concrete store class")

  def __getattr__(self, name):  # the concrete store's other methods (stream, ...)
    if name.startswith("_"):
      raise AttributeError(name)
    return getattr(self.concrete(), name)


def _is_run(index: np.ndarray) -> bool:
  """Whether i64[k] ``index`` is k consecutive increasing values (k > 0)."""
  return index.size > 0 and int(index[-1]) - int(index[0]) == index.size - 1 and bool(np.all(np.diff(index) == 1))
