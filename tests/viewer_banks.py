"""Real sampled banks shared by the viewer test modules (sampled once per
test process: sampling compiles and runs the sampler)."""

from __future__ import annotations

import functools
import pathlib

QUICKSTART = pathlib.Path(__file__).parents[1] / "configs" / "quickstart.yaml"


@functools.cache
def quickstart_bank(n_worlds: int = 4, seed: int = 0):
  """A quickstart bank of `n_worlds` worlds (treat as read-only)."""
  import jax

  import mwbx

  return mwbx.sample(mwbx.load_config(QUICKSTART), n_worlds=n_worlds, key=jax.random.key(seed))
