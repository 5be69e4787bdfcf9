"""Perturbations of a whole batch, computed only where impacts happened.

Impacts are rare (a few percent of body-steps), and drawing random numbers and
lobe directions for every body at every step dominated the sampler's own cost
on CPUs. So the batch's impacting body-steps are gathered into fixed-size
buffers of ``cap`` entries (enough rounds of them to cover all impacts), their
perturbations computed there, and scattered back.

The randomness of body ``b`` at step ``k`` of world ``w`` is
``fold_in(fold_in(world_key[w], k), b)``, and each entry's arithmetic does not
depend on where in the buffer it lands, so a world's perturbations do not
depend on the batch it runs in.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mwbx.perturb.impulses import PerturbParams, impulse_wrench, perturbation_from_uniforms


def body_step_uniforms(world_key: jax.Array, step: jax.Array, body: jax.Array) -> jax.Array:
  """f32[6] uniforms of one body at one step of one world."""
  key = jax.random.fold_in(jax.random.fold_in(world_key, step), body)
  return jax.random.uniform(key, (6,), jnp.float32)


def batch_perturbations(
    world_keys: jax.Array,
    first_step: jax.Array,
    delta_v: jax.Array,
    delta_w: jax.Array,
    linear_impact: jax.Array,
    angular_impact: jax.Array,
    params: PerturbParams,
    cap: int,
    *,
    inertial=None,
):
  """Perturbations of every body at every step of a frame, for a batch.

  Args:
    world_keys: key[W] per-world step key roots.
    first_step: i32[W] step index k of the frame's first step per world.
    delta_v: f32[W, S, B, 3] contact-induced velocity changes, m/s.
    delta_w: f32[W, S, B, 3] angular velocity changes, rad/s.
    linear_impact: bool[W, S, B] where a linear perturbation is wanted.
    angular_impact: bool[W, S, B] where an angular perturbation is wanted.
    params: α and lobe exponent.
    cap: entries per round (static); rounds repeat until all are done.
    inertial: optional ``(mass f32[B], inertia f32[B, 3], quat f32[W, S, B, 4],
      dt)``: also return the wrench that applies each perturbation in one
      step (:func:`impulse_wrench`), computed only at the impacts too.

  Returns:
    (dv f32[W, S, B, 3], dw f32[W, S, B, 3]), zero where no impact; with
    ``inertial``, also wrench f32[W, S, B, 6].
  """
  n_worlds, n_steps, n_bodies = linear_impact.shape
  total = n_worlds * n_steps * n_bodies
  cap = max(1, min(cap, total))
  want = (linear_impact | angular_impact).reshape(-1)
  count = jnp.sum(want.astype(jnp.int32))
  order = jnp.nonzero(want, size=total, fill_value=total)[0]
  flat_dv = delta_v.reshape(-1, 3)
  flat_dw = delta_w.reshape(-1, 3)
  flat_lin = linear_impact.reshape(-1)
  flat_ang = angular_impact.reshape(-1)

  if inertial is not None:
    mass, inertia, quat, dt = inertial
    flat_quat = quat.reshape(-1, 4)

  def entry(index):
    world = index // (n_steps * n_bodies)
    step = first_step[world] + (index // n_bodies) % n_steps
    body = index % n_bodies
    u = body_step_uniforms(world_keys[world], step, body)
    dv = perturbation_from_uniforms(u[0:3], flat_dv[index], params.alpha, params.lobe_exponent)
    dw = perturbation_from_uniforms(u[3:6], flat_dw[index], params.alpha, params.lobe_exponent)
    dv, dw = jnp.where(flat_lin[index], dv, 0.0), jnp.where(flat_ang[index], dw, 0.0)
    if inertial is None:
      return dv, dw, jnp.zeros(6, jnp.float32)
    return dv, dw, impulse_wrench(dv, dw, mass[body], inertia[body], flat_quat[index], dt)

  def one_round(r, out):
    index = jax.lax.dynamic_slice(order, (r * cap,), (cap,))
    values = jax.vmap(entry)(jnp.minimum(index, total - 1))
    # Fill entries (index == total) are dropped by the scatter.
    return tuple(o.at[index].set(v, mode="drop") for o, v in zip(out, values))

  zeros = (jnp.zeros((total, 3), jnp.float32), jnp.zeros((total, 3), jnp.float32),
           jnp.zeros((total, 6), jnp.float32))
  order = jnp.concatenate([order, jnp.full(cap, total, order.dtype)])  # room for the last round
  rounds = (count + cap - 1) // cap
  dv, dw, wrench = jax.lax.fori_loop(0, rounds, one_round, zeros)
  shape = (n_worlds, n_steps, n_bodies)
  if inertial is None:
    return dv.reshape(shape + (3,)), dw.reshape(shape + (3,))
  return dv.reshape(shape + (3,)), dw.reshape(shape + (3,)), wrench.reshape(shape + (6,))
