"""Guided sampling: batches of worlds drawn from a proposal that learns, batch
after batch, toward the worlds a set of queries wants (:mod:`.proposal`)."""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import numpy as np
import optax

from mwbx.bank import Bank
from mwbx.batch_sim.sampler import Sampler
from mwbx.errors import MwbxError
from mwbx.progress import Progress
from mwbx.queries import query_gaps
from mwbx.queries.query import as_queries
from mwbx.search import proposal as proposal_lib
from mwbx.search.objects import involved_objects

# Adam step sizes in latent units for the means and the log scales: the scales
# learn slower, so the proposal does not narrow onto a region before its mean
# has found it (measured on quickstart, docs/search.md).
MEAN_LEARNING_RATE = 0.5
SCALE_LEARNING_RATE = 0.15
GUIDED_PHASE = "guided sampling"


class GuidedRound(NamedTuple):
  """One batch of guided sampling.

  Attributes:
    round: its index. worlds: worlds sampled in it.
    matches: worlds that met every query. met_mean: queries met per world, mean.
    world_steps: physics steps of its worlds. seconds: wall time so far.
    scale_mean: mean latent standard deviation, over the learnt components,
      of the proposal it drew from.
  """

  round: int
  worlds: int
  matches: int
  met_mean: float
  world_steps: int
  seconds: float
  scale_mean: float


class GuidedResult(NamedTuple):
  """What :func:`guided_sample` made.

  Attributes:
    bank: every guided world (ids from ``first_world`` on); each world's
      lineage entry holds ``{"proposal": {"round": r, "noise": [D floats]}}``,
      its unit noise, from which its initial state is
      ``scene.initial_state_from_noise(noise)``.
    proposal: the learnt :class:`~.proposal.Proposal`.
    rounds: one :class:`GuidedRound` per batch.
  """

  bank: Bank
  proposal: proposal_lib.Proposal
  rounds: tuple[GuidedRound, ...]


def fitness(gaps: np.ndarray, gap_scale: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
  """f32[W] higher is better: queries met (gap 0), minus each unmet query's
  gap squashed into (0, 1) by ``gap / (gap + gap_scale)``; with ``weights``,
  each query's term times its weight.

  Args:
    gaps: f64[W, Q] (:func:`mwbx.queries.query_gaps`: 0 exactly where met);
    gap_scale: f64[Q] > 0, a typical gap of each query.
    weights: f64[Q] > 0 (default: 1 each).
  """
  squashed = np.where(np.isfinite(gaps), gaps / (gaps + gap_scale[None, :]), 1.0)
  per_query = (gaps == 0) - squashed  # squashed is 0 where met
  weights = np.ones(gaps.shape[1]) if weights is None else np.asarray(weights, np.float64)
  return (per_query @ weights).astype(np.float32)


def typical_gaps(gaps: np.ndarray) -> np.ndarray:
  """f64[Q] the median positive finite gap of each query (1e-3 where none)."""
  out = np.full(gaps.shape[1], 1e-3)
  for q in range(gaps.shape[1]):
    g = gaps[:, q]
    g = g[np.isfinite(g) & (g > 0)]
    if g.size:
      out[q] = float(np.median(g))
  return out


def default_optimizer(mean_rate: float = MEAN_LEARNING_RATE,
                      scale_rate: float = SCALE_LEARNING_RATE) -> optax.GradientTransformation:
  """Adam on the proposal's means and, with a smaller step, its log scales."""
  labels = proposal_lib.Proposal(mean="mean", log_scale="scale")
  return optax.multi_transform({"mean": optax.adam(mean_rate), "scale": optax.adam(scale_rate)}, labels)


def guided_sample(sampler: Sampler, queries, *, rounds: int, batch: int, key: jax.Array,
                  first_world: int = 0, optimizer: optax.GradientTransformation | None = None,
                  proposal: proposal_lib.Proposal | None = None, objects=None,
                  progress=None) -> GuidedResult:
  """Samples ``rounds`` batches, each from the proposal the previous ones taught.

  Args:
    sampler: a :class:`~mwbx.Sampler` of the scene.
    queries: what the worlds should satisfy (a query list or QuerySet).
    rounds: batches to sample. batch: worlds per batch (at least 2).
    key: run key: batch r's worlds take ids ``first_world + r·batch …`` and
      their perturbations from ``fold_in(key, id)``; the latent draws come from
      a key split off ``key``.
    first_world: id of the first world.
    optimizer: optax optimiser of the proposal (default :func:`default_optimizer`).
    proposal: where to start (default: the configured distribution).
    objects: objects whose randomization is learnt (default: those the
      queries involve, :func:`mwbx.search.involved_objects`); the others, and
      components configured with scale 0, keep the configured distribution.
    progress: optional callback taking a :class:`mwbx.progress.Progress`.

  Returns:
    a :class:`GuidedResult`.

  Example::

    with mwbx.Sampler(mwbx.load_config("configs/pachinko.yaml")) as sampler:
      result = mwbx.search.guided_sample(sampler, queries, rounds=8, batch=64, key=jax.random.key(0))
    print([r.matches for r in result.rounds])
  """
  queries = as_queries(queries)
  if rounds < 1 or batch < 2:
    raise MwbxError(f"guided sampling: rounds must be >= 1 and batch >= 2, got {rounds} and {batch}")
  if not queries:
    raise MwbxError("guided sampling: give at least one query to guide toward")
  scene = sampler.scene
  uniform = proposal_lib.uniform_slots(scene)
  if uniform.size == 0:
    raise MwbxError(f"guided sampling: {scene.config.source or 'the config'} randomizes nothing"
                    f" (no randomize entries), so there is nothing to guide")
  if objects is None:
    objects = {o for q in queries for o in involved_objects(scene, q)}
  learnt = proposal_lib.learnt_slots(scene, set(objects))
  if not learnt.any():
    raise MwbxError(f"guided sampling: none of the objects {sorted(objects)} has a randomized quantity"
                    f" with a nonzero scale in {scene.config.source or 'the config'}")
  optimizer = optimizer or default_optimizer()
  proposal = proposal or proposal_lib.init_proposal(uniform.size)
  opt_state = optimizer.init(proposal)
  latent_key = jax.random.fold_in(key, 0x6D77)  # apart from the worlds' own keys
  start = time.perf_counter()
  parts, history, gap_scale, steps = [], [], None, 0
  for r in range(rounds):
    eps, z = proposal_lib.draw(proposal, jax.random.fold_in(latent_key, r), batch)
    noise = np.asarray(proposal_lib.unit_from_latent(z, uniform))

    def report(p, _r=r, _steps=steps):
      if p.phase == "simulating":  # one bar over every round's worlds
        progress(Progress(GUIDED_PHASE, _r * batch + p.done, rounds * batch, _steps + p.world_steps))

    part, _ = sampler.run(batch, key, first_world=first_world + r * batch, noise=noise,
                          progress=report if progress is not None else None)
    gaps = query_gaps(part, queries)
    met = gaps == 0  # query_gaps is 0 exactly where evaluate_each holds
    if gap_scale is None:  # fixed after the first batch, so fitness means the same every round
      gap_scale = typical_gaps(gaps)
    steps += int(part.steps.sum())
    history.append(GuidedRound(
        round=r, worlds=batch, matches=int(met.all(axis=1).sum()), met_mean=float(met.sum(axis=1).mean()),
        world_steps=int(part.steps.sum()), seconds=time.perf_counter() - start,
        scale_mean=float(np.exp(np.asarray(proposal.log_scale))[learnt].mean())))
    lineage = {str(int(i)): {"proposal": {"round": r, "noise": [float(x) for x in u]}}
               for i, u in zip(part.world_ids, noise)}
    parts.append(dataclasses.replace(part, lineage=lineage))
    proposal, opt_state = proposal_lib.es_step(proposal, opt_state, eps, fitness(gaps, gap_scale),
                                               optimizer, learnt)
  if progress is not None:
    progress(Progress(GUIDED_PHASE, rounds * batch, rounds * batch, steps))
  return GuidedResult(Bank.concatenate(parts), proposal, tuple(history))
