"""The one numba decorator of mwbx's host loops, and where its machine code is kept.

Every host-side kernel (the codec's bit loops, the native backend's and the
refinement's per-world loops, the per-step bookkeeping) compiles with it:
``cache=True`` keeps the machine code on disk between runs, and
``nogil=True`` lets the native backend's threads (one world each) and a
compressing thread run at once.

The machine code of mwbx's kernels is kept in ``~/.cache/mwbx/numba`` (by
package path), not beside the sources: another clone or checkout of the same
code on this machine loads it instead of compiling again (about 30 s of a
first run on 2 cores). It is checked against a hash of every source file of
the package, not only the kernel's own file: numba inlines a kernel's callees
from other modules and freezes module constants into the machine code, so a
change to ``host_bookkeeping.py`` must also recompile ``compiled_world.py``'s
loop that calls it (numba's per-file check kept the stale loop).
``NUMBA_CACHE_DIR``, if set, is used instead, as numba documents (with
numba's per-file check).
"""

from __future__ import annotations

import functools
import hashlib
import os

import numba
from numba.core import cgutils, types
from numba.extending import intrinsic

PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
CACHE_DIR = os.path.join(os.path.expanduser("~"), ".cache", "mwbx", "numba")


@functools.lru_cache(maxsize=None)
def package_source_hash() -> bytes:
  """sha256 over the names and contents of every ``.py`` file of the package."""
  digest = hashlib.sha256()
  for folder, dirs, files in sorted(os.walk(PACKAGE_DIR)):
    dirs[:] = sorted(d for d in dirs if d != "__pycache__")
    for name in sorted(f for f in files if f.endswith(".py")):
      path = os.path.join(folder, name)
      digest.update(os.path.relpath(path, PACKAGE_DIR).encode() + b"\0")
      with open(path, "rb") as f:
        digest.update(hashlib.sha256(f.read()).digest())
  return digest.digest()


def _shared_cache_locator():
  """A numba cache locator for files of this package (None where numba's
  caching internals differ from what it is written for: numba's own
  locators then keep the code beside the sources)."""
  try:
    from numba.core import caching
    base = (caching._SourceFileBackedLocatorMixin, caching._CacheLocator)
    caching.CacheImpl._locator_classes  # noqa: B018 (where the locators are listed)
  except (ImportError, AttributeError):
    return None

  class SharedCacheLocator(*base):
    """Kernels of mwbx in CACHE_DIR/<path inside the package>."""

    def __init__(self, py_func, py_file):
      self._py_file = py_file
      self._lineno = py_func.__code__.co_firstlineno
      inside = os.path.relpath(os.path.dirname(os.path.abspath(py_file)), os.path.dirname(PACKAGE_DIR))
      self._cache_path = os.path.join(CACHE_DIR, inside)

    def get_cache_path(self):
      return self._cache_path

    def get_source_stamp(self):
      return package_source_hash()

    @classmethod
    def from_function(cls, py_func, py_file):
      if not os.path.abspath(py_file).startswith(PACKAGE_DIR + os.sep):
        return None
      return super().from_function(py_func, py_file)  # None if the folder cannot be written

  return SharedCacheLocator


def _install_shared_cache() -> None:
  locator = _shared_cache_locator()
  if os.environ.get("NUMBA_CACHE_DIR") or locator is None:
    return
  from numba.core import caching
  classes = caching.CacheImpl._locator_classes
  if not any(c.__name__ == locator.__name__ for c in classes):
    classes.insert(0, locator)


_install_shared_cache()  # before any kernel is decorated: mwbx/__init__ imports this module first

host_jit = numba.njit(cache=True, nogil=True)


def _borrowed_value(context, builder, typ, value):
  """``value`` of numba type ``typ`` with every array in it (nested tuples
  included) rebuilt without its memory owner."""
  if isinstance(typ, types.Array):
    array = context.make_array(typ)(context, builder, value=value)
    out = context.make_array(typ)(context, builder)
    for field in ("data", "nitems", "itemsize", "shape", "strides"):
      setattr(out, field, getattr(array, field))
    out.meminfo = cgutils.get_null_value(out.meminfo.type)
    out.parent = cgutils.get_null_value(out.parent.type)
    return out._getvalue()
  if isinstance(typ, types.BaseTuple):
    members = [_borrowed_value(context, builder, t, builder.extract_value(value, i)) for i, t in enumerate(typ)]
    return context.make_tuple(builder, typ, members)
  return value


@intrinsic
def borrowed(typingctx, value):
  """``value`` (an array, or a tuple or NamedTuple holding arrays at any
  depth) whose arrays are the same memory without an owner: passing them to a
  call, or binding them to a name, costs no reference counting.

  Numba counts references atomically each time an array is passed or bound,
  and a NamedTuple counts each of its arrays: a compiled loop that hands a
  few NamedTuples to its helpers at every physics step spent about a tenth
  of its time there. Valid only while the caller holds ``value``: take it at
  the top of a kernel from the kernel's own arguments, never store it.
  """
  def codegen(context, builder, signature, args):
    return _borrowed_value(context, builder, signature.args[0], args[0])

  return value(value), codegen


@intrinsic
def held(typingctx, value):
  """Keeps ``value`` alive up to this point of a kernel (numba frees an array
  after its last use): the owner of arrays :func:`borrowed` from it."""
  def codegen(context, builder, signature, args):
    return context.get_dummy_value()

  return types.none(value), codegen
