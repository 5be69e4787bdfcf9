"""Actuator controls from the config: one table of ``ctrl`` per physics step.

A scene with actuators (position servos holding a pose, motors) gets its
controls from the config's ``controls`` section (:class:`mwbx.config.ControlSchedule`):
fixed values or schedules over time, the same for every world. Every loop
(the native compiled loop, the lockstep rollout, MJX, both refinement loops)
reads row k of the same table before step k, so the backends apply the same
controls bit for bit; the value of step k is the schedule at its start time
``k · timestep``.

Example::

  controls:
    shoulder_l: 1.4                                  # a fixed target, rad
    neck: {times: [0.0, 0.5], values: [0.0, 0.9]}    # ramps to 0.9 rad by 0.5 s
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from mwbx.config import ControlSchedule
from mwbx.errors import MwbxError


def actuator_ids(model: mujoco.MjModel, controls: dict, source: str = "<config>") -> np.ndarray:
  """i64[k] MuJoCo actuator id of each named control (config order).

  Raises:
    MwbxError: naming ``controls.NAME`` for an actuator the MJCF lacks.
  """
  names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(model.nu)]
  ids = []
  for name in controls:
    if name not in names:
      have = ", ".join(n for n in names if n) or "none"
      raise MwbxError(f"{source}: controls.{name}: the MJCF has no actuator {name!r} (actuators: {have})")
    ids.append(names.index(name))
  return np.asarray(ids, np.int64)


def schedule_values(spec: ControlSchedule, times: np.ndarray) -> np.ndarray:
  """f64[n] one control's value at ``times`` (s); a fixed control is a
  schedule of one knot (the config makes it one)."""
  knots, values = np.asarray(spec.times), np.asarray(spec.values)
  if spec.interpolation == "linear":
    return np.interp(times, knots, values)
  index = np.searchsorted(knots, times, side="right") - 1
  return values[np.clip(index, 0, len(values) - 1)]


def control_table(model: mujoco.MjModel, controls: dict, n_steps: int, *, first_step: int = 0,
                  source: str = "<config>") -> np.ndarray:
  """The ``ctrl`` of steps ``first_step … first_step + n_steps - 1``.

  Args:
    model: the scene model (its ``opt.timestep`` spaces the steps).
    controls: the config's ``controls`` (actuator name -> ControlSchedule).
    n_steps: rows wanted.
    first_step: index of the first row's step (refinement starts mid-way).

  Returns:
    f64[n_steps, nu]; f64[n_steps, 0] when ``controls`` is empty (the loops
    then leave ``ctrl`` at MuJoCo's 0 and skip the per-step write).
  """
  if not controls:
    return np.zeros((n_steps, 0))
  ids = actuator_ids(model, controls, source)
  times = (first_step + np.arange(n_steps)) * float(model.opt.timestep)
  table = np.zeros((n_steps, model.nu))
  for column, spec in zip(ids, controls.values()):
    table[:, column] = schedule_values(spec, times)
  return table


def scene_table(scene, n_steps: int, first_step: int = 0) -> np.ndarray:
  """:func:`control_table` of a :class:`mwbx.scene.Scene` (its config and model)."""
  cfg = scene.config
  return control_table(scene.model, dict(cfg.controls), n_steps, first_step=first_step,
                       source=cfg.source or "<config>")


def activation_at(model: mujoco.MjModel, ctrl: np.ndarray, n_steps: int) -> np.ndarray:
  """f64[na] actuator activations after the first ``n_steps`` steps of ``ctrl``.

  Activation dynamics (integrator, filter, filterexact, muscle) depend on the
  controls and the activation alone, not on the pose, so every world of a
  scene has the same ``act`` at a given step; refinement restarts from it.
  MuJoCo integrates it here exactly as while sampling (``mj_step`` with the
  same control rows), the pose held at ``qpos0`` at rest in a copy of the
  model without contacts, constraints or gravity (nothing there can go
  unstable and reset the data).

  Args:
    model: the scene model.
    ctrl: f64[N, nu] the control table (:func:`scene_table`), N >= n_steps.
    n_steps: steps taken.
  """
  data = mujoco.MjData(model)
  if model.na == 0 or n_steps == 0:
    return np.array(data.act, np.float64)
  model = copy.copy(model)  # mj_copyModel
  model.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
                             | mujoco.mjtDisableBit.mjDSBL_GRAVITY)
  for k in range(n_steps):
    data.qpos[:] = model.qpos0
    data.qvel[:] = 0.0
    if model.nu:
      data.ctrl[:] = ctrl[k]
    mujoco.mj_step(model, data)
  return np.array(data.act, np.float64)
