"""The qpos stores a bank may hold, by kind, and the store a scene's worlds get.

A saved bank names its store's ``kind`` (``raw``: float32 frames,
:class:`~mwbx.qpos_store.RawQposStore`; ``codec``: compressed under error
bounds, :class:`~mwbx.codec.CompressedQposStore`); :func:`store_class` turns
that name back into the class. :func:`store_for` makes the empty store a
scene's worlds are recorded into: the sampler, refinement and a bank moved
to a new scene version (:mod:`mwbx.bank.versions`) all take it from here.
"""

from __future__ import annotations

from mwbx.codec import CompressedQposStore
from mwbx.errors import MwbxError
from mwbx.qpos_store import QposStore, RawQposStore

# The qpos stores a saved bank may name, by their ``kind``.
QPOS_STORES: dict[str, type] = {RawQposStore.kind: RawQposStore,
                                CompressedQposStore.kind: CompressedQposStore}


def store_class(kind: str) -> type:
  """The store class of a saved bank's ``kind``; MwbxError naming an unknown one."""
  if kind not in QPOS_STORES:
    raise MwbxError(f"bank: unknown qpos store {kind!r} (have: {', '.join(QPOS_STORES)})")
  return QPOS_STORES[kind]


def store_for(scene, kind: str = CompressedQposStore.kind) -> QposStore:
  """An empty qpos store of ``kind`` for the worlds of ``scene``.

  Args:
    scene: the :class:`mwbx.Scene` (its model and config).
    kind: ``codec`` (default): compressed under the config's ``codec`` bounds
      (:meth:`mwbx.config.CodecSection.bounds`) at ``sim.record_fps``;
      ``raw``: float32 frames of the model's ``nq`` coordinates.
  """
  store_class(kind)
  if kind == RawQposStore.kind:
    return RawQposStore(scene.model.nq)
  cfg = scene.config
  return CompressedQposStore.from_model(scene.model, cfg.codec.bounds(), cfg.sim.record_fps,
                                        n_bodies=len(scene.body_names))
