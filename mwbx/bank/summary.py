"""What a bank holds, counted: ``mwbx info``'s figures and the sampling summary."""

from __future__ import annotations

import numpy as np

from mwbx.bank import model as model_lib
from mwbx.bank.flags import FLAG_CONTACT_OVERFLOW
from mwbx.bank.flags import FLAG_SIM_ERROR
from mwbx.bank.flags import FLAG_UNSTABLE


def object_collisions(bank) -> np.ndarray:
  """f64[W] impacts per world: each rigid body's, and for a flex those of
  its most-struck vertex (its vertices land together: counting each would
  give a cloth hundreds)."""
  per_body = np.asarray(bank.metric("collisions"), np.float64)
  rigid = np.ones(per_body.shape[-1], bool)
  total = np.zeros(per_body.shape[:-1])
  for name in model_lib.flex_objects(bank):
    columns = bank.select_bodies(name)
    rigid[columns] = False
    total += per_body[..., columns].max(axis=-1) if len(columns) else 0.0
  return total + per_body[..., rigid].sum(-1)


def summary(bank) -> dict:
  """Counts for ``mwbx info`` and the sampling summary (``storage_bytes``: in memory)."""
  valid = bank.valid
  return {
      "worlds": bank.n_worlds,
      "valid": int(valid.sum()),
      "unstable": int(((bank.flags & (FLAG_UNSTABLE | FLAG_SIM_ERROR)) != 0).sum()),
      "sim_errors": int(((bank.flags & FLAG_SIM_ERROR) != 0).sum()),
      "contact_overflow": int(((bank.flags & FLAG_CONTACT_OVERFLOW) != 0).sum()),
      "at_rest_fraction": float(bank.at_rest.mean()) if bank.n_worlds else 0.0,
      "mean_collisions": float(object_collisions(bank)[valid].mean()) if valid.any() else 0.0,
      "perturbations": int(bank.perturbations.sum()),
      "storage_bytes": int(bank.nbytes),
      "qpos": bank.qpos_store.stats(),
  }
