"""Which objects decide a query: what a search refines or guides for it."""

from __future__ import annotations

import numpy as np

from mwbx.queries import JointQuery
from mwbx.scene import select_bodies


def involved_objects(owner, query) -> list[str]:
  """Objects whose motion decides a query: its bodies' objects (every object
  for a query on all bodies), or the object a joint query's joint belongs to.

  Args:
    owner: a :class:`~mwbx.Bank` or a :class:`~mwbx.Scene` (its tracked
      bodies, objects, groups and model).
    query: a :class:`~mwbx.Query`, :class:`~mwbx.OrientationQuery` (by their bodies) or
      :class:`~mwbx.JointQuery`.
  """
  if isinstance(query, JointQuery):
    model = owner.model() if callable(owner.model) else owner.model
    body = model.jnt_bodyid[model.joint(query.joint).id]
    root = model.body(int(model.body_rootid[body])).name
    return [root] if root in owner.objects else []
  if query.bodies is None:
    return list(owner.objects)
  rows = select_bodies(list(query.bodies), tuple(owner.body_names), owner.objects, owner.groups)
  chosen = {owner.body_names[b] for b in np.asarray(rows).tolist()}
  return [obj for obj, bodies in owner.objects.items() if chosen & set(bodies)]
