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

from mwbx import scene as scene_lib
from mwbx.errors import MwbxError

WORLD = "world"  # the unnamed static geoms


class Actors(NamedTuple):
  """Who can touch whom.

  Attributes:
    names: the actors: the objects in the scene's order, then the named
      static geoms in model order, then ``world`` if any static geom is unnamed.
    geom_actor: i32[ngeom] each geom's actor (index into ``names``).
    n_objects: how many of ``names`` are objects (the first ones).
    flex_actor: i32[nflex] each flex's actor (MuJoCo reports a flex's
      contacts by flex, not geom): the object it is (a cloth) or belongs to.
  """

  names: tuple[str, ...]
  geom_actor: np.ndarray
  n_objects: int
  flex_actor: np.ndarray = np.zeros(0, np.int32)

  def of_contacts(self, geoms: np.ndarray, flexes: np.ndarray) -> np.ndarray:
    """i64[K, 2] the actors of contacts: each side's geom's, or its flex's."""
    geoms = np.asarray(geoms, np.int64)
    flexes = np.asarray(flexes, np.int64)
    by_geom = self.geom_actor[np.maximum(geoms, 0)]
    by_flex = self.flex_actor[np.maximum(flexes, 0)] if len(self.flex_actor) else by_geom
    return np.where(geoms >= 0, by_geom, by_flex).astype(np.int64)

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
  flex_actor = np.full(model.nflex, len(names) - 1, np.int32)
  if model.nflex:
    bodies = scene_lib.find_objects(model, "contact events")
    owner = {b: object_index[name] for name, ids in bodies.items() if name in object_index for b in ids}
    for f in range(model.nflex):
      # The bodies that move it: its vertex bodies, or the node bodies of an
      # interpolated (trilinear) flex, whose vertices belong to no body.
      vertices = model.flex_vertbodyid[model.flex_vertadr[f]:model.flex_vertadr[f] + model.flex_vertnum[f]]
      nodes = model.flex_nodebodyid[model.flex_nodeadr[f]:model.flex_nodeadr[f] + model.flex_nodenum[f]]
      found = [owner[int(b)] for b in np.concatenate([vertices, nodes]) if int(b) in owner]
      if found:
        flex_actor[f] = found[0]
  return Actors(names, geom_actor, len(objects), flex_actor)


def actor_trees(model: mujoco.MjModel, actors: Actors) -> list[list[int]]:
  """Per actor, the kinematic trees it moves with, in the order first met: its
  geoms' bodies' trees, and a flex's vertex bodies' trees (a static actor: none).
  An actor moves while one of them is awake (MuJoCo's island sleep)."""
  trees: list[list[int]] = [[] for _ in actors.names]
  for body in range(1, model.nbody):
    tree = int(model.body_treeid[body])
    for g in range(model.body_geomadr[body], model.body_geomadr[body] + model.body_geomnum[body]):
      a = int(actors.geom_actor[g])
      if tree >= 0 and tree not in trees[a]:
        trees[a].append(tree)
  for f in range(model.nflex):
    a = int(actors.flex_actor[f])
    for b in model.flex_vertbodyid[model.flex_vertadr[f]:model.flex_vertadr[f] + model.flex_vertnum[f]]:
      tree = int(model.body_treeid[b])
      if tree >= 0 and tree not in trees[a]:
        trees[a].append(tree)
  return trees


def qpos_actors(model: mujoco.MjModel, actors: Actors) -> np.ndarray | None:
  """i64[nq] the actor each qpos coordinate moves (an object: the tree or
  flex its joint's body belongs to); None where a joint moves no actor."""
  owner = {b: actors.names.index(name) for name, ids in scene_lib.find_objects(model, "contact events").items()
           if name in actors.names[:actors.n_objects] for b in ids}
  out = np.full(model.nq, -1, np.int64)
  widths = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}
  for j in range(model.njnt):
    body = int(model.jnt_bodyid[j])
    actor = owner.get(body, owner.get(int(model.body_rootid[body]), -1))
    adr = int(model.jnt_qposadr[j])
    out[adr:adr + widths.get(int(model.jnt_type[j]), 1)] = actor
  return None if (out < 0).any() else out

