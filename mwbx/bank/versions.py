"""Scene versions: one bank across edits of its scene (paper §5, adding and
removing objects).

A bank starts as version 0 of its scene. Refining with a later version of
the scene (:func:`mwbx.refine` with ``scene=``, ``mwbx refine --scene``)
first moves the bank to it with :func:`upgrade`: the new version keeps every
object of the bank in order and appends its new objects after them, so the
old ``qpos`` is a prefix of the new one, and every world keeps its id, its
stored channels bit for bit (:meth:`CompressedQposStore.relaid`), its COM
polylines and metrics. Worlds of earlier versions hold the new objects
*parked*: free bodies at :data:`PARKED_POSITION`, far from everything, other
joints at the model's ``qpos0``; ``Bank.scene_version`` records each world's
version and ``Bank.versions`` the earlier scenes.

A removed object is parked too, from the refinement's t_min on (its ghost
still activates what it used to touch). :func:`absent` says, per world, which
objects are not in it and when, from the versions and the lineage.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from mwbx import scene as scene_lib

from mwbx.bank.stores import store_for
from mwbx.errors import MwbxError
from mwbx.joints import JNT_FREE
from mwbx.progress import Progress

# m: where a free object waits while it is not in a world (added in a later
# scene version, or removed): far below any scene, so no query box, contact
# or interaction test meets it.
PARKED_POSITION = (0.0, 0.0, -1000.0)
PARKED_RADIUS = 100.0  # m: points this close to it are parked objects (viewer framing)

# Config sections two versions of one bank must share (rates, bounds, metrics).
SHARED_SECTIONS = ("sim", "codec", "rest")


def scene_record(bank) -> dict:
  """The JSON record of ``bank``'s current scene version."""
  return {"digest": bank.digest, "config": bank.config, "mjcf_text": bank.mjcf_text,
          "mjcf_includes": dict(bank.mjcf_includes), "objects": list(bank.objects),
          "body_names": list(bank.body_names)}


def is_parked(points: np.ndarray) -> np.ndarray:
  """bool[...] which points (f[..., 3], m) are parked objects' positions."""
  return np.linalg.norm(np.asarray(points, np.float64) - PARKED_POSITION, axis=-1) < PARKED_RADIUS


def parked_columns(model: mujoco.MjModel, objects) -> np.ndarray:
  """bool[nq] the free-joint coordinates (position and orientation) of ``objects``."""
  out = np.zeros(model.nq, bool)
  ours = scene_lib.object_body_mask(model, objects).any(axis=0)
  for j in range(model.njnt):
    if ours[model.jnt_bodyid[j]] and model.jnt_type[j] == JNT_FREE:
      out[model.jnt_qposadr[j]:model.jnt_qposadr[j] + 7] = True
  return out


def parked_qpos(model: mujoco.MjModel, objects) -> np.ndarray:
  """f64[nq] ``model.qpos0`` with the free joints of ``objects`` at
  :data:`PARKED_POSITION`, identity orientation (other joints stay at qpos0).

  Args:
    model: the scene model.
    objects: names of the objects (root bodies) to park.
  """
  qpos = np.array(model.qpos0, np.float64)
  columns = parked_columns(model, objects)
  for j in range(model.njnt):
    a = int(model.jnt_qposadr[j])
    if model.jnt_type[j] == JNT_FREE and columns[a]:
      qpos[a:a + 7] = (*PARKED_POSITION, 1.0, 0.0, 0.0, 0.0)
  return qpos


def _check_compatible(bank, scene) -> list[str]:
  """The objects ``scene`` adds; MwbxError naming what breaks the prefix rule."""
  src = scene.config.source or "<scene>"
  old_objects, new_objects = list(bank.objects), list(scene.object_names)
  if new_objects[:len(old_objects)] != old_objects:
    missing = [o for o in old_objects if o not in new_objects]
    raise MwbxError(
        f"{src}: a new version of the bank's scene must keep the bank's objects, first and in their order"
        f" ({', '.join(old_objects)})" + (f"; missing: {', '.join(missing)} (remove objects with"
                                          f" remove=/--remove instead)" if missing else
                                          f"; got {', '.join(new_objects)}"))
  for o in old_objects:
    if tuple(scene.objects[o]) != tuple(bank.objects[o]):
      raise MwbxError(f"{src}: object {o!r} tracks other bodies than in the bank "
                      f"({', '.join(scene.objects[o])} vs {', '.join(bank.objects[o])})")
  if tuple(scene.body_names[:len(bank.body_names)]) != tuple(bank.body_names):
    raise MwbxError(f"{src}: the bank's tracked bodies must come first, in their order")
  for section in SHARED_SECTIONS:
    if scene.config.resolved().get(section) != bank.config.get(section):
      raise MwbxError(f"{src}: {section}: must equal the bank's (a scene version changes objects, not "
                      f"rates, bounds or rest rules)")
  old, new = bank.model, scene.model
  for j in range(old.njnt):
    name = mujoco.mj_id2name(old, mujoco.mjtObj.mjOBJ_JOINT, j)
    k = mujoco.mj_name2id(new, mujoco.mjtObj.mjOBJ_JOINT, name) if name else j
    if (k < 0 or new.jnt_type[k] != old.jnt_type[j] or new.jnt_qposadr[k] != old.jnt_qposadr[j]):
      raise MwbxError(f"{src}: joint {name or j!r} of the bank's scene is missing or moved in the new version "
                      f"(new objects' bodies go after the bank's in the MJCF)")
  if abs(new.opt.timestep - bank.timestep) > 1e-12:
    raise MwbxError(f"{src}: option timestep {new.opt.timestep:g} s differs from the bank's {bank.timestep:g} s")
  return new_objects[len(old_objects):]


def upgrade(bank, scene, progress=None):
  """``bank`` moved to a later version of its scene; every world kept.

  Args:
    bank: a :class:`mwbx.Bank`.
    scene: the new version (:class:`mwbx.Scene`): the bank's objects first, in
      order, with the same joints, then the added ones; same ``sim``,
      ``codec`` and ``rest`` sections.
    progress: optional callback taking a :class:`mwbx.progress.Progress`.

  Returns:
    The bank in the new layout (current version ``len(versions)``), worlds
    of earlier versions holding the added objects parked. A bank already of
    this scene is returned as it is.

  Raises:
    MwbxError: naming the object, joint or config section that does not fit.
  """
  if scene.digest == bank.digest:
    return bank
  if scene.digest in {v["digest"] for v in bank.versions}:
    raise MwbxError(f"{scene.config.source or '<scene>'}: is an earlier version of this bank's scene")
  added = _check_compatible(bank, scene)
  model = scene.model
  fill = parked_qpos(model, added).astype(np.float32)
  if progress is not None:
    progress(Progress("re-laying", 0, bank.n_worlds, 0))
  target = store_for(scene, bank.qpos_store.kind)
  store = bank.qpos_store.relaid(target, fill)
  # The added bodies' COM where they are parked, for every point of every old world.
  data = mujoco.MjData(model)
  data.qpos[:] = fill
  mujoco.mj_kinematics(model, data)
  mujoco.mj_comPos(model, data)
  new_bodies = np.asarray(scene.body_ids[len(bank.body_names):])
  parked_com = np.asarray(data.xipos[new_bodies], np.float32)
  com = np.asarray(bank.com)
  w, p = com.shape[:2]
  com = np.concatenate([com, np.broadcast_to(parked_com, (w, p, len(new_bodies), 3))], axis=2)
  metrics = np.concatenate([bank.metrics, np.zeros((w, len(new_bodies), bank.metrics.shape[2]), np.float32)],
                           axis=1)
  if progress is not None:
    progress(Progress("re-laying", bank.n_worlds, bank.n_worlds, 0))
  return dataclasses.replace(
      bank, com=com, metrics=metrics, qpos_store=store, body_names=tuple(scene.body_names),
      body_ids=np.asarray(scene.body_ids), objects=dict(scene.objects), groups=dict(scene.groups),
      config=scene.config.resolved(), mjcf_text=scene.mjcf_text, mjcf_includes=dict(scene.mjcf_includes),
      mjcf_assets=dict(scene.mjcf_assets),
      digest=scene.digest, versions=list(bank.versions) + [scene_record(bank)],
      scene_version=np.asarray(bank.scene_version, np.int16).copy(), _model=None)


def objects_of_version(bank, version: int) -> tuple[str, ...]:
  """Object names of scene version ``version`` of ``bank``."""
  if version == len(bank.versions):
    return tuple(bank.objects)
  return tuple(bank.versions[version]["objects"])


def absent(bank, world: int) -> dict[str, tuple[float, float]]:
  """Objects not in world ``world`` for a while: name -> (from, until) s.

  An object of a later version than the world's is absent throughout; a
  world refined with ``add=`` has the added objects from its t_min on, and
  with ``remove=`` loses the removed ones from its t_min on; both pass down
  to the worlds refined from it (lineage ``added``/``removed``).
  """
  row = bank.row_of(int(world))
  mine = set(objects_of_version(bank, int(bank.scene_version[row])))
  out = {o: (0.0, math.inf) for o in bank.objects if o not in mine}
  chain = [int(world)] + [int(a) for a in bank.ancestors(int(world))]
  for wid in reversed(chain):  # oldest first: a later change overrides an earlier one
    entry = bank.lineage.get(str(wid), {})
    for name, t in entry.get("added", {}).items():
      out[name] = (0.0, float(t))
    for name, t in entry.get("removed", {}).items():
      out[name] = (float(t), math.inf)
  return {k: v for k, v in out.items() if v[1] > v[0]}
