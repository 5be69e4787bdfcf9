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

import contextlib
import ctypes
import functools
import pathlib
import threading
import time
from typing import Callable, NamedTuple

import llvmlite.binding as llvm
import mujoco
import numpy as np
import numba
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
  mj_kinematics = types.ExternalFunction("mj_kinematics", types.void(_intp, _intp))
  # clock_gettime(CLOCK_MONOTONIC, int64[2]) from the C library already in the
  # process: the compiled loop times its physics.
  clock_gettime = types.ExternalFunction("clock_gettime", types.int32(types.int32, _intp))
else:  # pragma: no cover - platforms without the shared library next to the bindings
  mj_step = mj_resetData = mj_getState = mj_setState = mj_kinematics = clock_gettime = None
# mj_updateSleep (the sleep arrays from ``tree_asleep``) is exported by the
# library but not declared in its public header: bound only where present.
_HAS_UPDATE_SLEEP = mj_step is not None and hasattr(ctypes.CDLL(_library()), "mj_updateSleep")
# Where it is absent a stand-in keeps compiled loops that name it compiling;
# they call it only when can_put_to_sleep() is True.
mj_updateSleep = types.ExternalFunction("mj_updateSleep" if _HAS_UPDATE_SLEEP else "mj_kinematics",
                                        types.void(_intp, _intp)) if mj_step is not None else None
# tree_asleep of a fully awake tree (-(1 + mjMINAWAKE), engine_sleep.c).
TREE_AWAKE = -(1 + mujoco.mjMINAWAKE)
CLOCK_MONOTONIC = int(getattr(time, "CLOCK_MONOTONIC", 1))


def available() -> bool:
  """Whether the compiled per-world loop can call MuJoCo's C library here."""
  return mj_step is not None


def can_put_to_sleep() -> bool:
  """Whether compiled loops can put chosen trees to sleep (``mj_updateSleep`` bound)."""
  return _HAS_UPDATE_SLEEP


class MjDataViews(NamedTuple):
  """One thread's ``MjData`` as the compiled loops see it (:func:`data_views`).

  Attributes:
    model_adr: ``MjModel._address`` of the model the data steps with.
    data_adr: ``MjData._address``.
    qpos: f64[nq] view of ``qpos`` (m, rad; free-joint quaternions w, x, y, z).
    qvel: f64[nv] view of ``qvel`` (m/s, rad/s).
    xfrc_applied: f64[nbody, 6] view of ``xfrc_applied``: force N, torque N·m
      (world frame, at each body's COM).
    sensordata: f64[nsensordata] view of ``sensordata`` (the sensors' units).
    ctrl: f64[nu] view of ``ctrl`` (the actuators' units).
    tree_asleep: i32[ntree] view of ``tree_asleep`` (< 0: awake; MuJoCo 4's sleep).
    header_i32, header_i64: the ``mjData`` struct itself up to its
      ``contact`` and ``efc_force`` pointers, as int32 and int64 words
      (:class:`ContactLayout`; empty where it could not be found).
    arena_i32, arena_f64: the data's arena (where ``mj_collision`` puts the
      step's contacts) as int32 and float64 words.
  """

  model_adr: int
  data_adr: int
  qpos: np.ndarray
  qvel: np.ndarray
  xfrc_applied: np.ndarray
  sensordata: np.ndarray
  ctrl: np.ndarray
  tree_asleep: np.ndarray
  header_i32: np.ndarray = np.zeros(0, np.int32)
  header_i64: np.ndarray = np.zeros(0, np.int64)
  arena_i32: np.ndarray = np.zeros(0, np.int32)
  arena_f64: np.ndarray = np.zeros(0, np.float64)


def data_views(model: mujoco.MjModel, data: mujoco.MjData) -> MjDataViews:
  """``data`` (made for ``model``, or a model of the same sizes) for the compiled loops."""
  views = MjDataViews(model._address, data._address, data.qpos, data.qvel, data.xfrc_applied,
                      data.sensordata, data.ctrl, data.tree_asleep)
  layout = contact_layout()
  if layout is None:
    return views
  header = _words(data._address, 8 * (max(layout.contact, layout.efc_force) + 1))
  arena = _words(int(header.view(np.int64)[layout.arena]), int(data.narena) // 8 * 8)
  return views._replace(header_i32=header.view(np.int32), header_i64=header.view(np.int64),
                        arena_i32=arena.view(np.int32), arena_f64=arena.view(np.float64))


# -- the step's contacts, read in compiled loops --------------------------------------


class ContactLayout(NamedTuple):
  """Where a compiled loop finds the contacts of the step just taken.

  The bindings show ``mjData.contact`` to Python only; a compiled loop reads
  the struct: ``ncon`` and the ``contact`` pointer from the ``mjData`` words,
  the contacts from the arena they point into. The offsets are found once per
  process from the bindings themselves (:func:`contact_layout`), never from
  a header of another version.

  Attributes:
    ncon: int32 word of ``mjData.ncon``.
    arena, contact: int64 words of the ``mjData.arena`` and ``mjData.contact`` pointers.
    stride: bytes of one ``mjContact``.
    geom, flex, exclude, efc_address, dim: byte offsets of those
      ``mjContact`` fields (``geom``, ``flex``: int[2]).
    efc_force: int64 word of the ``mjData.efc_force`` pointer (into the arena).
  """

  ncon: int
  arena: int
  contact: int
  stride: int
  geom: int
  flex: int
  exclude: int
  efc_address: int
  dim: int
  efc_force: int


def _words(address: int, n_bytes: int) -> np.ndarray:
  """u8[n_bytes] view of memory at ``address`` (kept alive by its owner)."""
  if n_bytes <= 0:
    return np.zeros(0, np.uint8)
  return np.ctypeslib.as_array((ctypes.c_uint8 * n_bytes).from_address(address))


_PROBE = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
  <body name="box" pos="0 0 .09"><freejoint/><geom type="box" size=".1 .1 .1"/></body>
  <body name="ball" pos="1 0 .09"><freejoint/><geom type="sphere" size=".1"/></body>
</worldbody></mujoco>"""
_PROBE_HEIGHTS = ((0.09, 0.09), (0.09, 1.0), (1.0, 0.09))  # box, ball: 5, 4 and 1 contacts
_MAX_HEADER_BYTES = 1 << 22  # mjData's fixed part is far smaller (200 KB in MuJoCo 4)


@functools.cache
def contact_layout() -> ContactLayout | None:
  """The :class:`ContactLayout` of this MuJoCo, found on a probe scene whose
  contact count changes (5, 4, 1) and checked on a second ``MjData``; None
  where it cannot be found unambiguously (compiled loops then see no
  contacts, and events come from the stored frames)."""
  try:
    model = mujoco.MjModel.from_xml_string(_PROBE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    n_bytes = _bytes_until(data, data.efc_force.ctypes.data)  # efc_force's pointer comes after contact's
    if n_bytes is None:
      return None
    header = _words(data._address, n_bytes)
    same, counts = np.ones(n_bytes // 4, bool), []
    for box, ball in _PROBE_HEIGHTS:  # no reset between them: the most contacts so far stays 5
      data.qpos[2], data.qpos[9] = box, ball
      mujoco.mj_forward(model, data)
      counts.append(data.ncon)
      same &= header.view(np.int32) == data.ncon
    ncon, pointers = np.flatnonzero(same), np.flatnonzero(header.view(np.int64) == data.contact.dist.ctypes.data)
    if len(set(counts)) < len(counts) or len(ncon) != 1 or len(pointers) != 2:
      return None
    contact = data.contact
    offset = lambda field: int(getattr(contact, field).ctypes.data - contact.dist.ctypes.data)
    layout = ContactLayout(ncon=int(ncon[0]), arena=int(pointers[0]), contact=int(pointers[1]),
                           stride=int(contact.dist.strides[0]), geom=offset("geom"), flex=offset("flex"),
                           exclude=offset("exclude"), efc_address=offset("efc_address"), dim=offset("dim"),
                           efc_force=n_bytes // 8 - 1)
    other = mujoco.MjData(model)  # the same words mean the same on another data
    mujoco.mj_forward(model, other)
    words = _words(other._address, 8 * (layout.efc_force + 1)).view(np.int64)
    inside = 0 <= words[layout.efc_force] - words[layout.arena] < other.narena  # efc_force is in the arena
    if (words.view(np.int32)[layout.ncon] != other.ncon or words[layout.contact] != other.contact.dist.ctypes.data
        or words[layout.efc_force] != other.efc_force.ctypes.data or not inside):
      return None
    return layout
  except (ValueError, TypeError, AttributeError, mujoco.FatalError):
    return None


def _bytes_until(data: mujoco.MjData, pointer: int) -> int | None:
  """Bytes of ``data``'s struct up to and with the word holding ``pointer``
  (None if not met within :data:`_MAX_HEADER_BYTES`): read word by word, never past it."""
  for i in range(_MAX_HEADER_BYTES // 8):
    if ctypes.c_uint64.from_address(data._address + 8 * i).value == pointer:
      return 8 * (i + 1)
  return None


# -- MuJoCo errors inside compiled loops ---------------------------------------------

_ERROR_FN = ctypes.CFUNCTYPE(None, ctypes.c_char_p)
_trap_lock = threading.Lock()
_callbacks: list = []  # callbacks a parked thread is still inside: never freed


def _global_slot(name: str):
  """MuJoCo's global callback pointer ``name`` (``mju_user_error``,
  ``mjcb_time``) as a ctypes pointer slot; None where it cannot be reached."""
  path = _library()
  if path is None:
    return None
  try:
    return ctypes.c_void_p.in_dll(ctypes.CDLL(path), name)
  except (OSError, ValueError):
    return None


@contextlib.contextmanager
def trap_errors(on_error: Callable[[str], None]):
  """While inside: an ``mju_error`` on a thread without a handler of its own
  calls ``on_error(message)`` on that thread, which then never returns.

  MuJoCo's bindings give every Python-level call a thread-local handler that
  raises ``mujoco.FatalError``; a compiled loop calling ``mj_step`` directly has
  none, and MuJoCo's fallback prints and exits the process. MuJoCo cannot go on
  after an error, and numba frames cannot be unwound, so the erring thread is
  parked for good instead (a daemon thread blocked on an event, holding only
  its own ``MjData``): the caller flags that world and carries on with fresh
  threads. Restores the previous handler on exit.

  Yields:
    True if the handler is installed (False where the library's global cannot
    be reached: an error then ends the process as before).
  """
  slot = _global_slot("mju_user_error")
  if slot is None:
    yield False
    return

  fired = []

  def handler(message):
    fired.append(True)
    try:
      on_error((message or b"").decode(errors="replace").strip())
    finally:
      threading.Event().wait()  # never return into MuJoCo

  callback = _ERROR_FN(handler)
  _callbacks.append(callback)
  with _trap_lock:
    previous = slot.value
    slot.value = ctypes.cast(callback, ctypes.c_void_p).value
    try:
      yield True
    finally:
      slot.value = previous
      if not fired:  # no thread is inside it: let it (and what on_error holds) go
        _callbacks.remove(callback)


# -- MuJoCo's profiling timers, not read while compiled loops step ------------------


@numba.cfunc(types.float64(), cache=True)
def _zero_clock():
  return 0.0


_timers_lock = threading.Lock()
_timers = {"users": 0, "saved": None}  # callers inside engine_timers_off; the callback they replaced


@contextlib.contextmanager
def engine_timers_off():
  """While inside: MuJoCo's per-stage profiling timers (``MjData.timer``) read
  a clock that returns 0 instead of the system's.

  MuJoCo 4's default timer reads the monotonic clock about 30 times a step to
  fill ``MjData.timer``, which nothing in mwbx reads: 8 % of a quickstart
  step (``scripts/bench_sampler.py``). A timer callback set through
  ``mujoco.set_mjcb_time`` (a profiler) is left as it is. The slot is global,
  so overlapping callers count themselves in and the last one out restores it.
  """
  slot = _global_slot("mjcb_time")
  if slot is None:
    yield
    return
  with _timers_lock:
    if _timers["users"] == 0:
      _timers["saved"] = slot.value
      if mujoco.get_mjcb_time() is None:
        slot.value = _zero_clock.address
    _timers["users"] += 1
  try:
    yield
  finally:
    with _timers_lock:
      _timers["users"] -= 1
      if _timers["users"] == 0:
        slot.value = _timers["saved"]
