"""The host's CPU device, where mwbx's host stages run their JAX code.

On a GPU machine JAX's default device is the GPU, and float32 rounds
differently there (sin, cos, erfinv, sums). The stages whose results are
stored or name a world (initial states drawn from a world's key, the codec's
fit) run on the host's CPU instead, so that a world id and a bank's streams
are the same on every machine, whatever accelerator simulated them.
"""

from __future__ import annotations

import jax


def host_cpu() -> jax.Device | None:
  """This process's first CPU device (a local one: under ``jax.distributed``
  ``jax.devices("cpu")[0]`` belongs to process 0); None where JAX has no CPU
  backend (e.g. ``JAX_PLATFORMS=cuda``), which ``jax.default_device(None)``
  reads as JAX's default.

  Example::

    with jax.default_device(host_cpu()):
      qpos0 = jax.jit(f)(keys)  # runs on the CPU
  """
  try:
    return jax.local_devices(backend="cpu")[0]
  except RuntimeError:
    return None
