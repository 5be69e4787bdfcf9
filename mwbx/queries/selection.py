"""Which tracked bodies a query's ``bodies`` (body, object or group names) select."""

from __future__ import annotations

import numpy as np

from mwbx.errors import MwbxError
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


def turning_mask(bank, bodies, label: str) -> np.ndarray:
  """:func:`selection_mask` without a flex's vertex bodies, which never turn
  (orientation queries and turning metrics): a name that selects only a
  flex's vertices (``cloth``), or a selection left empty, is refused; an
  object that holds a flex among its rigid bodies keeps those bodies.

  Raises:
    MwbxError: one line, starting with ``label``.
  """
  mask = selection_mask(bank, bodies)
  vertices = bank.flex_body_mask()
  if not vertices.any():
    return mask
  names = () if bodies is None else ((bodies,) if isinstance(bodies, str) else tuple(bodies))
  for name in names:
    if not (selection_mask(bank, (name,)) & ~vertices).any():
      raise MwbxError(f"{label}: bodies: {name} is a flex's vertices; a flex (cloth, soft solid, rope) has no"
                      " orientation")
  mask = mask & ~vertices
  if not mask.any():
    raise MwbxError(f"{label}: every tracked body is a flex's vertex; a flex (cloth, soft solid, rope) has no"
                    " orientation")
  return mask
