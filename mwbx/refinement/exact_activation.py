"""The objects an exact interaction test activates in a refined world: the
reference the conservative sphere test (:mod:`.interactions`) is measured
against (``scripts/bench_refine.py``, tests).

Replayed from what the bank stores, frame by frame from the world's t_min: an
inactive object becomes active when one of its geoms comes within ``margin``
of a geom of an active object (at the refined world's pose) or of an active
object's ghost (at the parent's pose), as MuJoCo's narrow phase measures it
(``mj_geomDistance``), for geom pairs MuJoCo's contype/conaffinity filter lets
collide; activation spreads until nothing changes. Slow (Python loops over
frames and geom pairs) and only as exact as the stored frames: motion between
two 120 fps frames is not seen.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mwbx import scene as scene_lib

from mwbx.refinement.plan import object_coordinates


def _object_geoms(model: mujoco.MjModel, object_names) -> list[np.ndarray]:
  """i[k] geom ids of each object (geoms of every body under its root)."""
  geom_object = scene_lib.object_body_mask(model, object_names)[:, model.geom_bodyid]
  return [np.flatnonzero(row) for row in geom_object]


def _can_collide(model: mujoco.MjModel, g1: int, g2: int) -> bool:
  return bool((model.geom_contype[g1] & model.geom_conaffinity[g2])
              or (model.geom_contype[g2] & model.geom_conaffinity[g1]))


def _near(model, data, geoms_a: np.ndarray, geoms_b: np.ndarray, margin: float) -> bool:
  """Whether any collidable pair of geoms lies within ``margin`` in ``data``."""
  fromto = np.zeros(6)
  for g1 in geoms_a:
    for g2 in geoms_b:
      if not _can_collide(model, int(g1), int(g2)):
        continue
      # Bounding spheres first: most pairs are far apart.
      gap = (np.linalg.norm(data.geom_xpos[g1] - data.geom_xpos[g2])
             - model.geom_rbound[g1] - model.geom_rbound[g2])
      if gap > margin:
        continue
      if mujoco.mj_geomDistance(model, data, int(g1), int(g2), margin, fromto) <= margin:
        return True
  return False


def exact_active(bank, world: int, margin: float = 0.01) -> tuple[str, ...]:
  """Objects an exact test activates in refined world ``world`` (see the module).

  Args:
    bank: the bank holding the world and its parent.
    world: id of a refined world.
    margin: contact margin, m (refinement's ``margin``).

  Returns:
    the object names, in the scene's object order.
  """
  entry = bank.lineage[str(int(world))]
  parent = int(entry["parent"])
  model = bank.model
  names = tuple(bank.objects)
  geoms = _object_geoms(model, names)
  active = np.array([o in entry["objects"] for o in names])
  child_q = bank.qpos_frames(int(world))
  parent_q = bank.qpos_frames(parent)
  f0 = int(round(float(entry["t_min"]) * bank.record_fps))
  qpos_of, _ = object_coordinates(model, names)  # bool[O, nq]
  # `now`: active objects where the refined world has them, the others on
  # their stored path; `ghost`: every object on its stored path.
  now, ghost = mujoco.MjData(model), mujoco.MjData(model)
  for f in range(f0, len(child_q)):
    stored = parent_q[min(f, len(parent_q) - 1)]
    ghost.qpos[:] = stored
    mujoco.mj_kinematics(model, ghost)
    changed = True
    while changed:
      changed = False
      now.qpos[:] = np.where(qpos_of[active].any(axis=0), child_q[f], stored)
      mujoco.mj_kinematics(model, now)
      for o in np.flatnonzero(~active):
        if any(_near(model, now, geoms[a], geoms[o], margin) or _near(model, ghost, geoms[a], geoms[o], margin)
               for a in np.flatnonzero(active)):
          active[o] = changed = True
  return tuple(n for n, a in zip(names, active) if a)
