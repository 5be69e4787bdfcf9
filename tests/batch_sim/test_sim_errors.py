"""A world that makes MuJoCo raise an error is flagged; the run goes on.

``scenes/stack_overflow.xml`` gives MuJoCo a 46 KB arena: a world whose slab
lands on the marbles overflows MuJoCo's stack inside ``mj_step``
(``mju_error``); one whose slab lands on the floor does not. The reference
for which worlds err is MuJoCo itself, stepped through its Python bindings
(which turn ``mju_error`` into ``mujoco.FatalError``).
"""

import subprocess
import sys

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.batch_sim import mujoco_c, sampler as sampler_lib
from conftest import REPO, TESTS

SCENE = TESTS / "scenes" / "stack_overflow.yaml"
N_WORLDS = 12

pytestmark = pytest.mark.skipif(not mujoco_c.available(), reason="needs MuJoCo's C library")


def _errs_in_python(scene, qpos, qvel, n_steps) -> bool:
  """Whether MuJoCo raises an error stepping this initial state (the reference)."""
  data = mujoco.MjData(scene.model)
  data.qpos[:], data.qvel[:] = qpos, qvel
  try:
    for _ in range(n_steps):
      mujoco.mj_step(scene.model, data)
  except mujoco.FatalError:
    return True
  return False


def test_erring_worlds_are_flagged_and_the_others_finish():
  config = mwbx.load_config(SCENE)
  key = jax.random.key(0)
  with mwbx.Sampler(config, backend="native", chunk_size=4) as sampler:
    bank, stats = sampler.run(N_WORLDS, key)
    _, init_keys, _ = sampler_lib.world_keys(key, np.arange(N_WORLDS))
    qpos0, qvel0 = jax.vmap(sampler.scene.initial_state)(init_keys)
    n_steps = (sampler.n_frames - 1) * sampler.params.steps_per_frame
    expected = np.array([_errs_in_python(sampler.scene, np.asarray(qpos0[w]), np.asarray(qvel0[w]), n_steps)
                         for w in range(N_WORLDS)])
  flagged = (bank.flags & mwbx.FLAG_SIM_ERROR) != 0
  assert 0 < expected.sum() < N_WORLDS  # the scene really has both kinds of world
  np.testing.assert_array_equal(flagged, expected)
  assert sorted(i for i, _ in stats.sim_errors) == sorted(bank.world_ids[flagged].tolist())
  assert all("mj_stackAlloc" in message for _, message in stats.sim_errors)
  assert not bank.valid[flagged].any()
  # The others ran to rest, and an erring world keeps the frames before the error.
  assert bank.at_rest[~flagged].all()
  assert (bank.frame_count[flagged] > 0).all()
  for w in bank.world_ids[flagged]:
    assert np.isfinite(bank.qpos_frames(int(w))).all()
  # The same worlds, whatever the chunking (errors park threads, fresh ones go on).
  with mwbx.Sampler(config, backend="native", chunk_size=N_WORLDS) as sampler:
    again, _ = sampler.run(N_WORLDS, key)
  np.testing.assert_array_equal(again.flags, bank.flags)
  for w in range(N_WORLDS):
    np.testing.assert_array_equal(again.qpos_frames(w), bank.qpos_frames(w))


def test_cli_names_each_erring_world_and_saves_the_bank(tmp_path):
  out = tmp_path / "bank"
  result = subprocess.run(
      [sys.executable, "-m", "mwbx.cli", "sample", str(SCENE), "--worlds", "8", "--out", str(out)],
      capture_output=True, text=True, cwd=REPO, timeout=600)
  assert result.returncode == 0, result.stderr
  bank = mwbx.Bank.load(out)
  flagged = bank.world_ids[(bank.flags & mwbx.FLAG_SIM_ERROR) != 0].tolist()
  assert flagged
  named = sorted(int(line.split()[2].rstrip(":")) for line in result.stderr.splitlines()
                 if "MuJoCo error" in line)
  assert named == flagged
  assert f"{len(flagged)} of them stopped by MuJoCo errors" in result.stdout


def test_a_refined_world_that_errs_is_flagged(tmp_path):
  """A valid parent (its slab lands on the floor) refined with a second slab
  added above the marbles: the children overflow MuJoCo's arena inside the
  compiled refinement loop, are flagged FLAG_SIM_ERROR and left out of
  queries, and keep the frames before the error."""
  text = (TESTS / "scenes" / "stack_overflow.xml").read_text()
  slab = '<body name="slab" pos="0.3 0 0.4"><freejoint/><geom type="box" size=".15 .15 .05"/></body>'
  (tmp_path / "two_slabs.xml").write_text(text.replace(
      slab, slab + '\n  <body name="slab2" pos="0 0 0.3"><freejoint/><geom type="box" size=".15 .15 .05"/></body>'))
  (tmp_path / "two_slabs.yaml").write_text(SCENE.read_text().replace(
      "mjcf: stack_overflow.xml", f"mjcf: {tmp_path / 'two_slabs.xml'}"))
  bank = mwbx.sample(mwbx.load_config(SCENE), n_worlds=N_WORLDS, key=jax.random.key(0), backend="native")
  parent = int(bank.world_ids[bank.valid][0])
  new = mwbx.refine(bank, parent, scene=tmp_path / "two_slabs.yaml", add="slab2", t_min=0.1, n_samples=2,
                    key=jax.random.key(1), backend="native")
  children = new.row_of(new.children(parent))
  assert (new.flags[children] & mwbx.FLAG_SIM_ERROR).all()
  assert not new.valid[children].any() and new.valid[new.row_of(parent)]
  f0 = int(round(0.1 * new.record_fps))
  for row in children:
    assert new.frame_count[row] > f0  # it ran a while after t_min before the error
    assert np.isfinite(new.qpos_frames(int(new.world_ids[row]))).all()
