"""MJX's step (impl ``jax``) with a broadphase by world bounding boxes.

MJX's own collision driver keeps, in each collision-function group of more
than ``max_geom_pairs`` pairs, the pairs closest by bounding-sphere distance.
For long flat geoms that ranking is blind: SIGGRAPH's back and glass walls
span the board (bounding radius about 1 m), so every letter box ranks first
against them, touching or not, and a cap that keeps the pairs really near
each other must hold hundreds (224 on SIGGRAPH), each of which runs the
narrow phase (box-box: most of a step) every step.

Here a group's pairs are ranked by the gap between their geoms' world
axis-aligned boxes, grown by the pair's margin (:func:`box_gap`); a pair whose
grown boxes do not overlap cannot have a contact within its margin, so a cap
that holds every overlapping pair drops nothing, and whether it did is exact:
more overlapping pairs than the cap (``contact_budget.JaxOverflowCheck``).
Everything else is MJX's: the collision functions (but capsule-box:
:mod:`mwbx.batch_sim.mjx_capsule_box`), contact parameters, the
per-condim ``max_contact_points`` cut (the most penetrating contacts), and the
contact array's size and order (``collision_driver.make_condim``, which
``mjx.make_data`` sizes it by), so a budgeted ``mjx.Data`` serves both.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco.mjx._src import collision_driver, constraint, forward as mjx_forward, sensor, smooth
from mujoco.mjx._src import solver
from mujoco.mjx._src.types import GeomType, IntegratorType

from mwbx.batch_sim import mjx_capsule_box, mjx_packed_solve
from mwbx.errors import MwbxError

# A gap this close to zero counts as overlap (float32 rounding), m.
GAP_TOLERANCE = 1e-5

# Collision functions used in place of MJX's for these geom-type pairs (where
# MJX's misses contacts MuJoCo C finds; each module says which and how often).
COLLISION_FUNC = {
    (GeomType.CAPSULE, GeomType.BOX): mjx_capsule_box.capsule_box,
}


def world_boxes(geom_xpos, geom_xmat, geom_aabb):
  """(centre f32[G, 3], half-size f32[G, 3]) of each geom's axis-aligned
  bounding box in the world frame, from its box in its own frame
  (``geom_aabb`` f32[G, 6]: centre, half-size), m. Works on numpy and jax arrays."""
  xp = jnp if isinstance(geom_xpos, jax.Array) else np
  rot = geom_xmat.reshape(-1, 3, 3)
  centre = geom_xpos + xp.einsum("gij,gj->gi", rot, geom_aabb[:, :3])
  half = xp.einsum("gij,gj->gi", xp.abs(rot), geom_aabb[:, 3:])
  return centre, half


def box_gap(g1, g2, centre, half, margin):
  """f32[P] gap between the world boxes of geom pairs (g1, g2 i32[P]), less
  their margin f32[P], m: the largest per-axis separation; <= 0 where the
  grown boxes overlap (only then can the pair have a contact)."""
  xp = jnp if isinstance(centre, jax.Array) else np
  apart = xp.abs(centre[g2] - centre[g1]) - (half[g1] + half[g2])
  return apart.max(axis=-1) - margin


def collision(m, d):
  """``collision_driver.collision`` with groups culled by :func:`box_gap`
  (the ``max_geom_pairs`` numeric: pairs kept per cullable group)."""
  if d._impl.ncon == 0:  # pylint: disable=protected-access
    return d
  max_geom_pairs = collision_driver._numeric(m, "max_geom_pairs")  # pylint: disable=protected-access
  max_contact_points = collision_driver._numeric(m, "max_contact_points")  # pylint: disable=protected-access
  groups = collision_driver._contact_groups(m, d)  # pylint: disable=protected-access
  boxes = None
  for key, contact in groups.items():
    if (max_geom_pairs > -1 and contact.geom.shape[0] > max_geom_pairs
        and not set(key.types) & collision_driver._GEOM_NO_BROADPHASE):  # pylint: disable=protected-access
      if boxes is None:
        boxes = world_boxes(d.geom_xpos, d.geom_xmat, m.geom_aabb)
      gap = box_gap(contact.geom[:, 0], contact.geom[:, 1], *boxes, contact.includemargin)
      _, idx = jax.lax.top_k(-gap, k=max_geom_pairs)
      contact = jax.tree_util.tree_map(lambda x, idx=idx: x[idx], contact)
    func = COLLISION_FUNC.get(key.types) or collision_driver._COLLISION_FUNC[key.types]  # pylint: disable=protected-access
    dist, pos, frame = func(m, d, key, contact.geom)
    if func.ncon > 1:  # one row per contact point the function emits
      contact = jax.tree_util.tree_map(lambda x, r=func.ncon: jnp.repeat(x, r, axis=0), contact)
    groups[key] = contact.replace(dist=dist, pos=pos, frame=frame)

  condim_groups = {}
  for key, contact in groups.items():
    condim_groups.setdefault(key.condim, []).append(contact)
  if max_contact_points > -1:  # the most penetrating contacts of each condim group
    for key, contacts in condim_groups.items():
      contact = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *contacts)
      if contact.geom.shape[0] > max_contact_points:
        _, idx = jax.lax.top_k(-contact.dist, k=max_contact_points)
        contact = jax.tree_util.tree_map(lambda x, idx=idx: x[idx], contact)
      condim_groups[key] = [contact]
  contacts = sum([condim_groups[k] for k in sorted(condim_groups)], [])
  contact = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *contacts)
  return d.tree_replace({"_impl.contact": contact})


def before_solve(m, d):
  """``mjx.forward`` (impl jax) up to its constraint solve, with
  :func:`collision`: the same stages in the same order
  (``forward.fwd_position`` and ``forward.forward``)."""
  d = smooth.kinematics(m, d)
  d = smooth.com_pos(m, d)
  d = smooth.camlight(m, d)
  d = smooth.tendon(m, d)
  d = smooth.crb(m, d)
  d = smooth.tendon_armature(m, d)
  d = smooth.factor_m(m, d)
  d = collision(m, d)
  d = constraint.make_constraint(m, d)
  d = smooth.transmission(m, d)
  d = sensor.sensor_pos(m, d)
  d = mjx_forward.fwd_velocity(m, d)
  d = sensor.sensor_vel(m, d)
  d = mjx_forward.fwd_actuation(m, d)
  return mjx_forward.fwd_acceleration(m, d)


def forward(m, d):
  """``mjx.forward`` (impl jax) with :func:`collision`, for one world."""
  d = before_solve(m, d)
  if d._impl.efc_J.size == 0:  # pylint: disable=protected-access
    return d.replace(qacc=d.qacc_smooth)
  d = solver.solve(m, d)
  return sensor.sensor_acc(m, d)


def _integrator(m):
  # RK4 is left out: MJX's rungekutta4 calls its own forward (and collision) inside.
  integrate = {IntegratorType.EULER: mjx_forward.euler,
               IntegratorType.IMPLICITFAST: mjx_forward.implicit}.get(m.opt.integrator)
  if integrate is None:
    raise MwbxError(f"integrator {IntegratorType(m.opt.integrator).name}: the MJX backend (impl jax) runs"
                    " Euler and implicitfast; use the native backend or mjx_impl: warp")
  return integrate


def step(m, d):
  """``mjx.step`` (impl jax) with :func:`collision`, for one world (the
  reference :func:`batched_step` is held to)."""
  return _integrator(m)(m, forward(m, d))


def batched_step(m, d):
  """:func:`step` of a batch (``d``: ``mjx.Data`` with a world axis), its
  constraint solve over each world's rows in use
  (:func:`mjx_packed_solve.solve_batch`: the same accelerations, float32
  rounding aside, and a world the same bits in any batch); the other stages
  vmapped as they are."""
  integrate = _integrator(m)
  d = jax.vmap(before_solve, in_axes=(None, 0))(m, d)
  if d._impl.efc_J.shape[-2] == 0:  # pylint: disable=protected-access
    d = d.replace(qacc=d.qacc_smooth)
  else:
    d = mjx_packed_solve.solve_batch(m, d)
    d = jax.vmap(sensor.sensor_acc, in_axes=(None, 0))(m, d)
  return jax.vmap(integrate, in_axes=(None, 0))(m, d)
