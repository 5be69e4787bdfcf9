"""Guided proposals: learn where in the configured randomization the worlds a
set of queries wants come from.

A world's initial state is a function of its unit noise ``u: f32[D]``
(:attr:`mwbx.Scene.noise_slots`): each randomized quantity is
``mean + scale * u`` with ``u`` uniform in [-1, 1] or standard normal, as the
config says. A :class:`Proposal` is a diagonal Gaussian over a latent
``z: f32[D]`` mapped onto ``u`` by :func:`unit_from_latent`:

* uniform slots: ``u = 2 Φ(z) - 1`` (Φ the standard normal CDF), so ``u``
  always lies in [-1, 1]: every proposed world stays inside the configured
  range and is as plausible as a plainly sampled one;
* normal slots: ``u = clip(z, -3, 3)``: within three configured standard
  deviations.

At ``mean = 0, log_scale = 0`` the proposal *is* the configured distribution
(up to the normal slots' clip at 3σ). Learning moves it toward worlds with
smaller query gaps (:func:`mwbx.queries.query_gaps`) by a score-function
(evolution-strategies) gradient with rank-shaped fitness, stepped by an optax
optimiser (:func:`es_step`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

NORMAL_CLIP = 3.0  # normal slots stay within this many configured standard deviations
MIN_LOG_SCALE = float(np.log(0.02))  # the narrowest proposal, in latent standard deviations
MAX_MEAN = 3.0  # |mean| of the latent: Φ(3) leaves 0.13 % of a uniform range's end


class Proposal(NamedTuple):
  """A diagonal Gaussian over the latent of a world's unit noise.

  Attributes:
    mean: f32[D] latent means.
    log_scale: f32[D] log latent standard deviations (at most 0).
  """

  mean: jax.Array
  log_scale: jax.Array


def init_proposal(width: int) -> Proposal:
  """The proposal equal to the configured distribution, for ``D = width``."""
  return Proposal(jnp.zeros(width, jnp.float32), jnp.zeros(width, jnp.float32))


def uniform_slots(scene) -> np.ndarray:
  """bool[D] components drawn uniformly (the rest are normal), per ``scene.noise_slots``."""
  out = []
  for slot in scene.noise_slots:
    out.extend([slot.dist.dist == "uniform"] * slot.width)
  return np.asarray(out, bool)


def learnt_slots(scene, objects) -> np.ndarray:
  """bool[D] components worth learning: those of ``objects`` with a nonzero
  configured scale (the others keep the configured distribution)."""
  out = []
  for slot in scene.noise_slots:
    scale = np.broadcast_to(np.asarray(slot.dist.scale, np.float64), (slot.width,))
    out.extend((scale != 0) & (slot.object in objects))
  return np.asarray(out, bool)


def unit_from_latent(z: jax.Array, uniform: jax.Array) -> jax.Array:
  """Unit noise from the latent: f32[..., D] (see the module docstring).

  Args:
    z: f32[..., D] latent draws.
    uniform: bool[D] which components are uniform slots.
  """
  as_uniform = 2.0 * jax.scipy.stats.norm.cdf(z) - 1.0
  return jnp.where(uniform, as_uniform, jnp.clip(z, -NORMAL_CLIP, NORMAL_CLIP)).astype(jnp.float32)


def draw(proposal: Proposal, key: jax.Array, n: int) -> tuple[jax.Array, jax.Array]:
  """``n`` latent draws: (eps f32[n, D] standard normal, z f32[n, D])."""
  eps = jax.random.normal(key, (n,) + proposal.mean.shape, jnp.float32)
  return eps, proposal.mean + jnp.exp(proposal.log_scale) * eps


def centered_ranks(fitness: jax.Array) -> jax.Array:
  """f32[n] fitness replaced by its rank, scaled to [-0.5, 0.5] (ties share
  their mean rank): invariant to how the score is scaled."""
  n = fitness.shape[0]
  order = jnp.argsort(jnp.argsort(fitness)).astype(jnp.float32)
  # Ties: average the ranks of equal values.
  same = fitness[:, None] == fitness[None, :]
  ranks = (same * order[None, :]).sum(axis=1) / same.sum(axis=1)
  return ranks / jnp.maximum(n - 1, 1) - 0.5


def es_gradient(proposal: Proposal, eps: jax.Array, fitness: jax.Array) -> Proposal:
  """Score-function estimate of the gradient of ``-E[shaped fitness]``.

  Args:
    proposal: the proposal the batch was drawn from.
    eps: f32[n, D] the standard-normal draws (``z = mean + σ eps``).
    fitness: f32[n] higher is better (e.g. minus the summed gaps).

  Returns:
    the gradient as a :class:`Proposal` (to minimise, as optax does).
  """
  weights = centered_ranks(fitness)
  n = eps.shape[0]
  g_mean = -(weights[:, None] * eps).sum(axis=0) / (n * jnp.exp(proposal.log_scale))
  g_log_scale = -(weights[:, None] * (eps ** 2 - 1.0)).sum(axis=0) / n
  return Proposal(g_mean, g_log_scale)


def clip_proposal(proposal: Proposal) -> Proposal:
  """Keeps the proposal in its box: |mean| <= MAX_MEAN, log scale in [MIN_LOG_SCALE, 0]."""
  return Proposal(jnp.clip(proposal.mean, -MAX_MEAN, MAX_MEAN),
                  jnp.clip(proposal.log_scale, MIN_LOG_SCALE, 0.0))


def es_step(proposal: Proposal, opt_state, eps: jax.Array, fitness: jax.Array,
            optimizer: optax.GradientTransformation, learnt=None) -> tuple[Proposal, optax.OptState]:
  """One optimiser step of the proposal on one batch's fitness.

  ``learnt``: optional bool[D]; other components get no gradient and keep
  their values.

  Example::

    optimizer = optax.adam(0.1)
    proposal = init_proposal(width)
    opt_state = optimizer.init(proposal)
    eps, z = draw(proposal, key, 64)
    # ... simulate worlds from unit_from_latent(z, uniform), score them ...
    proposal, opt_state = es_step(proposal, opt_state, eps, fitness, optimizer)
  """
  grad = es_gradient(proposal, jnp.asarray(eps), jnp.asarray(fitness, jnp.float32))
  if learnt is not None:
    grad = jax.tree.map(lambda g: jnp.where(jnp.asarray(learnt), g, 0.0), grad)
  updates, opt_state = optimizer.update(grad, opt_state, proposal)
  return clip_proposal(optax.apply_updates(proposal, updates)), opt_state
