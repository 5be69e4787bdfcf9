"""Thread pools for host stages (the codec's fit, whole-geometry passes): a
thread per core, made on first use, and made afresh in a forked child (which
has none of its parent's threads).

Example::

  _POOL = LazyPool("mwbx-codec-fit")
  results = list(_POOL.get().map(work, items))
"""

from __future__ import annotations

import concurrent.futures
import os
import weakref

_ALL: "weakref.WeakSet[LazyPool]" = weakref.WeakSet()


class LazyPool:
  """A ``ThreadPoolExecutor`` with a thread per core, made on first :meth:`get`."""

  def __init__(self, name: str):
    self.name = name
    self._pool: concurrent.futures.ThreadPoolExecutor | None = None
    _ALL.add(self)

  def get(self) -> concurrent.futures.ThreadPoolExecutor:
    if self._pool is None:
      self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=os.cpu_count() or 1,
                                                         thread_name_prefix=self.name)
    return self._pool

  def forget(self) -> None:
    """Drops the pool (a forked child's copy has no threads behind it)."""
    self._pool = None


def _forget_all() -> None:
  for pool in list(_ALL):
    pool.forget()


os.register_at_fork(after_in_child=_forget_all)
