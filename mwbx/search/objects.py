"""Which objects decide a query: what a search refines or guides for it."""

from __future__ import annotations

import dataclasses
from typing import Collection, Sequence

import numpy as np

from mwbx.queries import JointQuery
from mwbx.queries import Query
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
  chosen = set(_chosen_bodies(owner, query))
  return [obj for obj, bodies in owner.objects.items() if chosen & set(bodies)]


def _chosen_bodies(owner, query) -> list[str]:
  """The tracked body names a query's ``bodies`` (bodies, objects, groups) select."""
  rows = select_bodies(list(query.bodies), tuple(owner.body_names), owner.objects, owner.groups)
  return [owner.body_names[b] for b in np.asarray(rows).tolist()]


def alone(owner, query) -> dict[str, Query]:
  """A ``mode: any`` include query over several objects, as each object
  alone would meet it: {object: the query on that object's bodies only}; {}
  for any other query (an exclude query is met by each object that keeps
  out, so no one object holds it).

  Either G may fill either G slot on SIGGRAPH: the search must not refine the
  G that already fills one slot to fill the other, so it asks which object
  meets a query by itself (:func:`spare_objects`).

  Example::

    alone(bank, g_in_slot_2)  # {'letter_G1': <query on letter_G1>, 'letter_G2': <query on letter_G2>}
  """
  if not isinstance(query, Query) or not query.include or query.mode != "any" or query.bodies is None:
    return {}
  chosen = _chosen_bodies(owner, query)
  per_object = {obj: tuple(f"body:{b}" for b in chosen if b in bodies) for obj, bodies in owner.objects.items()}
  per_object = {obj: bodies for obj, bodies in per_object.items() if bodies}
  if len(per_object) < 2:
    return {}
  return {obj: dataclasses.replace(query, bodies=bodies, name=f"{query.name or 'query'} [{obj}]")
          for obj, bodies in per_object.items()}


def spare_objects(objects: Sequence[str], held: Collection[str]) -> list[str]:
  """The objects a repair may change: ``objects`` but those ``held`` (each
  the only object meeting another ``mode: any`` query the world meets, by
  :func:`alone`); all of them when every one is held.

  Example:
    >>> spare_objects(["letter_G1", "letter_G2"], {"letter_G2"})
    ['letter_G1']
  """
  spare = [o for o in objects if o not in held]
  return spare or list(objects)
