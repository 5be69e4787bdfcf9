"""Reading banks saved as one orbax checkpoint (formats 1 and 2, before shards).

Format 1 named lineage and parents by bank row; format 2 by world id and
added per-array checksums. Both are read into a :class:`~mwbx.bank.Bank`;
saving it writes the shard format (:mod:`mwbx.bank.shards`) next to the old
checkpoints, which stay where they are.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from mwbx.bank import checks
from mwbx.bank.stores import store_class
from mwbx.errors import MwbxError

FORMATS = (1, 2)


class _manager:
  """An orbax CheckpointManager over a bank directory, closed on exit."""

  def __init__(self, path: pathlib.Path):
    import orbax.checkpoint as ocp
    self.manager = ocp.CheckpointManager(
        path / "checkpoints",
        options=ocp.CheckpointManagerOptions(max_to_keep=1, enable_async_checkpointing=False),
        item_handlers={"bank": ocp.StandardCheckpointHandler(), "meta": ocp.JsonCheckpointHandler()},
    )

  def __enter__(self):
    return self.manager

  def __exit__(self, *exc):
    self.manager.close()


def load(cls, path: pathlib.Path):
  """The bank of the latest orbax checkpoint under ``path/checkpoints``."""
  import orbax.checkpoint as ocp
  try:
    with _manager(path) as manager:
      step = manager.latest_step()
      if step is None:
        raise MwbxError(f"{path}: no bank here (no checkpoint)")
      restored = manager.restore(step, args=ocp.args.Composite(
          bank=ocp.args.StandardRestore(), meta=ocp.args.JsonRestore()))
    tree, meta = restored["bank"], restored["meta"]
    checks.verify(path, tree, meta.get("checksums"))
    if meta.get("format") not in FORMATS:
      raise MwbxError(f"{path}: unsupported bank format {meta.get('format')!r}")
    store_meta = meta["qpos_store"]
    store = store_class(store_meta["kind"]).restore(
        {k[len("qpos_"):]: np.asarray(v) for k, v in tree.items() if k.startswith("qpos_")}, store_meta)
    bank = cls(
        **{name: np.asarray(tree[name]) for name in cls.ROW_ARRAYS if name in tree},
        qpos_store=store, body_names=tuple(meta["body_names"]), body_ids=np.asarray(tree["body_ids"]),
        objects={k: tuple(v) for k, v in meta["objects"].items()},
        groups={k: tuple(v) for k, v in meta["groups"].items()},
        metric_names=tuple(meta["metric_names"]), record_fps=meta["record_fps"],
        query_fps=meta["query_fps"], timestep=meta["timestep"], config=meta["config"],
        mjcf_text=meta["mjcf_text"], mjcf_includes=meta.get("mjcf_includes", {}),
        mjcf_assets={},  # this format stored no files: a model naming one is refused
        digest=meta["digest"], lineage=meta.get("lineage", {}), run=meta.get("run", {}),
        next_id=int(meta.get("next_id", 0)))
  except MwbxError:
    raise
  except Exception as err:  # orbax/tensorstore/json errors: a corrupt or foreign directory.
    raise MwbxError(f"{path}: corrupt or unreadable bank ({type(err).__name__}: "
                    f"{checks.first_line(err)})") from None
  return _from_rows_to_ids(bank) if meta.get("format") == 1 else bank


def _from_rows_to_ids(bank):
  """A format-1 bank (lineage and parents named by bank row) with world ids."""
  ids = bank.world_ids
  parents = np.where(bank.parent_world >= 0, ids[np.clip(bank.parent_world, 0, None)], -1)
  lineage = {}
  for row, entry in bank.lineage.items():
    entry = dict(entry)
    if "parent" in entry:
      entry["parent"] = int(ids[int(entry["parent"])])
    lineage[str(int(ids[int(row)]))] = entry
  return dataclasses.replace(bank, parent_world=parents.astype(np.int64), lineage=lineage)
