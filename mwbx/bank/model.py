"""A bank's scene and MuJoCo model, built from what the bank stores alone.

A bank keeps its config, MJCF text, included files and assets (meshes,
textures, ...); :func:`build_model` compiles them (with mwbx's observation
sensors) and :func:`scene` rebuilds the :class:`mwbx.Scene` that refinement
and solve resample. Nothing is read from the folder the MJCF came from.
:class:`~mwbx.Bank`'s ``model`` (built once and kept), ``scene``,
``qpos_columns`` and flex accessors call these.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from mwbx import scene as scene_lib
from mwbx.config import ASSET_DIR
from mwbx.config import config_from_dict
from mwbx.errors import MwbxError
from mwbx.joints import QPOS_WIDTH


def build_model(bank) -> mujoco.MjModel:
  """The bank's ``MjModel`` at its timestep, from its MJCF text, includes and files.

  Raises:
    MwbxError: the MJCF names a file the bank does not store (or an absolute
      path, or one leaving its folder), naming it, or does not compile.
  """
  try:
    model = scene_lib.build_model(bank.mjcf_text, bank.body_names, includes=bank.mjcf_includes,
                                  assets=bank.mjcf_assets)
  except MwbxError as err:
    raise MwbxError(f"bank: {err}") from None
  except ValueError as err:
    raise MwbxError(f"bank: its MJCF does not compile ({scene_lib.one_line(err)})") from None
  model.opt.timestep = bank.timestep
  return model


def mjcf_dir(config: dict) -> str | None:
  """The folder the MJCF was in when the bank was sampled, as its config
  names it (for people; nothing is read there, nor is it looked up)."""
  source = config.get("source")
  mjcf = (config.get("scene") or {}).get("mjcf")
  if not isinstance(mjcf, str) or not mjcf:
    return None
  base = os.path.dirname(source) if isinstance(source, str) and not source.startswith("<") else str(ASSET_DIR)
  return os.path.normpath(os.path.join(os.path.abspath(base), os.path.dirname(mjcf)))


def scene(bank) -> scene_lib.Scene:
  """The bank's :class:`mwbx.Scene`, from the config, MJCF text and files it stores.

  Raises:
    MwbxError: the stored MJCF names a file the bank does not store, or its
      tracked bodies no longer match its own config.
  """
  data = dict(bank.config)
  data.pop("source", None)
  out = scene_lib.Scene(config_from_dict(data, source="<bank config>"), mjcf_text=bank.mjcf_text,
                        mjcf_includes=bank.mjcf_includes, mjcf_dir=mjcf_dir(bank.config),
                        mjcf_assets=bank.mjcf_assets)
  if out.body_names != tuple(bank.body_names):
    raise MwbxError("bank: the tracked bodies do not match its own config")
  return out


def qpos_columns(model: mujoco.MjModel, body_ids) -> np.ndarray:
  """i64[k] qpos columns of the joints placing the MuJoCo bodies ``body_ids``:
  each body's own joints and its ancestors'."""
  columns = []
  for body in (int(b) for b in body_ids):
    while body > 0:
      for j in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body]):
        width = QPOS_WIDTH[int(model.jnt_type[j])]
        columns.extend(range(model.jnt_qposadr[j], model.jnt_qposadr[j] + width))
      body = int(model.body_parentid[body])
  return np.unique(np.asarray(columns, np.int64))


def flex_objects(bank) -> tuple[str, ...]:
  """The bank's objects that are flexes (cloth, soft solids, ropes), known
  from its compiled model (``nflex``), never from the MJCF's text."""
  flexes = scene_lib.flex_bodies(bank.model)
  return tuple(name for name in bank.objects if name in flexes)


def flex_body_mask(bank) -> np.ndarray:
  """bool[B] the tracked bodies that are a flex's own (vertex or node)
  bodies, which have no orientation; not a body a flex is pinned to."""
  own = [b for ids in scene_lib.flex_bodies(bank.model).values() for b in ids]
  return np.isin(np.asarray(bank.body_ids), own)
