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


def is_place_query(query) -> bool:
  """Whether a query asks where its bodies end up: an include query whose
  window opens at a time and runs to the end (a letter rests in its slot for
  the last second). Only one such place can hold a body, and other bodies
  resting there may keep it out."""
  return (isinstance(query, Query) and query.include and query.bodies is not None and query.window is not None
          and query.window[0] is not None and query.window[1] is None)


def place_variants(owner, query) -> dict[str, Query]:
  """A place query (:func:`is_place_query`) as each object alone would meet
  it, for every object of the scene, involved or not: {object: the query on
  that object's bodies, mode any}; {} for any other query.

  The search asks which objects rest where a query wants others
  (:func:`occupants`): on SIGGRAPH a G left in S's slot keeps S out, so
  repairing S moves that G too.

  Example::

    place_variants(bank, s_in_slot_0)['letter_G2']  # S's slot asked of G2
  """
  if not is_place_query(query):
    return {}
  return {obj: dataclasses.replace(query, bodies=tuple(f"body:{b}" for b in bodies), mode="any",
                                   name=f"{query.name or 'query'} [{obj}]")
          for obj, bodies in owner.objects.items() if bodies}


def occupants(involved: Collection[str], here: Collection[str], placed: Collection[str]) -> list[str]:
  """The objects in the way of a place query: those resting in its place
  (``here``) that it does not ask for (not ``involved``) and that are not in
  a place asked of them (not ``placed``: an object where it belongs is not
  moved for another).

  Example:
    >>> occupants(["letter_S"], ["letter_G2", "letter_S", "letter_I"], {"letter_I"})
    ['letter_G2']
  """
  return [o for o in here if o not in involved and o not in placed]
