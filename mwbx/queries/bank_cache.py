"""What queries build from a bank once and reuse: kept per bank while it lives.

Browsing asks the same bank again and again, so the bounds hierarchy, the
geometry index and decoded joint angles and orientations are built once. A
:class:`PerBank` keeps each value under the bank (by identity, weakly: it
goes when the bank goes) and a key, with a *state* token (world count, the
qpos store's identity, ...) that says when the bank changed under it.

Example::

  _INDEX = PerBank()
  index = _INDEX.get(bank, "index", (bank.n_worlds,), lambda: build(bank))
"""

from __future__ import annotations

from typing import Callable, Hashable, TypeVar
import weakref

T = TypeVar("T")


class PerBank:
  """Values kept per (bank, key), rebuilt when the bank's state token changes."""

  def __init__(self):
    self._entries: dict = {}  # (id(bank), key) -> (weakref or bank, state, value)

  def get(self, bank, key: Hashable, state: Hashable, build: Callable[[], T]) -> T:
    """The value of ``bank`` under ``key``: the kept one if it was built for the
    same ``state``, else ``build()``, kept."""
    entry = self._entries.get((id(bank), key))
    if entry is not None:
      ref, old_state, value = entry
      alive = ref() if isinstance(ref, weakref.ref) else ref
      if alive is bank and old_state == state:
        return value
    value = build()
    self.put(bank, key, state, value)
    return value

  def peek(self, bank, key: Hashable, state: Hashable):
    """The kept value, or None."""
    entry = self._entries.get((id(bank), key))
    if entry is None:
      return None
    ref, old_state, value = entry
    alive = ref() if isinstance(ref, weakref.ref) else ref
    return value if alive is bank and old_state == state else None

  def put(self, bank, key: Hashable, state: Hashable, value) -> None:
    slot = (id(bank), key)
    try:
      ref = weakref.ref(bank, lambda _, entries=self._entries, bank_id=id(bank): _forget(entries, bank_id))
    except TypeError:  # not weak-referenceable: kept strongly, but only the latest such bank
      ref = bank
      for k in [k for k, (r, _, _) in self._entries.items() if not isinstance(r, weakref.ref) and k[0] != id(bank)]:
        del self._entries[k]
    self._entries[slot] = (ref, state, value)

  def clear(self) -> None:
    self._entries.clear()


def _forget(entries: dict, bank_id: int) -> None:
  for k in [k for k in entries if k[0] == bank_id]:
    entries.pop(k, None)
