"""Lexicase selection: which world :func:`mwbx.solve` refines next, and which
children of a refinement it keeps.

A best-first search refines the one best world until its tries run out, so
its success hangs on the lineage it happens to follow. Lexicase selection
(Spector 2012; Helmuth, Spector and Matheson 2015) keeps many lineages
alive without a distance between worlds or a tuned constant: each pick
draws a fresh random order of the queries and filters the worlds by them in
turn, keeping only the worlds that meet the query whenever some do. The
world left is the best at that order's first queries: the world meeting the
most queries whenever those come first, and otherwise a *specialist*, one
meeting a query that better worlds fail (a letter in the slot no better
world has it in). Every world meeting a set of queries no other world's set
contains is picked by some order, and so worked on.

The queries the search ranks first (:func:`~mwbx.search.place_queries`)
come first in every order: a world lacking a place is never chosen over
one that has it for a pose it meets.
"""

from __future__ import annotations

import numpy as np


def query_order(first: np.ndarray, rng: np.random.Generator) -> np.ndarray:
  """i[Q] a random order of the queries: those marked in ``first`` (bool[Q])
  in a random order, then the others in a random order."""
  first = np.asarray(first, bool)
  head, tail = np.flatnonzero(first), np.flatnonzero(~first)
  return np.concatenate([rng.permutation(head), rng.permutation(tail)]).astype(np.int64)


def lexicase(met: np.ndarray, order: np.ndarray, score: np.ndarray) -> int:
  """The world lexicase selection picks for one order of the queries.

  Args:
    met: bool[n, Q] which queries each candidate world meets.
    order: i[Q] the order the queries filter in (:func:`query_order`).
    score: f[n] higher is better: breaks the tie between the worlds left,
      which meet the same queries (the nearest to the rest, say).

  Returns:
    the index (into the n candidates) of the world picked.

  Example:
    >>> met = np.array([[1, 1, 0], [0, 0, 1], [1, 0, 0]], bool)
    >>> lexicase(met, np.array([0, 1, 2]), np.zeros(3)), lexicase(met, np.array([2, 0, 1]), np.zeros(3))
    (0, 1)
  """
  met = np.asarray(met, bool)
  if met.shape[0] == 0:
    raise ValueError("lexicase: no candidate worlds")
  alive = np.arange(met.shape[0])
  for q in order:
    meets = met[alive, q]
    if meets.any():
      alive = alive[meets]
    if alive.size == 1:
      break
  return int(alive[np.argmax(np.asarray(score)[alive])])


def first_unmet(met_row: np.ndarray, order: np.ndarray) -> list[int]:
  """The queries a world fails (``met_row``: bool[Q]), in ``order``."""
  return [int(q) for q in order if not met_row[q]]


def lexicase_keep(met: np.ndarray, score: np.ndarray, keep: int, orders) -> np.ndarray:
  """i[<= keep] the candidates kept, one lexicase pick per order in ``orders``
  (each over the candidates not kept yet), in the order picked."""
  met = np.asarray(met, bool)
  left = np.arange(met.shape[0])
  kept = []
  for order in orders:
    if len(kept) == keep or left.size == 0:
      break
    pick = left[lexicase(met[left], order, np.asarray(score)[left])]
    kept.append(int(pick))
    left = left[left != pick]
  return np.asarray(kept, np.int64)
