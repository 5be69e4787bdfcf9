"""Contact events inside the MJX scan, at every physics step.

The native loop reads MuJoCo C's contact list after each ``mj_step``
(:func:`mwbx.batch_sim.compiled_world.read_contacts`); this is the same
reading of a batched MJX step's contacts, on either implementation, handed
to the per-world episode tracker (:func:`mwbx.events.steps.track_tick`,
vmapped over the batch):

* a contact *touches* where MuJoCo would not mark it in its margin's gap:
  ``dist < includemargin`` (``includemargin`` is margin − gap; C's
  ``exclude == 1`` is the complement), MuJoCo's contact with no margin added;
* its normal force is the step's ``efc_force`` on its rows: the first
  (elliptic cones, frictionless contacts) or the sum over its pyramid's
  ``2 (dim − 1)`` edges (pyramidal), as ``mj_contactForce`` reads it;
* impl ``jax`` keeps a fixed contact slot per candidate pair in each world
  (its ``contact`` is batched); impl ``warp`` keeps one pool for the batch,
  each contact naming its world (``contact__worldid``), the first ``nacon``
  in use, its rows addressed within its world's ``efc__force``;
* MuJoCo Warp sleeps (under Newton): a pair whose actors all sleep is not
  tested and holds its touch until one wakes, as in the native loop.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx.events import steps as steps_lib
from mwbx.events.actors import Actors, actor_trees

# Rows of a pyramidal contact at most: 2 (condim − 1), condim up to 6.
MAX_PYRAMID_EDGES = 10


class MjxEventInputs(NamedTuple):
  """What the scan needs to find a model's contact events (static).

  Attributes:
    geom_actor: i32[ngeom] each geom's actor. flex_actor: i32[max(nflex, 1)]
      each flex's (-1: none).
    n_actors: actors; a world's pair codes are ``a * n_actors + b``.
    gap: steps apart that end an episode (:mod:`mwbx.events.steps`).
    cap: episode rows per world (:func:`mwbx.events.steps.episode_capacity`).
    pyramidal: the model's friction cones are pyramidal.
    actor_trees: bool[n_actors, ntree] the kinematic trees each actor moves
      with (a static actor: none), for MuJoCo Warp's sleep.
  """

  geom_actor: np.ndarray
  flex_actor: np.ndarray
  n_actors: int
  gap: int
  cap: int
  pyramidal: bool
  actor_trees: np.ndarray


def event_inputs(model: mujoco.MjModel, actors: Actors, gap: int) -> MjxEventInputs:
  """The :class:`MjxEventInputs` of a model and its actors."""
  n = len(actors.names)
  trees = np.zeros((n, max(int(model.ntree), 1)), bool)
  for a, moved_with in enumerate(actor_trees(model, actors)):
    trees[a, moved_with] = True
  flex_actor = np.asarray(actors.flex_actor, np.int32)
  return MjxEventInputs(np.asarray(actors.geom_actor, np.int32),
                        flex_actor if flex_actor.size else np.full(1, -1, np.int32), n,
                        int(gap), steps_lib.episode_capacity(n),
                        int(model.opt.cone) == int(mujoco.mjtCone.mjCONE_PYRAMIDAL), trees)


def _normal_force(efc_force: jax.Array, addresses: jax.Array, dim: jax.Array, pyramidal: bool) -> jax.Array:
  """f32[K] contacts' normal forces from ``efc_force`` (f[nefc]) at
  ``addresses`` (i[K, E]: each of a contact's rows, -1: none)."""
  edges = jnp.where((dim > 1) & pyramidal, 2 * (dim - 1), 1)
  k = jnp.arange(addresses.shape[-1])
  use = (k[None, :] < edges[:, None]) & (addresses >= 0)
  values = efc_force[jnp.clip(addresses, 0, efc_force.shape[-1] - 1)]
  return jnp.where(use, values, 0.0).sum(axis=-1).astype(jnp.float32)


def _jax_world(contact, efc_force, inputs: MjxEventInputs) -> tuple[jax.Array, jax.Array]:
  """One world's (touches, force) per pair from impl jax's contact slots."""
  dim = jnp.broadcast_to(jnp.asarray(contact.dim), contact.dist.shape)
  first = jnp.asarray(contact.efc_address)
  # A contact's rows are consecutive in impl jax: its pyramid's edges follow the first.
  addresses = jnp.where(first[:, None] >= 0, first[:, None] + jnp.arange(MAX_PYRAMID_EDGES)[None, :], -1)
  force = _normal_force(efc_force, addresses, dim, inputs.pyramidal)
  geom_actor = jnp.asarray(inputs.geom_actor)
  geom = jnp.asarray(contact.geom)
  touching = contact.dist < contact.includemargin
  return steps_lib.pair_touches(geom_actor[geom[:, 0]], geom_actor[geom[:, 1]], touching, force, inputs.n_actors)


def _warp_batch(impl, n_worlds: int, inputs: MjxEventInputs) -> tuple[jax.Array, jax.Array]:
  """(bool[W, P], f32[W, P]) from MuJoCo Warp's contact pool."""
  n_pairs = inputs.n_actors * inputs.n_actors
  dist = impl.contact__dist
  in_use = jnp.arange(dist.shape[0]) < jnp.reshape(impl.nacon, (-1,))[0]
  touching = in_use & (dist < impl.contact__includemargin)
  world = jnp.clip(impl.contact__worldid, 0, n_worlds - 1)
  # Each contact's rows are addressed within its world's efc__force [W, njmax]: flattened, offset by world.
  efc = impl.efc__force
  addresses = jnp.asarray(impl.contact__efc_address)
  addresses = jnp.where(addresses >= 0, addresses + world[:, None] * efc.shape[-1], -1)
  force = _normal_force(efc.reshape(-1), addresses, impl.contact__dim, inputs.pyramidal)
  geom, flex = impl.contact__geom, impl.contact__flex
  geom_actor, flex_actor = jnp.asarray(inputs.geom_actor), jnp.asarray(inputs.flex_actor)
  by_geom = jnp.where(geom >= 0, geom_actor[jnp.maximum(geom, 0)], -1)
  side = by_geom if flex.shape != geom.shape else jnp.where(  # (a model without flexes has no flex column)
      geom >= 0, by_geom, flex_actor[jnp.clip(flex, 0, flex_actor.shape[0] - 1)])
  lo, hi = jnp.minimum(side[:, 0], side[:, 1]), jnp.maximum(side[:, 0], side[:, 1])
  real = touching & (lo >= 0) & (lo != hi)
  code = jnp.where(real, world * n_pairs + lo * inputs.n_actors + hi, 0)
  touches = jnp.zeros(n_worlds * n_pairs, jnp.int32).at[code].add(real.astype(jnp.int32)) > 0
  total = jnp.zeros(n_worlds * n_pairs, jnp.float32).at[code].add(jnp.where(real, jnp.maximum(force, 0.0), 0.0))
  return touches.reshape(n_worlds, n_pairs), total.reshape(n_worlds, n_pairs)


def step_touches(d, impl: str, inputs: MjxEventInputs) -> tuple[jax.Array, jax.Array, jax.Array | None]:
  """(bool[W, P] touches, f32[W, P] normal force, bool[W, P] or None: pairs
  whose actors all sleep) of a batched step's contacts (``d``: the data the
  step produced, its contacts those of the state it started from)."""
  n_worlds = d.qpos.shape[0]
  if impl == "warp":
    touches, force = _warp_batch(d._impl, n_worlds, inputs)  # pylint: disable=protected-access
    asleep = d._impl.tree_asleep  # pylint: disable=protected-access
    trees = jnp.asarray(inputs.actor_trees)
    if asleep.shape[-1] != trees.shape[1]:  # no trees (nothing moves): nothing sleeps
      return touches, force, None
    moving = (trees[None, :, :] & (asleep[:, None, :] < 0)).any(axis=-1)  # [W, A]
    still = ~(moving[:, :, None] | moving[:, None, :])
    return touches, force, still.reshape(n_worlds, -1)
  touches, force = jax.vmap(_jax_world, in_axes=(0, 0, None))(d._impl.contact, d._impl.efc_force, inputs)  # pylint: disable=protected-access
  return touches, force, None


def new_tracks(n_worlds: int, inputs: MjxEventInputs) -> steps_lib.EpisodeTrack:
  """A batch's empty episode trackers (each field with a leading W axis)."""
  one = steps_lib.new_track(inputs.n_actors, inputs.cap)
  return jax.tree.map(lambda x: jnp.broadcast_to(x, (n_worlds,) + x.shape), one)


def track_step(tracks: steps_lib.EpisodeTrack, d, impl: str, inputs: MjxEventInputs, ticks: jax.Array,
               running: jax.Array, timestep: float) -> steps_lib.EpisodeTrack:
  """The batch's trackers after one step (``ticks``: i32[W] the step's tick
  in each world; worlds not ``running`` keep theirs)."""
  touches, force, still = step_touches(d, impl, inputs)
  step = lambda t, touch, f, s, tick, live: steps_lib.track_tick(t, touch, f, tick, inputs.n_actors, inputs.gap,
                                                                   timestep, still=s, live=live)
  # (An ended world is masked inside: a select over every world's row buffer each step would copy them all.)
  return jax.vmap(step)(tracks, touches, force, still if still is not None else jnp.zeros_like(touches), ticks,
                        running)


def finish_tracks(tracks: steps_lib.EpisodeTrack, last_ticks: np.ndarray, n_actors: int):
  """(rows i32[W, cap, 4], strength f32[W, cap, 2], count i64[W]) of a
  batch's trackers once its worlds ended at ``last_ticks`` (host arrays;
  :func:`mwbx.events.steps.finish` per world)."""
  host = jax.tree.map(np.array, tracks)
  count = np.zeros(len(last_ticks), np.int64)
  for w, last in enumerate(np.asarray(last_ticks).tolist()):
    count[w] = steps_lib.finish_track(host.first[w], host.seen[w], host.peak[w], host.impulse[w], host.rows[w],
                                      host.strength[w], int(host.count[w]), n_actors, int(last))
  return host.rows, host.strength, count
