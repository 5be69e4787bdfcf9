"""New banks from old ones: a subset of rows, worlds dropped, banks joined.

Every function returns a new bank and leaves its arguments as they are (a
bank is a frozen record). Arrays are taken or joined once each, through
:mod:`mwbx.bank.lazy` so a lazily loaded bank's shards are read only when
needed. :class:`~mwbx.Bank`'s ``append``, ``drop`` and ``concatenate`` call these.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from mwbx.bank import lazy
from mwbx.bank import saving
from mwbx.errors import MwbxError
from mwbx.events import record as events_lib


def take_rows(bank, rows: np.ndarray, **changes):
  """The bank of ``rows`` (i64[k], in that order; the store is copied), with
  ``changes`` to its other fields."""
  fields = {name: lazy.take_rows(getattr(bank, name), rows) for name in bank.ROW_ARRAYS}
  fields.update(qpos_store=bank.qpos_store.take(rows), next_id=bank.next_world_id,
                events=None if bank.events is None else bank.events.take(rows))
  return dataclasses.replace(bank, **{**fields, **changes})


def drop(bank, ids):
  """The bank without the worlds ``ids`` (their ids are never given again);
  their lineage entries go, worlds refined from them keep their parent id."""
  rows = bank.row_of(np.atleast_1d(np.asarray(ids, np.int64)))
  keep = np.setdiff1d(np.arange(bank.n_worlds), rows)
  dropped = {str(int(i)) for i in bank.world_ids[rows]}
  return take_rows(bank, keep, lineage={k: v for k, v in bank.lineage.items() if k not in dropped})


def append(bank, other):
  """``bank``'s worlds, then ``other``'s (same scene and config), renumbered
  from ``bank.next_world_id`` on if any of ``other``'s ids is below it."""
  if other.digest != bank.digest:
    raise MwbxError("append: the banks come from different configs or MJCF (digest mismatch)")
  if other.com.shape[1:] != bank.com.shape[1:]:
    raise MwbxError("append: polyline shapes differ")
  if other.qpos_store.kind != bank.qpos_store.kind:
    raise MwbxError("append: the banks store qpos differently (raw vs compressed)")
  return concatenate([bank, renumbered_after(other, bank)])


def concatenate(banks: Sequence):
  """One bank of the worlds of ``banks`` (same scene, distinct ids), in
  order; each array is joined once (not once per bank, as chained appends)."""
  banks = list(banks)
  if not banks:
    raise MwbxError("concatenate: no banks")
  first = banks[0]
  ids = np.concatenate([b.world_ids for b in banks])
  if len(np.unique(ids)) != ids.size:
    raise MwbxError("concatenate: the banks share world ids (use append, which renumbers)")
  for b in banks[1:]:
    if b.digest != first.digest or b.qpos_store.kind != first.qpos_store.kind:
      raise MwbxError("concatenate: the banks come from different scenes or qpos stores")
  store = lazy.concat_stores([b.qpos_store for b in banks])
  arrays = {name: lazy.concat_rows([getattr(b, name) for b in banks]) for name in first.ROW_ARRAYS}
  lineage = {k: v for b in banks for k, v in b.lineage.items()}
  actors, events = events_lib.merge([(b.event_actors, b.events) for b in banks])
  return dataclasses.replace(first, **arrays, qpos_store=store, lineage=lineage, events=events,
                             event_actors=actors, next_id=max(b.next_world_id for b in banks))


def renumbered_after(bank, first):
  """``bank`` with new ids from ``first.next_world_id`` on if any of its ids
  is below that (ids ``first`` may have given); parent ids and lineage follow."""
  start = first.next_world_id
  if not bank.n_worlds or bank.world_ids.min() >= start:
    return bank
  return saving.renumbered(bank, dict(zip(bank.world_ids.tolist(), range(start, start + bank.n_worlds))))
