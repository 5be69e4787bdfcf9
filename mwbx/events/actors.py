"""The actors of contact events: the objects, then the named static geoms.

An object (a kinematic tree hanging off the world body, named by its root
body) is one actor whatever its bodies and geoms. A geom that belongs to no
object (static scenery: a floor, a bin, a ramp) is an actor if it is named;
unnamed static geoms together are the actor ``world``. Contacts inside one
actor (an arm's links, two walls of the scenery) are not events.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import mujoco
import numpy as np

from mwbx.errors import MwbxError

WORLD = "world"  # the unnamed static geoms


class Actors(NamedTuple):
  """Who can touch whom.

  Attributes:
    names: the actors: the objects in the scene's order, then the named
      static geoms in model order, then ``world`` if any static geom is unnamed.
    geom_actor: i32[ngeom] each geom's actor (index into ``names``).
    n_objects: how many of ``names`` are objects (the first ones).
  """

  names: tuple[str, ...]
  geom_actor: np.ndarray
  n_objects: int

  def index(self, name: str) -> int:
    """The actor named ``name``; MwbxError listing the actors otherwise."""
    try:
      return self.names.index(name)
    except ValueError:
      raise MwbxError(f"unknown actor {name!r} (objects and named static geoms: {', '.join(self.names)})") from None


def actors_of(model: mujoco.MjModel, objects: Sequence[str]) -> Actors:
  """The actors of a scene.

  Args:
    model: the scene's model.
    objects: object (root body) names, in the scene's order.
  """
  object_index = {name: i for i, name in enumerate(objects)}
  geom_actor = np.full(model.ngeom, -1, np.int32)
  static_names: list[str] = []
  unnamed = False
  for g in range(model.ngeom):
    root = int(model.body_rootid[model.geom_bodyid[g]])
    root_name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, root) if root > 0 else None
    if root_name in object_index:
      geom_actor[g] = object_index[root_name]
      continue
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
    if name:
      if name in object_index or name == WORLD:
        raise MwbxError(f"MJCF: static geom {name!r} has the name of an object (or 'world'); rename it")
      static_names.append(name)
      geom_actor[g] = len(objects) + len(static_names) - 1
    else:
      unnamed = True
  names = tuple(objects) + tuple(static_names) + ((WORLD,) if unnamed else ())
  geom_actor[geom_actor < 0] = len(names) - 1  # the unnamed static geoms: `world`
  return Actors(names, geom_actor, len(objects))
