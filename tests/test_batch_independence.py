"""A native world is bit-identical whatever batch it is sampled in: its stored
qpos, COM polylines, perturbations and metrics (the README's promise)."""

import jax
import numpy as np

import mwbx
from conftest import TESTS


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
