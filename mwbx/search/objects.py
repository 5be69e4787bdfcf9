"""Which objects decide a query: what a search refines or guides for it."""

from __future__ import annotations

from typing import Collection, Sequence



def involved_objects(owner, query) -> list[str]:
  """Objects whose motion decides a query (:meth:`mwbx.Query.objects`): its
  bodies' objects (every object for a query on all bodies), or the object a
  joint query's joint belongs to.

  Args:
    owner: a :class:`~mwbx.Bank` or a :class:`~mwbx.Scene`.
    query: any :class:`~mwbx.Query`.
  """
  return query.objects(owner)


def spare_objects(objects: Sequence[str], held: Collection[str]) -> list[str]:
  """The objects a repair may change: ``objects`` but those ``held`` (each
  the only object meeting another ``mode: any`` query the world meets, by
  :meth:`mwbx.Query.per_object`); all of them when every one is held.

  Example:
    >>> spare_objects(["letter_G1", "letter_G2"], {"letter_G2"})
    ['letter_G1']
  """
  spare = [o for o in objects if o not in held]
  return spare or list(objects)
