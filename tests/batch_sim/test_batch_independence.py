"""A native world is bit-identical whatever batch it is sampled in: its stored
qpos, COM polylines, perturbations and metrics (the README's promise)."""

import jax
import numpy as np
import pytest

import mwbx
from conftest import REPO, TESTS


def test_world_metrics_do_not_depend_on_the_batch():
  # 19 bodies in a pile: a 1-ulp difference in one world's initial state (a
  # vmapped batch rounded the elements of a partial SIMD vector differently)
  # stayed below the codec's and the COM grid's resolution but changed a metric.
  config = mwbx.load_config(TESTS / "scenes" / "crates.yaml")
  key = jax.random.key(0)
  with mwbx.Sampler(config, backend="native", chunk_size=16) as sampler:
    batch, _ = sampler.run(16, key)
    assert batch.perturbations.sum() > 0 and (batch.metric("collisions") > 0).any()
    for w in range(16):
      alone, _ = sampler.run(1, key, ids=[w])
      assert alone.world_ids[0] == w and alone.flags[0] == batch.flags[w]
      np.testing.assert_array_equal(alone.qpos_frames(w), batch.qpos_frames(w))
      np.testing.assert_array_equal(alone.com[0], batch.com[w])
      assert alone.perturbations[0] == batch.perturbations[w]
      np.testing.assert_array_equal(alone.metrics[0], batch.metrics[w], err_msg=f"world {w}")


def _quat_multiply(a, b):
  return np.array([a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                   a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                   a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                   a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])


def _reference_state(scene, unit):
  """qpos f64[nq], qvel f64[nv] of one world from its unit noise, in float64 numpy."""
  qpos = np.array(scene.model.qpos0, np.float64)
  qvel = np.zeros(scene.model.nv)
  inits = {init.name: init for init in scene.object_inits}
  for slot in scene.noise_slots:
    init = inits[slot.object]
    value = (np.broadcast_to(np.asarray(slot.dist.mean, np.float64), (slot.width,))
             + np.broadcast_to(np.asarray(slot.dist.scale, np.float64), (slot.width,))
             * unit[slot.start:slot.start + slot.width])
    a, v = init.free_qpos, init.free_dof
    if slot.field == "position":
      qpos[a:a + 3] += value
    elif slot.field == "rotation":
      angle = np.linalg.norm(value)
      turn = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * value / angle])
      qpos[a + 3:a + 7] = _quat_multiply(turn, qpos[a + 3:a + 7])
    elif slot.field == "linear_velocity":
      qvel[v:v + 3] += value
    elif slot.field == "angular_velocity":
      qvel[v + 3:v + 6] += value
    else:
      qpos[list(init.joint_qpos)] += value
  return qpos, qvel


@pytest.mark.parametrize("config", ["tests/scenes/tiny.yaml", "tests/scenes/chain.yaml", "configs/quickstart.yaml"])
def test_initial_states_alone_and_in_a_batch_match_a_float64_reference(config):
  # XLA inlines a one-trip lax.map and compiled it wrongly here (the tiny
  # scene's ball turned 2e-3 off); per_world runs a batch of one as two.
  from mwbx.batch_sim.sampler import per_world, world_keys
  scene = mwbx.Scene(mwbx.load_config(REPO / config))
  _, init_keys, _ = world_keys(jax.random.key(42), np.arange(5))
  unit = np.asarray(jax.vmap(scene.unit_noise)(init_keys), np.float64)
  init = per_world(scene.initial_state)
  for batch in (init_keys[:1], init_keys):
    qpos, qvel = map(np.asarray, init(batch))
    assert qpos.shape[0] == len(batch)
    for w in range(len(batch)):
      ref_qpos, ref_qvel = _reference_state(scene, unit[w])
      np.testing.assert_allclose(qpos[w], ref_qpos, atol=2e-6, err_msg=f"world {w} of {len(batch)}")
      np.testing.assert_allclose(qvel[w], ref_qvel, atol=2e-6)
  alone = init(init_keys[3:4])
  np.testing.assert_array_equal(np.asarray(alone[0])[0], np.asarray(init(init_keys)[0])[3])
