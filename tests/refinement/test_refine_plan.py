"""A refinement resolved once into a plan, run by its backend's runner, and
the result ``mwbx refine`` reports."""

from __future__ import annotations

import pathlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx.bank.core import Bank
from mwbx.errors import MwbxError
from mwbx.refinement import RefineRequest, plan_refinement, run_refinement, runners, sampler_for
from mwbx.refinement.plan import run_plan


def refine_run(bank, world, objects=(), *, progress=None, **fields):
  """The refined worlds alone and their stats (through the one entry, :func:`mwbx.run_refinement`)."""
  done = run_refinement(bank, RefineRequest(world, objects, **fields), progress)
  return done.new, done.stats

TINY = pathlib.Path(__file__).parents[1] / "scenes" / "tiny.yaml"
ARRAYS = ("world_ids", "keys", "flags", "frame_count", "com", "com_count", "metrics", "perturbations", "steps",
          "parent_world", "refine_time", "scene_version")


@pytest.fixture(scope="module")
def bank():
  return mwbx.sample(mwbx.load_config(TINY), 8, jax.random.key(3), backend="native")


def _same(a, b):
  for name in ARRAYS:
    x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
    assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
  assert a.lineage == b.lineage
  for i in a.world_ids:
    assert a.qpos_frames(int(i)).tobytes() == b.qpos_frames(int(i)).tobytes()


def test_the_plan_holds_the_resolved_refinement(bank):
  plan = plan_refinement(bank, RefineRequest(2, "ball", t_min=0.31, n_samples=3, key=jax.random.key(1),
                                             backend="native", chunk_size=2, remove="cube"))
  assert (plan.world, plan.row, plan.objects, plan.removed, plan.added) == (2, 2, ("ball",), ("cube",), ())
  assert plan.first_frame == int(0.31 * bank.record_fps) and plan.t_min == pytest.approx(0.31)
  assert (plan.n_samples, plan.chunk, plan.first_id, plan.scene_version) == (3, 2, bank.next_world_id, 0)
  assert plan.bounds.e_rot == pytest.approx(np.deg2rad(bank.config["codec"]["e_rot_deg"]))
  new, stats = run_plan(bank, plan, sampler_for(bank, "native"))
  again, _ = refine_run(bank, 2, "ball", t_min=0.31, n_samples=3, key=jax.random.key(1), backend="native",
                        chunk_size=2, remove="cube")
  _same(new, again)
  assert new.world_ids.tolist() == [8, 9, 10] and stats.first_frame == plan.first_frame
  assert all(new.lineage[str(i)]["removed"] == {"cube": plan.first_frame / bank.record_fps} for i in (8, 9, 10))


def test_a_world_id_becomes_a_row_once(bank, monkeypatch):
  """The refinement maps its parent's id to a row once; Bank.absent maps it
  twice more inside the bank (the world's row, its ancestors). It used to be
  six times a call."""
  calls = []
  row_of = Bank.row_of

  def counting(self, ids):
    calls.append(ids)
    return row_of(self, ids)

  monkeypatch.setattr(Bank, "row_of", counting)
  refine_run(bank, 2, "ball", t_min=0.3, n_samples=1, key=jax.random.key(1), backend="native")
  assert len(calls) == 3, calls


def test_each_backend_has_its_runner(bank):
  sampler = sampler_for(bank, "native")
  runner = runners.runner_for(sampler, "frame", compiled=False)
  assert isinstance(runner, runners.NativeRunner) and runner.steps_per_frame == sampler.params.steps_per_frame
  runner.check(sampler.scene.model, ("cube",), ())  # native parks removed objects
  mjx = runners.MjxRunner(None, sampler.params.steps_per_frame, "step", True)
  with pytest.raises(MwbxError, match="MJX backend cannot keep removed objects"):
    mjx.check(sampler.scene.model, ("cube",), ())
  mjx.check(sampler.scene.model, (), ())


def test_refinement_returns_what_the_command_reports(bank):
  request = RefineRequest(2, "ball", t_min=0.3, n_samples=2, key=jax.random.key(4), backend="native")
  done = run_refinement(bank, request)
  assert done.scene_version is None and done.plan.objects == ("ball",)
  assert done.bank.n_worlds == bank.n_worlds + 2 and done.new.n_worlds == 2
  assert done.stats.world_steps == int(done.new.steps.sum()) > 0
  _same(done.bank, mwbx.refine(bank, 2, "ball", t_min=0.3, n_samples=2, key=jax.random.key(4),
                               backend="native"))
  _same(done.bank, mwbx.refine(bank, request))  # the request itself, as refinement takes it


def test_an_object_to_add_that_the_scene_lacks_names_the_scene_argument(bank):
  with pytest.raises(MwbxError, match=r"refine: add: unknown object or group 'ramp'.*scene=, mwbx refine --scene"):
    run_refinement(bank, RefineRequest(2, add="ramp", t_min=0.3, n_samples=1, backend="native"))
