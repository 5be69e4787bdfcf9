"""Which tracked bodies a query's ``bodies`` (body, object or group names) select."""

from __future__ import annotations

import numpy as np

from mwbx.scene import select_bodies


def selection_mask(bank, bodies) -> np.ndarray:
  """bool[B] of the tracked bodies named by body/object/group names (None: all)."""
  n_bodies = len(bank.body_names)
  if bodies is None:
    return np.ones(n_bodies, bool)
  if isinstance(bodies, str):
    bodies = (bodies,)
  mask = np.zeros(n_bodies, bool)
  if len(bodies):
    mask[np.asarray(bank.select_bodies(list(bodies)), np.int64)] = True
  return mask


def chosen_bodies(owner, bodies) -> list[str]:
  """The tracked body names that ``bodies`` (bodies, objects, groups) select.

  Args:
    owner: a :class:`~mwbx.Bank` or :class:`~mwbx.Scene`.
    bodies: names (not None).
  """
  rows = select_bodies(list(bodies), tuple(owner.body_names), owner.objects, owner.groups)
  return [owner.body_names[b] for b in np.asarray(rows).tolist()]
