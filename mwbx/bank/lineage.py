"""A bank's family tree: which world was refined from which.

Pure functions of a bank's ``world_ids`` and ``parent_world`` (i64[W]: the
id each world was refined from, -1 for a sampled one); :class:`~mwbx.Bank`'s
``children``, ``descendants``, ``ancestors`` and ``under`` call them. A world
refined from one later dropped keeps its parent's id: its ancestry stops there.
"""

from __future__ import annotations

import numpy as np


def children(bank, world_id: int) -> np.ndarray:
  """i64[k] ids of the worlds refined directly from ``world_id``.

  Raises:
    MwbxError: the bank holds no world ``world_id``.
  """
  bank.row_of(int(world_id))
  return bank.world_ids[bank.parent_world == int(world_id)].copy()


def descendants(bank, world_id: int) -> np.ndarray:
  """i64[k] ids of every world refined from ``world_id``, directly or not,
  generation by generation."""
  bank.row_of(int(world_id))
  out, frontier = [], [int(world_id)]
  while frontier:
    kids = bank.world_ids[np.isin(bank.parent_world, frontier)]
    out.extend(kids.tolist())
    frontier = kids.tolist()
  return np.asarray(out, np.int64)


def ancestors(bank, world_id: int) -> np.ndarray:
  """i64[k] ids of the worlds ``world_id`` was refined from, its parent first,
  up to the sampled world (or the first one dropped from the bank)."""
  out = []
  parent = int(bank.parent_world[bank.row_of(int(world_id))])
  while parent >= 0:
    out.append(parent)
    hit = np.flatnonzero(bank.world_ids == parent)  # absent: dropped from the bank
    parent = int(bank.parent_world[hit[0]]) if hit.size else -1
  return np.asarray(out, np.int64)


def under(bank, world_id: int) -> np.ndarray:
  """bool[W] the worlds in the family tree below ``world_id``, itself included."""
  return np.isin(bank.world_ids, np.concatenate([[int(world_id)], descendants(bank, world_id)]))
