"""MuJoCo Warp's constraint solver settings for ``mjx:warp``: which solver,
what tolerance, how many iterations.

MuJoCo Warp's Newton solver keeps a dense nv x nv Hessian and its Cholesky
factor per world (``mujoco_warp/_src/solver.py``, ``block_cholesky.py``): for
the trebuchet tower (nv 1185) 5.6 MB each per world and ~5.5e8 flop per
factorization. Its CG solver allocates no Hessian; an iteration costs about
the constraint Jacobian's nonzeros. MJX passes ``opt.tolerance`` to MuJoCo
Warp unchanged (``mjx/_src/io.py``), bypassing Warp's own float32 floor of
1e-6 (``mujoco_warp/_src/io.py``, ``put_model``): with MuJoCo's default 1e-8,
which float32 rarely reaches, the solver runs all its iterations every step.

:func:`warp_solver_settings` chooses (a pure function of the model and the
config's ``sim.mjx``); :func:`solver_model` applies the choice to a copy of
the model before ``mjx.put_model`` (MuJoCo Warp sizes its buffers from the
solver type, so it must be set before, not patched afterwards). A bank's run
record keeps the settings (``run["warp_solver"]``) and refinement replays
them.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import mujoco

from mwbx.errors import MwbxError

# Degrees of freedom above which ``solver: auto`` takes CG. Taken from
# upstream guidance, not measured here (no GPU): MuJoCo Warp benchmarks Newton
# on its articulated models (three humanoids, nv 81: Newton 709 k against CG
# 241 k steps/s on an RTX 6000 Ada, mujoco_warp PR #1331) and CG on its only
# large ones (cloth nv 2706, aloha cloth nv 2716; "they all use Newton, only
# these two use CG", mujoco_warp PR #1417). The crossover lies between; 500 is
# where MuJoCo Warp's own put_model starts treating a model as large (it
# widens the line search's thread block for nv > 500, ``_src/io.py``). Every
# shipped scene but the trebuchet tower (nv 1185) is at or below 120.
NEWTON_MAX_NV = 500

# The smallest tolerance ``auto`` passes on: MuJoCo Warp's own float32 floor
# (``opt.tolerance = max(opt.tolerance, 1e-6)`` in its put_model), which MJX
# skips. A config's explicit ``sim.mjx.tolerance`` is used as given.
FLOAT32_TOLERANCE = 1e-6

SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}


class WarpSolverSettings(NamedTuple):
  """MuJoCo Warp's solver settings of one run.

  Attributes:
    solver: ``newton`` or ``cg``.
    tolerance: the solver's tolerance (dimensionless, MuJoCo's ``opt.tolerance``).
    iterations: the solver's iteration limit per physics step.
    reason: why, in words (the model's nv and the threshold, the clamp,
      the config's overrides).
  """

  solver: str
  tolerance: float
  iterations: int
  reason: str

  def describe(self) -> str:
    """One line for the run summary."""
    return f"{self.solver}, tolerance {self.tolerance:g}, {self.iterations} iterations ({self.reason})"

  @classmethod
  def from_dict(cls, record: dict) -> "WarpSolverSettings":
    """The settings of a bank's run record (``run["warp_solver"]``)."""
    try:
      settings = cls(solver=str(record["solver"]), tolerance=float(record["tolerance"]),
                     iterations=int(record["iterations"]), reason=str(record.get("reason", "recorded")))
    except (KeyError, TypeError, ValueError) as err:
      raise MwbxError(f"run record warp_solver: expected solver, tolerance and iterations, got {record!r}"
                      f" ({err})") from None
    if settings.solver not in SOLVERS or not settings.tolerance > 0 or settings.iterations < 1:
      raise MwbxError(f"run record warp_solver: solver {settings.solver!r}, tolerance {settings.tolerance:g},"
                      f" iterations {settings.iterations}: expected newton or cg, a positive tolerance and"
                      f" at least 1 iteration")
    return settings


def _sleeps(model: mujoco.MjModel) -> bool:
  """Whether the model enables sleeping (MuJoCo Warp sleeps only under Newton)."""
  return bool(model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP))


def warp_solver_settings(model: mujoco.MjModel, mjx_config=None) -> WarpSolverSettings:
  """MuJoCo Warp's solver, tolerance and iterations for ``model``.

  Pure: reads ``model.opt`` and the config, changes neither.

  Args:
    model: the scene's model (its ``nv``, ``opt.tolerance``, ``opt.iterations``
      and sleep flag are read).
    mjx_config: the config's :class:`mwbx.config.MjxSection` (None: its
      defaults: ``solver: auto``, no tolerance or iteration override).

  Returns:
    the :class:`WarpSolverSettings`: ``solver`` CG above :data:`NEWTON_MAX_NV`
    degrees of freedom and Newton at or below it (Newton where the model
    sleeps, which MuJoCo Warp supports only under Newton), unless the config
    names one; ``tolerance`` the config's, else the model's raised to
    :data:`FLOAT32_TOLERANCE`; ``iterations`` the config's, else the model's.

  Raises:
    MwbxError: ``sim.mjx.solver: cg`` for a model that enables sleeping.
  """
  asked = "auto" if mjx_config is None else mjx_config.solver
  reasons = []
  if asked == "auto":
    if model.nv > NEWTON_MAX_NV and not _sleeps(model):
      solver = "cg"
      reasons.append(f"auto: nv {model.nv} > {NEWTON_MAX_NV}, no dense nv x nv Hessian per world")
    else:
      solver = "newton"
      reasons.append(f"auto: nv {model.nv} <= {NEWTON_MAX_NV}" if model.nv <= NEWTON_MAX_NV
                     else f"auto: nv {model.nv}, but the model sleeps (MuJoCo Warp sleeps only under Newton)")
  else:
    if asked == "cg" and _sleeps(model):
      raise MwbxError("sim.mjx.solver: cg: the model enables sleeping, which MuJoCo Warp supports only with"
                      " the Newton solver (use newton or auto)")
    solver = asked
    reasons.append(f"sim.mjx.solver {asked}")

  model_tolerance = float(model.opt.tolerance)
  given_tolerance = None if mjx_config is None else mjx_config.tolerance
  if given_tolerance is not None:
    tolerance = float(given_tolerance)
    reasons.append(f"sim.mjx.tolerance {tolerance:g}")
  elif model_tolerance < FLOAT32_TOLERANCE:
    tolerance = FLOAT32_TOLERANCE
    reasons.append(f"model tolerance {model_tolerance:g} raised to float32's {FLOAT32_TOLERANCE:g}")
  else:
    tolerance = model_tolerance
    reasons.append("model tolerance")

  given_iterations = None if mjx_config is None else mjx_config.iterations
  if given_iterations is not None:
    iterations = int(given_iterations)
    reasons.append(f"sim.mjx.iterations {iterations}")
  else:
    iterations = int(model.opt.iterations)
    reasons.append("model iterations")
  return WarpSolverSettings(solver, tolerance, iterations, "; ".join(reasons))


def as_shipped(model: mujoco.MjModel) -> WarpSolverSettings:
  """The model's own solver, tolerance and iterations, unchanged (what mwbx
  ran before these settings; benchmarks compare against it).

  Raises:
    MwbxError: the model names a solver MuJoCo Warp does not have (PGS).
  """
  names = {int(v): k for k, v in SOLVERS.items()}
  if int(model.opt.solver) not in names:
    raise MwbxError(f"opt.solver: MuJoCo Warp has no {mujoco.mjtSolver(model.opt.solver).name} solver"
                    f" (newton or cg)")
  return WarpSolverSettings(names[int(model.opt.solver)], float(model.opt.tolerance), int(model.opt.iterations),
                            "as shipped: the model's own options")


def solver_model(model: mujoco.MjModel, settings: WarpSolverSettings) -> mujoco.MjModel:
  """A copy of ``model`` with ``settings`` in its ``opt`` (``model`` itself,
  the scene's shared model, is left as it was); put it on the device with
  ``mjx.put_model``."""
  out = copy.copy(model)  # MjModel's copy owns its own arrays and options
  out.opt.solver = SOLVERS[settings.solver]
  out.opt.tolerance = settings.tolerance
  out.opt.iterations = settings.iterations
  return out
