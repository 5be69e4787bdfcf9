"""MuJoCo's C entry points for compiled loops (numba calls them through ctypes).

``mujoco``'s Python functions take the GIL and cost a Python call each; a numba
loop that steps one world from start to finish calls the C library that ships
inside the ``mujoco`` package directly instead, with the model and data
addresses (``MjModel._address``, ``MjData._address``). The library is loaded
into the process (llvmlite) and its functions are declared by name
(``numba.types.ExternalFunction``), so compiled loops resolve them when they
load and can be cached on disk. Pointers are declared as ``intp`` (the same in
the C calling convention), so numba can hand over integers and
``array.ctypes.data``.

``available()`` is False where the library or the clock cannot be bound; the
native backend then steps through ``mujoco.rollout`` instead.
"""

from __future__ import annotations

import pathlib
import time

import llvmlite.binding as llvm
import mujoco
from numba import types

STATE_FULLPHYSICS = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)


def _library() -> str | None:
  """Path of the MuJoCo C library inside the ``mujoco`` package."""
  folder = pathlib.Path(mujoco.__file__).parent
  for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
    for path in sorted(folder.glob(pattern)):
      return str(path)
  return None


def _load(path: str | None) -> bool:
  if path is None:
    return False
  try:
    llvm.load_library_permanently(path)
  except RuntimeError:
    return False
  return True


_intp = types.intp
if _load(_library()):
  mj_step = types.ExternalFunction("mj_step", types.void(_intp, _intp))
  mj_resetData = types.ExternalFunction("mj_resetData", types.void(_intp, _intp))
  mj_getState = types.ExternalFunction("mj_getState", types.void(_intp, _intp, _intp, types.int32))
  mj_setState = types.ExternalFunction("mj_setState", types.void(_intp, _intp, _intp, types.int32))
  # clock_gettime(CLOCK_MONOTONIC, int64[2]) from the C library already in the
  # process: the compiled loop times its physics.
  clock_gettime = types.ExternalFunction("clock_gettime", types.int32(types.int32, _intp))
else:  # pragma: no cover - platforms without the shared library next to the bindings
  mj_step = mj_resetData = mj_getState = mj_setState = clock_gettime = None
CLOCK_MONOTONIC = int(getattr(time, "CLOCK_MONOTONIC", 1))


def available() -> bool:
  """Whether the compiled per-world loop can call MuJoCo's C library here."""
  return mj_step is not None
