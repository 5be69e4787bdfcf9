"""mjx:warp's solver settings (mwbx.batch_sim.warp_solver): the choice for
small and large models, the float32 tolerance floor, the config's overrides,
the scene's model left as it was, and a few CG worlds of the tiny scene."""

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from conftest import TESTS
from mwbx.batch_sim import warp_solver
from mwbx.config import MjxSection, config_from_dict
from mwbx.errors import MwbxError


def _boxes(n: int, tolerance: float = 1e-8, iterations: int = 100, sleep: bool = False) -> mujoco.MjModel:
  """``n`` free boxes on a plane: nv = 6 n."""
  bodies = "".join(f'<body pos="{i % 10} {i // 10} 0.2"><freejoint/><geom type="box" size=".05 .05 .05"/></body>'
                   for i in range(n))
  model = mujoco.MjModel.from_xml_string(
      f'<mujoco><option tolerance="{tolerance}" iterations="{iterations}"/>'
      f'<worldbody><geom type="plane" size="20 20 .1"/>{bodies}</worldbody></mujoco>')
  if sleep:
    model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
  return model


SMALL = 2  # nv 12
LARGE = warp_solver.NEWTON_MAX_NV // 6 + 1  # just over the threshold


def test_auto_takes_newton_for_a_small_model_and_cg_for_a_large_one():
  small, large = _boxes(SMALL), _boxes(LARGE)
  assert small.nv <= warp_solver.NEWTON_MAX_NV < large.nv
  assert warp_solver.warp_solver_settings(small).solver == "newton"
  chosen = warp_solver.warp_solver_settings(large, MjxSection())
  assert chosen.solver == "cg"
  assert f"nv {large.nv} > {warp_solver.NEWTON_MAX_NV}" in chosen.reason
  # At the threshold itself: Newton.
  at = _boxes(warp_solver.NEWTON_MAX_NV // 6)
  assert at.nv <= warp_solver.NEWTON_MAX_NV and warp_solver.warp_solver_settings(at).solver == "newton"


def test_the_tolerance_is_raised_to_what_float32_reaches_and_iterations_are_the_models():
  chosen = warp_solver.warp_solver_settings(_boxes(SMALL, tolerance=1e-8, iterations=37))
  assert chosen.tolerance == warp_solver.FLOAT32_TOLERANCE == 1e-6
  assert chosen.iterations == 37
  assert "1e-08 raised to float32's 1e-06" in chosen.reason
  # A model tolerance above the floor is kept as it is.
  assert warp_solver.warp_solver_settings(_boxes(SMALL, tolerance=1e-4)).tolerance == 1e-4


def test_the_configs_overrides_win():
  large = _boxes(LARGE)
  chosen = warp_solver.warp_solver_settings(large, MjxSection(solver="newton", tolerance=1e-7, iterations=7))
  assert chosen[:3] == ("newton", 1e-7, 7)  # an explicit tolerance is used as given, below the floor too
  assert all(f"sim.mjx.{field}" in chosen.reason for field in ("solver", "tolerance", "iterations"))
  assert warp_solver.warp_solver_settings(_boxes(SMALL), MjxSection(solver="cg")).solver == "cg"


def test_a_sleeping_model_stays_on_newton_and_refuses_cg():
  sleeping = _boxes(LARGE, sleep=True)
  chosen = warp_solver.warp_solver_settings(sleeping)
  assert chosen.solver == "newton" and "sleeps" in chosen.reason
  with pytest.raises(MwbxError, match=r"^sim\.mjx\.solver: cg: .*sleeping"):
    warp_solver.warp_solver_settings(sleeping, MjxSection(solver="cg"))


def test_the_shared_model_is_not_mutated():
  model = _boxes(LARGE, tolerance=1e-8, iterations=100)
  before = (int(model.opt.solver), float(model.opt.tolerance), int(model.opt.iterations))
  chosen = warp_solver.warp_solver_settings(model, MjxSection(iterations=9))
  copy = warp_solver.solver_model(model, chosen)
  assert (int(model.opt.solver), float(model.opt.tolerance), int(model.opt.iterations)) == before
  assert before[0] == mujoco.mjtSolver.mjSOL_NEWTON
  assert (copy.opt.solver, copy.opt.tolerance, copy.opt.iterations) == (mujoco.mjtSolver.mjSOL_CG, 1e-6, 9)
  copy.opt.timestep = 0.5  # the copy owns its options
  assert model.opt.timestep != 0.5


def test_settings_round_trip_through_a_run_record_and_bad_records_name_the_field():
  chosen = warp_solver.warp_solver_settings(_boxes(LARGE))
  assert warp_solver.WarpSolverSettings.from_dict(chosen._asdict()) == chosen
  with pytest.raises(MwbxError, match=r"^run record warp_solver: .*pgs"):
    warp_solver.WarpSolverSettings.from_dict({**chosen._asdict(), "solver": "pgs"})
  with pytest.raises(MwbxError, match=r"^run record warp_solver: expected"):
    warp_solver.WarpSolverSettings.from_dict({"solver": "cg"})
  shipped = warp_solver.as_shipped(_boxes(SMALL, tolerance=1e-8, iterations=50))
  assert shipped[:3] == ("newton", 1e-8, 50)


@pytest.mark.parametrize("field, value", [("solver", "pgs"), ("tolerance", 0.0), ("tolerance", 2.0),
                                          ("iterations", 0), ("iterations", True)])
def test_config_validation_names_the_field(field, value):
  with pytest.raises(MwbxError, match=rf"^t\.yaml: sim\.mjx\.{field}: "):
    config_from_dict({"scene": {"mjcf": "tiny.xml"}, "sim": {"mjx": {field: value}}}, source="t.yaml")


@pytest.mark.slow
def test_cg_worlds_of_the_tiny_scene_stay_finite_and_unflagged():
  """A few worlds of tests/scenes/tiny.yaml on mjx:warp (MuJoCo Warp's CPU
  device) under the CG settings: finite, none unstable or over the budget, and
  the settings in the bank's run record (what refinement replays). About 45 s
  on 2 cores with Warp's kernel cache cold (its CG kernels compile)."""
  pytest.importorskip("warp")
  config = mwbx.load_config(TESTS / "scenes" / "tiny.yaml")
  sim = config.sim.model_copy(update={"end_time": 0.5, "mjx_impl": "warp",
                                      "mjx": config.sim.mjx.model_copy(update={"solver": "cg"})})
  config = config.model_copy(update={"sim": sim})
  scene = mwbx.Scene(config)
  with mwbx.Sampler(scene, backend="mjx", chunk_size=8) as sampler:
    assert sampler.warp_solver.solver == "cg" and sampler.warp_solver.tolerance == 1e-6
    assert sampler.backend.model.opt.solver == mujoco.mjtSolver.mjSOL_CG
    assert scene.model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON  # the scene's own model: as it was
    bank, _ = sampler.run(8, jax.random.key(0))
  assert bank.valid.all(), bank.summary()
  assert not (bank.flags & mwbx.FLAG_CONTACT_OVERFLOW).any()
  assert np.isfinite(bank.com).all() and np.isfinite(bank.metrics).all()
  assert bank.run["warp_solver"] == sampler.warp_solver._asdict()
  # A sampler given the record (as refinement is) runs with it, whatever the config says.
  replay = warp_solver.WarpSolverSettings.from_dict({**bank.run["warp_solver"], "iterations": 3})
  with mwbx.Sampler(mwbx.Scene(config.model_copy(update={"sim": config.sim.model_copy(
      update={"mjx": MjxSection()})})), backend="mjx", chunk_size=8, contact_budget=bank.run["contact_budget"],
      warp_solver=replay._asdict()) as again:
    assert again.warp_solver == replay and again.backend.model.opt.iterations == 3
