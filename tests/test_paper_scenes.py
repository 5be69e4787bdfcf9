"""The paper's §6 scenes load, sample without unstable worlds and answer their
query files (configs/{siggraph,spiral_staircase,refrigerator_toy}.yaml)."""

import jax
import numpy as np
import pytest

import mwbx
from conftest import REPO

SCENES = ("siggraph", "spiral_staircase", "refrigerator_toy")


@pytest.mark.parametrize("name", SCENES)
def test_scene_samples_stably_and_its_queries_load(name):
  cfg = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  bank = mwbx.sample(cfg, n_worlds=4, key=jax.random.key(0), backend="native")
  assert bank.valid.all(), bank.flags
  queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{name}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  assert each.shape == (4, len(queries.queries))


def test_staircase_servos_raise_the_arms():
  """The figure's shoulder servos follow the config's schedule: the arms are
  raised over the head (target -2.6 rad) once the ramp is over."""
  cfg = mwbx.load_config(REPO / "configs" / "spiral_staircase.yaml")
  scene = mwbx.Scene(cfg)
  bank = mwbx.sample(scene, n_worlds=2, key=jax.random.key(1), backend="native")
  column = scene.model.jnt_qposadr[scene.model.joint("shoulder_flex_l").id]
  for w in bank.world_ids:
    angle = bank.qpos_frames(int(w))[:, column]
    assert abs(angle[0]) < 0.05
    assert np.median(angle[60:]) < -1.5  # after 0.5 s: raised (falls jolt it about)
