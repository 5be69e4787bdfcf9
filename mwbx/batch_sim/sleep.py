"""Island sleep in the native engine (MuJoCo 4's ``mjENBL_SLEEP``).

A kinematic tree whose velocities stay below ``opt.sleep_tolerance`` for
``mjMINAWAKE`` steps is ready to sleep; an island sleeps when all its trees
are: its velocities are set to zero and its contacts (inside the island and
with static geometry) are no longer computed. Contact with an awake body, a
``qpos`` change or a nonzero ``xfrc_applied`` wakes it. A sleeping body gets
no perturbation: its contact velocity change is what holds it against
gravity, below every impact threshold, as for a body resting awake. A world
whose every tree sleeps is at rest (:func:`every_tree` of :func:`asleep_count`) and stops.

``sim.sleep: auto`` turns sleep on where it was measured to agree with sleep
off (docs/sampling.md, "Sleep"): scenes of many rigid trees, where most
contacts are resting ones (the tower: 197 trees, 1009 contacts a step awake,
219 with sleep), and where the MJCF enables it itself. Small scenes (a few
bodies, which rarely all rest before the end) gain little and keep the
physics they were tuned with; flexes are left awake (their vertex bodies
were not measured).
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import mujoco
import numpy as np

from mwbx.host_jit import host_jit
from mwbx.joints import QPOS_WIDTH

_SLEEP_BIT = int(mujoco.mjtEnableBit.mjENBL_SLEEP)
# Scenes with at least this many trees that may sleep get sleep under ``auto``.
AUTO_MIN_TREES = 32
_NEVER = (int(mujoco.mjtSleepPolicy.mjSLEEP_NEVER), int(mujoco.mjtSleepPolicy.mjSLEEP_AUTO_NEVER))


class SleepSettings(NamedTuple):
  """Whether and how the native engine lets resting islands sleep.

  Attributes:
    enabled: sleep on.
    tolerance: ``opt.sleep_tolerance`` the model steps with.
    reason: why (``auto``'s rule, or the config's word), for ``mwbx info``.
  """

  enabled: bool
  tolerance: float
  reason: str

  def as_record(self) -> dict:
    """JSON-able, as a bank's ``run`` record keeps it."""
    return {"enabled": bool(self.enabled), "tolerance": float(self.tolerance), "reason": self.reason}

  @classmethod
  def from_record(cls, record: dict) -> "SleepSettings":
    return cls(bool(record["enabled"]), float(record["tolerance"]), str(record.get("reason", "")))

  def describe(self) -> str:
    return f"{'on' if self.enabled else 'off'} (tolerance {self.tolerance:g}; {self.reason})"


def sleepy_trees(model: mujoco.MjModel) -> int:
  """How many of the model's kinematic trees may sleep."""
  return int(np.sum(~np.isin(np.asarray(model.tree_sleep_policy), _NEVER)))


def resolve(model: mujoco.MjModel, sleep: bool | str = "auto", tolerance: float | None = None) -> SleepSettings:
  """The sleep settings of a scene's model under ``sim.sleep`` / ``sim.sleep_tolerance``.

  Args:
    model: the scene model (its MJCF may enable sleep itself).
    sleep: ``auto``, True or False.
    tolerance: velocity tolerance; None keeps the model's.

  Example:
    >>> settings = resolve(scene.model, "auto")
    >>> model = sleeping_copy(scene.model, settings)
  """
  tol = float(model.opt.sleep_tolerance if tolerance is None else tolerance)
  if sleep is True:
    return SleepSettings(True, tol, "sim.sleep: true")
  if sleep is False:
    return SleepSettings(False, tol, "sim.sleep: false")
  if model.opt.enableflags & _SLEEP_BIT:
    return SleepSettings(True, tol, "auto: the MJCF enables it")
  if model.nflex:
    return SleepSettings(False, tol, "auto: off with flexes")
  trees = sleepy_trees(model)
  if trees >= AUTO_MIN_TREES:
    return SleepSettings(True, tol, f"auto: {trees} trees may sleep")
  return SleepSettings(False, tol, f"auto: off below {AUTO_MIN_TREES} trees that may sleep ({trees})")


def starts_asleep(model: mujoco.MjModel) -> np.ndarray:
  """bool[nq]: the qpos columns of the trees whose sleep policy is ``init``
  (asleep from the start where sleep is on)."""
  init = np.asarray(model.tree_sleep_policy) == int(mujoco.mjtSleepPolicy.mjSLEEP_INIT)
  columns = np.zeros(model.nq, bool)
  for j in range(model.njnt):
    tree = int(model.body_treeid[model.jnt_bodyid[j]])
    if tree >= 0 and init[tree]:
      adr = int(model.jnt_qposadr[j])
      columns[adr:adr + QPOS_WIDTH[int(model.jnt_type[j])]] = True
  return columns


def resolve_warp(model: mujoco.MjModel, sleep: bool | str = "auto", tolerance: float | None = None) -> SleepSettings:
  """:func:`resolve` for MuJoCo Warp (mjx:warp), which sleeps under its Newton
  solver only: ``auto`` leaves sleep off there unless the MJCF enables it
  (its cost and gain on a GPU are not measured; where a GPU is visible, the
  engine probe times mjx:warp with sleep as an engine of its own,
  :data:`mwbx.batch_sim.engine_probe.WARP_SLEEP`); ``true``/``false`` as on native."""
  settings = resolve(model, sleep, tolerance)
  if sleep == "auto" and settings.enabled and not model.opt.enableflags & _SLEEP_BIT:
    return SleepSettings(False, settings.tolerance, f"auto: off on mjx:warp (native: {settings.reason})")
  return settings


def sleeping_copy(model: mujoco.MjModel, settings: SleepSettings) -> mujoco.MjModel:
  """A copy of ``model`` with sleep set as ``settings`` say (the flag and the tolerance)."""
  out = copy.copy(model)
  if settings.enabled:
    out.opt.enableflags |= _SLEEP_BIT
  else:
    out.opt.enableflags &= ~_SLEEP_BIT
  out.opt.sleep_tolerance = settings.tolerance
  return out


@host_jit
def asleep_count(tree_asleep) -> int:
  """How many trees of a world sleep (``tree_asleep``: i32[ntree], MjData's; < 0 is awake)."""
  n = 0
  for t in range(tree_asleep.size):
    n += tree_asleep[t] >= 0
  return n


@host_jit
def every_tree(asleep: int, trees: int) -> bool:
  """Whether ``asleep`` of a world's ``trees`` are all of them (False for a model without trees)."""
  return trees > 0 and asleep == trees
