"""Refinement on the MJX backend agrees with the native one on a tiny scene
(three spheres: one falls onto a resting one, the third rests far away)."""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx.refinement import RefineRequest, run_refinement


def refine_run(bank, world, objects=(), *, progress=None, **fields):
  """The refined worlds alone and their stats (through the one entry, :func:`mwbx.run_refinement`)."""
  done = run_refinement(bank, RefineRequest(world, objects, **fields), progress)
  return done.new, done.stats

SCENES = pathlib.Path(__file__).parents[1] / "refine_scenes"


@pytest.fixture(scope="module")
def bank():
  return mwbx.sample(mwbx.load_config(SCENES / "tiny.yaml"), 2, jax.random.key(0), backend="native")


def test_mjx_refinement_runs_and_agrees_on_activation(bank):
  runs = {}
  for backend in ("native", "mjx"):
    new, stats = refine_run(bank, 0, ["striker"], t_min=0.05, n_samples=2, key=jax.random.key(3),
                            backend=backend)
    runs[backend] = (new, stats)
  base = bank.n_worlds
  for backend, (new, stats) in runs.items():
    assert stats.backend.startswith(backend)
    assert np.all(new.valid)
    assert np.all(stats.max_perturbation_ratio <= 1.0 + 1e-5)
    assert np.all(stats.inactive_perturbations == 0)
    for w in range(new.n_worlds):
      lineage = new.lineage[str(base + w)]
      # The striker lands on the target: activated; the far sphere never is.
      assert sorted(lineage["active"]) == ["striker", "target"], backend
      q = new.qpos_frames(new.world_ids[w])
      np.testing.assert_array_equal(q[:, 14:21], bank.qpos_frames(0)[:, 14:21])
  times = [[runs[b][0].lineage[str(base + w)]["activated_at"]["target"] for w in range(2)] for b in runs]
  np.testing.assert_allclose(times[0], times[1], atol=3 / bank.record_fps)


def test_mjx_refinement_uses_the_banks_contact_budget_and_flags_overflow(bank):
  """A bank sampled under a budget is refined under the same one: here one
  too small for the spheres (one contact point), so every refined world is
  flagged and leaves matches."""
  small = dataclasses.replace(bank, run={**bank.run, "contact_budget": {
      "max_contact_points": 1, "max_geom_pairs": 1, "nconmax": 2, "njmax": 8, "source": "test"}})
  new, stats = refine_run(small, 0, ["striker"], t_min=0.05, n_samples=2, key=jax.random.key(3), backend="mjx")
  from mwbx.refinement.refine import sampler_for
  assert sampler_for(small, "mjx").contact_budget.max_contact_points == 1
  assert np.all((new.flags & mwbx.FLAG_CONTACT_OVERFLOW) != 0)
  assert not new.valid.any()


def test_refinement_runs_on_mujoco_warp():
  """A bank whose config asks for MuJoCo Warp is refined on it (on the CPU here):
  the striker still activates the target, and no world is over the budget."""
  pytest.importorskip("warp")
  config = mwbx.load_config(SCENES / "tiny.yaml")
  config = config.model_copy(update={"sim": config.sim.model_copy(update={"mjx_impl": "warp"})})
  bank = mwbx.sample(config, 1, jax.random.key(0), backend="native")
  new, stats = refine_run(bank, 0, ["striker"], t_min=0.05, n_samples=2, key=jax.random.key(3), backend="mjx")
  assert stats.backend == "mjx:warp"
  assert new.valid.all()
  for w in range(new.n_worlds):
    assert sorted(new.lineage[str(bank.n_worlds + w)]["active"]) == ["striker", "target"]
