"""Goal-seeking: find a world that satisfies every query by refinement alone.

The paper leaves the search to a person and sketches how an algorithm could
do it (§6): repair the objects that are wrong, from a time before they go
wrong, keep what works, back-track when stuck. :func:`solve` is that search
over the bank's refinement tree, with every world in the bank as its
population:

1. Pick a world by lexicase selection (:mod:`mwbx.search.lexicase`): a
   random order of the queries, places first (:func:`place_queries`), filters
   the worlds tried fewer than ``tries_per_world`` times; the world left is
   the best at that order's first queries, the nearest to the rest among
   equals. Its first unmet queries in that order are what it repairs. The
   best world is picked most, and every world meeting a set of queries no
   other world's contains (a letter in the slot no better world has it in)
   is picked too, so no one lineage decides the search.
2. Draw how: one query or two together, restarted from which fraction of
   the time they go wrong, by Thompson sampling over the gains measured so
   far (:mod:`mwbx.search.restarts`).
3. The objects involved (the query's bodies' objects, or the object a joint
   query's joint belongs to; of a ``mode: any`` query, not an object that
   alone holds another: ``_Search.repair_target``) are refined from that
   fraction of the time they go wrong (:func:`restart_goal`): when they leave
   the nearest path of a world that meets the query (:func:`divergence_time`),
   no earlier than where an include query's bodies settle (:func:`settle_time`);
   without such a world, the query's deadline; an orientation query's
   bodies: when they settle.
4. ``keep`` children join the bank under their parent, each a lexicase pick
   among them, the first with the repaired queries first: the child nearest
   the repair's goal is kept even where it lost something else. The others
   are dropped. The refinement *gains* where a child meets more places, or as
   many and more queries, than its parent: that is what the restart's arm
   learns from.
5. After ``patience`` refinements without a better best world,
   ``reseed_rounds`` batches of guided sampling aimed at the best world's
   unmet query that refinements have met least often add worlds where it
   holds (where the initial conditions put a letter in its slot, say):
   refinement cannot change initial conditions, and lexicase selection works
   on such worlds as soon as they meet it.

Every step is an ordinary :func:`mwbx.refine`: the result is an ordinary,
plausible world with its full lineage, viewable and refinable by hand.
A budget that runs out ends with the best world found and a message saying so
(``solved=False``); ``throw=True`` raises instead. Ctrl-C (KeyboardInterrupt)
ends it with :class:`SolveInterrupted`, which holds the result so far: the
refinements already done are kept, to be saved as at any end.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from typing import NamedTuple, Sequence

import jax
import numpy as np

from mwbx.bank import Bank
from mwbx.errors import MwbxError
from mwbx.progress import Progress
from mwbx.queries import metric, query_gaps
from mwbx.queries.paths import body_radii
from mwbx.queries.query import as_queries
from mwbx.queries.selection import selection_mask
from mwbx.refinement import RefineRequest, run_refinement, sampler_for
from mwbx.refinement.plan import refined_events
from mwbx.search.guided import fitness, guided_sample, typical_gaps
from mwbx.search.lexicase import first_unmet, lexicase, lexicase_keep, query_order
from mwbx.search.objects import spare_objects
from mwbx.search.restarts import ARMS, RestartArms

class KeyStream(enum.IntEnum):
  """The search's independent random streams: each is folded into the search
  key first, then the draw's index into the stream, so no two draws of one
  search can share a key (a single ``fold_in(key, offset + index)`` per use
  lets one stream's index reach another's offset)."""
  GUIDED = 0  # the guided sampling before the search
  RESEED = 1  # guided reseeding when the search stalls, by refinement count
  REFINE = 2  # each refinement's perturbations, by refinement count
  SELECT = 3  # lexicase orders and restart arms (one generator for the whole search)


def stream_key(key: jax.Array, stream: KeyStream, index: int = 0) -> jax.Array:
  """The key of draw ``index`` of ``stream`` in a search keyed by ``key``."""
  return jax.random.fold_in(jax.random.fold_in(key, int(stream)), int(index))
SOLVE_PHASE = "solving"
# Two paths part where their bodies are this many bounding radii apart.
DIVERGENCE_TOLERANCE = 0.5


@dataclasses.dataclass(frozen=True)
class Budget:
  """When :func:`solve` gives up (whichever comes first; None: no limit).

  Attributes:
    refinements: refinement calls.
    seconds: wall time, s.
    world_steps: physics steps of refined (and guided) worlds.
  """

  refinements: int | None = None
  seconds: float | None = None
  world_steps: int | None = None

  def __post_init__(self):
    for field in ("refinements", "seconds", "world_steps"):
      value = getattr(self, field)
      if value is not None and not value > 0:
        raise MwbxError(f"solve: budget.{field} must be > 0 or None, got {value!r}")
    if self.refinements is None and self.seconds is None and self.world_steps is None:
      raise MwbxError("solve: budget: set at least one of refinements, seconds, world_steps")

  def expected_refinements(self, refinements: int, seconds: float, world_steps: int) -> int:
    """How many refinements the budget allows at the rate so far (for progress)."""
    limits = [self.refinements] if self.refinements is not None else []
    if refinements > 0 and self.seconds is not None:
      limits.append(refinements * self.seconds / max(seconds, 1e-9))
    if refinements > 0 and self.world_steps is not None:
      limits.append(refinements * self.world_steps / max(world_steps, 1))
    return int(max(refinements, min(limits))) if limits else refinements + 1

  def spent(self, refinements: int, seconds: float, world_steps: int) -> bool:
    return ((self.refinements is not None and refinements >= self.refinements)
            or (self.seconds is not None and seconds >= self.seconds)
            or (self.world_steps is not None and world_steps >= self.world_steps))


@dataclasses.dataclass(frozen=True)
class SolveOptions:
  """How :func:`solve` searches: its knobs, each with its default (the one
  argument besides the bank and the goal; :func:`solve` also takes them by
  name). Checked when made.

  Attributes:
    budget: a :class:`Budget`, or an int: refinements (default 100); an int
      becomes ``Budget(refinements=int(budget))``.
    key: search key (default ``jax.random.key(0)``: a search is repeatable).
    samples: refined worlds per refinement. keep: children kept per refinement.
    tries_per_world: refinements from one world; after, lexicase selection
      no longer picks it.
    patience: refinements without a better best world before the search
      reseeds (``reseed_rounds``; see the module docstring).
    backend: ``native`` | ``mjx`` (default: the bank's config's).
    guided_rounds: batches of guided sampling (:func:`guided_sample`) added to
      the bank before the search, ``guided_batch`` worlds each.
    guided_batch: worlds per batch of guided sampling (``guided_rounds``,
      ``reseed_rounds``).
    reseed_rounds: at a stall, batches of guided sampling aimed at the best
      world's unmet query that refinements have met least often
      (``guided_batch`` worlds each), added to the bank: more worlds where it
      holds to repair the rest in. 0: none.
    tie_metric: metric (summed over bodies) that breaks ties, smaller first.
    throw: raise :class:`~mwbx.MwbxError` when the budget runs out unsolved.

  Example::

    options = mwbx.SolveOptions(budget=mwbx.search.Budget(seconds=600), samples=16)
    result = mwbx.solve(bank, queries, options)  # as mwbx.solve(bank, queries, budget=..., samples=16)
  """

  budget: Budget | int = 100
  key: jax.Array | None = None
  samples: int = 32
  keep: int = 4
  tries_per_world: int = 4
  patience: int = 40
  backend: str | None = None
  guided_rounds: int = 0
  guided_batch: int = 64
  reseed_rounds: int = 4
  tie_metric: str = "collisions"
  throw: bool = False

  def __post_init__(self):
    if isinstance(self.budget, (int, np.integer)):
      object.__setattr__(self, "budget", Budget(refinements=int(self.budget)))
    if self.samples < 1 or self.keep < 1 or self.tries_per_world < 1:
      raise MwbxError(f"solve: samples, keep and tries_per_world must be >= 1, got {self.samples}, {self.keep},"
                      f" {self.tries_per_world}")


_OPTION_FIELDS = frozenset(field.name for field in dataclasses.fields(SolveOptions))


class SolveStep(NamedTuple):
  """The search after one refinement (or the start, or guided sampling).

  Attributes:
    refinements: refinements done. world_steps: physics steps spent.
    seconds: wall time. satisfied: queries the best world meets.
    world: the best world's id. refined: the world refined in this step (-1: none).
    objects: objects refined. t_min: restart time, s (nan: none).
    repaired: names (or indices) of the queries the refinement aimed at, and
      ``attempt``: the refinements from that world before this one. With the
      search's seed they say why each refinement was made: the path is the
      same on every run (only ``seconds`` differ).
    places: places (:func:`place_queries`) the best world meets; the search
      ranks by them first, so ``satisfied`` may dip when a place is won at
      the cost of poses (-1: not recorded).
    fraction: the restart arm's fraction of the time the objects go wrong
      (nan: none). gained: whether a child met more places than its parent,
      or as many and more queries (what the arm learnt).
  """

  refinements: int
  world_steps: int
  seconds: float
  satisfied: int
  world: int
  refined: int
  objects: tuple[str, ...]
  t_min: float
  repaired: tuple[str, ...] = ()
  attempt: int = -1
  places: int = -1
  fraction: float = float("nan")
  gained: bool = False


class SolveResult(NamedTuple):
  """What :func:`solve` found.

  Attributes:
    bank: the bank with every kept refinement (and guided world) appended.
    world: id of the best world found.
    satisfied: queries it meets. n_queries: queries asked.
    solved: whether it meets all of them.
    unmet: names (or indices) of the queries it does not meet.
    message: one line saying what happened.
    steps: the search's progress, one :class:`SolveStep` per step.
    advice: unsolved: one short paragraph on what is closest, which queries
      block it and what to try (a larger budget, more sampled worlds); "" if solved.
  """

  bank: Bank
  world: int
  satisfied: int
  n_queries: int
  solved: bool
  unmet: tuple[str, ...]
  message: str
  steps: tuple[SolveStep, ...]
  advice: str = ""


class SolveInterrupted(KeyboardInterrupt):
  """Ctrl-C (or SIGTERM through the CLI) during :func:`solve`.

  Attributes:
    result: the :class:`SolveResult` so far: every refinement finished
      before the interrupt is in ``result.bank``, its best world in
      ``result.world``; save it as a finished search's.
  """

  def __init__(self, result: SolveResult):
    super().__init__(f"solve: {result.message}")
    self.result = result


def deadline(bank, world: int, query) -> float:
  """Seconds by which a query's objects must be right, in one world
  (:meth:`mwbx.Query.deadline`): an include query's window start (else the
  world's end), an exclude query's first entry (a whole-geometry one's: its
  bounding sphere's, no later), a joint or orientation query's window start
  (else its end)."""
  return query.deadline(bank, world)


def _apart(bank, bodies: np.ndarray, com: np.ndarray, reference: np.ndarray) -> np.ndarray:
  """bool[...]: where some chosen body's COM (``com`` f32[..., b, 3], m) is
  more than :data:`DIVERGENCE_TOLERANCE` of its bounding radius from
  ``reference`` (broadcast against ``com``)."""
  radius = np.maximum(body_radii(bank.model, np.asarray(bank.body_ids)[bodies]), 1e-3)
  return (np.linalg.norm(com - reference, axis=-1) > DIVERGENCE_TOLERANCE * radius).any(axis=-1)


def divergence_time(bank, row: int, matching: np.ndarray, bodies: np.ndarray) -> float | None:
  """When a world's bodies leave the nearest path that meets the query.

  Args:
    bank: the bank. row: the world's row.
    matching: i[K] rows of worlds that meet the query.
    bodies: bool[B] the query's bodies.

  Returns:
    seconds: over the matching worlds, the latest time up to which the
    world's chosen bodies stayed within :data:`DIVERGENCE_TOLERANCE` of that
    world's bodies' bounding radius of it; None without matching worlds.
  """
  matching = matching[matching != row]
  if matching.size == 0 or not bodies.any():
    return None
  com = np.asarray(bank.com[np.concatenate([[row], matching])], np.float32)[:, :, bodies]  # [1+K, P, b, 3]
  apart = _apart(bank, bodies, com[1:], com[:1])  # [K, P]
  first_apart = np.where(apart.any(axis=1), apart.argmax(axis=1), apart.shape[1])
  return float(first_apart.max()) / float(bank.query_fps)


def settle_time(bank, row: int, bodies: np.ndarray) -> float:
  """When a world's bodies come to their final place.

  Args:
    bank: the bank. row: the world's row.
    bodies: bool[B] the bodies.

  Returns:
    seconds: the first stored time from which every chosen body stays
    within :data:`DIVERGENCE_TOLERANCE` of its bounding radius of where it
    ends (0 if none moves that far).
  """
  com = np.asarray(bank.com[row], np.float32)[:, bodies]  # [P, b, 3]; past com_count: the last point
  away = _apart(bank, bodies, com, com[-1:])  # [P]
  last_away = np.flatnonzero(away)
  return float(last_away[-1] + 1 if last_away.size else 0) / float(bank.query_fps)


def restart_goal(bank, row: int, world: int, query, met: np.ndarray) -> float:
  """The time a query's objects go wrong in a world: when they leave the
  nearest path of a world that meets it, else the query's deadline. An
  orientation query's bodies go wrong where they settle (how a body lands
  decides how it ends up turned, not the path that brought it there, which
  may meet other queries): from when they come to their final place. So do
  an include query's bodies that part from every meeting path before they
  settle: in a crowd (letters through a peg board) paths part early by
  chance, and restarting there re-rolls every body the crowd touches, while
  where a body settles is decided by its last bounces (docs/search.md)."""
  if query.goal == "pose":
    return min(settle_time(bank, row, selection_mask(bank, query.bodies)), deadline(bank, world, query))
  bodies = query.body_mask(bank)
  t = divergence_time(bank, row, np.flatnonzero(met & np.asarray(bank.valid, bool)), bodies)
  if t is None:
    return deadline(bank, world, query)
  if query.until_rest and bodies.any():
    t = max(t, settle_time(bank, row, bodies))
  return min(t, deadline(bank, world, query))


def place_queries(queries) -> np.ndarray:
  """bool[Q]: the queries the search ranks and repairs first, the *places*:
  every query but an orientation query (all of them where only orientations
  are asked).

  Where a body ends up among others is decided early, as it passes through
  the crowd, and a repair must restart it there, which re-rolls how it and
  the bodies it touches land. How it is turned is decided where it settles,
  and a repair restarting there moves little but that body. So a world with more
  places met is nearer the goal than one with more poses met: on SIGGRAPH,
  every letter upright with four in the wrong slots is four early restarts
  from the goal, every letter in its slot with four lying is four late ones.

  Example::

    place_queries(mwbx.load_queries("configs/queries/siggraph.yaml", bank=bank))  # the 8 slots
  """
  places = np.array([q.goal == "place" for q in as_queries(queries)], bool)
  return places if places.any() else np.ones_like(places)


def nearness(gaps: np.ndarray, ties: np.ndarray, scale: np.ndarray) -> np.ndarray:
  """f64[n] higher is better, between worlds meeting the same queries (what
  lexicase selection breaks its ties by): the fitness of query gaps ``gaps``
  (f64[n, Q], the squashed gaps to the unmet ones), then the smallest tie
  metric ``ties`` (f[n]); ranks, so only the order counts."""
  order = np.lexsort((ties, -fitness(gaps, scale)))
  rank = np.empty(len(order))
  rank[order] = -np.arange(len(order))
  return rank


def _label(query, index: int) -> str:
  return query.name or f"query {index}"


def solve(bank: Bank, queries, options: SolveOptions | None = None, *, progress=None, **fields) -> SolveResult:
  """Searches the bank's refinement tree for a world that meets every query.

  Args:
    bank: the sampled bank to start from (worlds, or a bank already refined).
    queries: the goal: a query list or :class:`~mwbx.QuerySet`.
    options: how to search: a :class:`SolveOptions` (budget, key, samples,
      keep, tries_per_world, patience, backend, guided_rounds, guided_batch,
      reseed_rounds, tie_metric, throw); default: its defaults.
    progress: optional callback taking a :class:`mwbx.progress.Progress`.
    **fields: instead of ``options``, its fields by name (``budget=200,
      samples=16``); not both.

  Returns:
    a :class:`SolveResult`; ``result.bank`` holds every kept world.

  Raises:
    SolveInterrupted: on Ctrl-C (KeyboardInterrupt), holding the result so
      far (every refinement finished is in its bank).
    TypeError: ``options`` and fields both given, or a field it does not have.

  Example::

    bank = mwbx.Bank.load("out/siggraph")
    queries = mwbx.load_queries("configs/queries/siggraph.yaml", bank=bank)
    result = mwbx.solve(bank, queries, budget=mwbx.search.Budget(seconds=600))
    print(result.message)
    bank = result.bank.save("out/siggraph")  # the bank as stored: its new worlds' ids as on disk
    world = bank.origin.id_on_disk(result.world)  # the solved world's id there
  """
  if options is not None and fields:
    raise TypeError(f"solve: give options or its fields ({', '.join(sorted(fields))}), not both")
  if options is not None and not isinstance(options, SolveOptions):
    raise TypeError(f"solve: options must be a SolveOptions, got {type(options).__name__}")
  unknown = sorted(set(fields) - _OPTION_FIELDS)
  if unknown:
    raise TypeError(f"solve() got an unexpected keyword argument {unknown[0]!r}")
  queries = as_queries(queries)
  if not queries:
    raise MwbxError("solve: give at least one query to satisfy")
  options = SolveOptions(**fields) if options is None else options
  search = _Search(bank, queries, options, progress)
  try:
    search.begin()
    while search.step():
      pass
    return search.result(search.reason, options.throw)
  except KeyboardInterrupt:  # Ctrl-C: what was found so far is kept
    raise SolveInterrupted(search.interrupted()) from None


class _Search:
  """The state of one :func:`solve`: the bank as it grows (its worlds are the
  population), each world's query gaps (and so which queries it meets), the
  tie metric, the restart arms' measured gains and the bookkeeping of tries
  and plateaus. :meth:`begin`, then :meth:`step` until it returns False,
  then :meth:`result`."""

  def __init__(self, bank: Bank, queries, options: SolveOptions, progress):
    self.options = options
    self.bank, self.queries, self.budget = bank, queries, options.budget
    self.key = jax.random.key(0) if options.key is None else options.key
    self.rng = np.random.default_rng(
        np.asarray(jax.random.key_data(stream_key(self.key, KeyStream.SELECT))).ravel().tolist())
    self.tie_metric, self.backend, self.progress = options.tie_metric, options.backend, progress
    self.start = time.perf_counter()
    self.n_queries = len(queries)
    self.sampled = int((np.asarray(bank.parent_world) < 0).sum())  # the sampled worlds it started from
    self.gaps = query_gaps(bank, queries)  # f[W, Q]
    self.met = self.gaps == 0  # query_gaps is 0 exactly where evaluate_each holds
    # mode-any queries over several objects, as each object alone meets them
    self.alone = [(q, obj, query) for q in range(len(queries)) for obj, query in queries[q].per_object(bank).items()]
    self.alone_met = self._alone_met(bank)  # bool[W, len(self.alone)]
    self.scale = typical_gaps(self.gaps)
    self.places = place_queries(queries)  # bool[Q]: first in every order, ranked first
    self.ties = metric(bank, self.tie_metric)
    self.arms = RestartArms()
    self.steps: list[SolveStep] = []
    self.spent_steps, self.refinements = 0, 0
    self.tries: dict[int, int] = {}  # refinements started from each world id
    self.attempts = np.zeros(self.n_queries, np.int64)  # refinements aimed at each query
    self.hits = np.zeros(self.n_queries, np.int64)  # of those, refinements with a child meeting it
    # The plateau: the search gains when the best world's (places, queries met) rise.
    self.best_met = (-1, -1)  # the best world's (places, queries met) at the last gain
    self.last_gain = 0  # refinements at the last gain, or at the last reseeding
    self.reason = ""  # why the search ended unsolved; meanwhile, the last world it could not refine

  def begin(self) -> None:
    """Before the first step: guided sampling (``guided_rounds``) and the first record."""
    if self.options.guided_rounds > 0:
      self.add_guided(self.queries, self.options.guided_rounds, self.options.guided_batch,
                      stream_key(self.key, KeyStream.GUIDED))
    self.note()

  def step(self) -> bool:
    """One turn of the search: the plateau's bookkeeping (:meth:`track_plateau`),
    then a world picked by lexicase selection repaired (:meth:`repair`: at
    most one refinement). Returns whether the search goes on: False once the
    best world meets every query, the budget is spent or every world was
    tried (:attr:`reason` says which of the last two)."""
    best = self.steps[-1]
    if best.satisfied == self.n_queries:
      return False
    if self.budget_spent():
      self.reason = "budget spent"
      return False
    self.track_plateau(best)
    picked = self.pick(self.options.tries_per_world)
    if picked is None:
      self.reason = "every world tried"
      return False
    self.repair(*picked)
    return True

  def track_plateau(self, best: SolveStep) -> None:
    """Notes a gain of the best world ``best``; after ``patience``
    refinements without one, reseeds (:meth:`reseed`)."""
    if (best.places, best.satisfied) > self.best_met:
      self.best_met, self.last_gain = (best.places, best.satisfied), self.refinements
    elif self.refinements - self.last_gain >= self.options.patience:
      self.reseed(best.world, self.options.reseed_rounds, self.options.guided_batch)
      self.last_gain = self.refinements

  def pick(self, tries_per_world: int) -> tuple[int, int, int, list[int]] | None:
    """A world tried fewer than ``tries_per_world`` times, by lexicase
    selection over one random order of the queries: (row, world id, tries
    so far, its unmet queries in that order), counted as tried; None if none."""
    valid = np.flatnonzero(self.bank.valid)
    rows = np.asarray([r for r in valid if self.tries.get(int(self.bank.world_ids[r]), 0) < tries_per_world],
                      np.int64)
    if rows.size == 0:
      return None
    order = query_order(self.places, self.rng)
    row = int(rows[lexicase(self.met[rows], order, nearness(self.gaps[rows], self.ties[rows], self.scale))])
    world = int(self.bank.world_ids[row])
    attempt = self.tries.get(world, 0)
    self.tries[world] = attempt + 1
    return row, world, attempt, first_unmet(self.met[row], order)

  def repair(self, row: int, world: int, attempt: int, unmet: list[int]) -> None:
    """Attempt ``attempt`` on world ``world`` (at ``row``): refines the objects
    of its first unmet queries (``unmet``, in the pick's order), one or two as
    the drawn arm says, from the arm's fraction of the time they go wrong; a
    world it cannot refine is tried out."""
    tries_per_world = self.options.tries_per_world
    if not unmet:  # a world guided reseeding just added meets every query
      self.note()
      return
    goal = self.queries[unmet[0]].goal
    arm = self.arms.draw(goal, max_group=len(unmet), rng=self.rng)
    fraction, group = ARMS[arm]
    chosen = unmet[:group]
    self.attempts[chosen] += 1
    objects, targets = [], [self.repair_target(row, q) for q in chosen]
    for target_objects, _, _ in targets:
      objects += [o for o in target_objects if o not in objects]
    if not objects:
      self.tries[world] = tries_per_world  # nothing to refine for these queries here
      return
    t_goal = min(restart_goal(self.bank, row, world, query, met) for _, query, met in targets)
    t_min = fraction * t_goal
    try:
      gained = self.refine(row, world, objects, t_min, chosen)
    except MwbxError as err:  # e.g. a restart past the end: this world cannot be repaired so
      self.tries[world] = tries_per_world
      self.reason = f"world {world}: {err}"
      return
    self.arms.record(goal, arm, gained)
    self.note(world, objects, t_min, tuple(_label(self.queries[q], q) for q in chosen), attempt, fraction, gained)

  def elapsed(self) -> float:
    return time.perf_counter() - self.start

  def budget_spent(self) -> bool:
    return self.budget.spent(self.refinements, self.elapsed(), self.spent_steps)

  def best_rows(self, rows: np.ndarray) -> np.ndarray:
    """``rows`` best first (:meth:`rank_order`)."""
    return rows[self.rank_order(self.gaps[rows], self.ties[rows])]

  def rank_order(self, gaps: np.ndarray, ties: np.ndarray) -> np.ndarray:
    """i[n] the order of worlds with query gaps ``gaps: f64[n, Q]`` and tie
    metric ``ties: f[n]``, best first, as the search reports its best world:
    most places met (:func:`place_queries`), then the fitness of every
    query, then the smallest tie metric."""
    places_met = ((gaps == 0) & self.places).sum(axis=1)
    return np.lexsort((ties, -fitness(gaps, self.scale), -places_met))

  def note(self, refined: int = -1, objects=(), t_min: float = float("nan"), repaired=(), attempt: int = -1,
           fraction: float = float("nan"), gained: bool = False) -> None:
    """Records a step (the best world now) and reports progress."""
    bank = self.bank
    rows = self.best_rows(np.flatnonzero(bank.valid)) if bank.valid.any() else np.zeros(0, int)
    row = rows[0] if rows.size else 0
    self.steps.append(SolveStep(self.refinements, self.spent_steps, self.elapsed(), int(self.met[row].sum()),
                                int(bank.world_ids[row]), int(refined), tuple(objects), float(t_min),
                                tuple(repaired), int(attempt), int(self.met[row, self.places].sum()),
                                float(fraction), bool(gained)))
    if self.progress is not None:
      total = self.budget.expected_refinements(self.refinements, self.elapsed(), self.spent_steps)
      self.progress(Progress(SOLVE_PHASE, min(self.refinements, total), total, self.spent_steps, self._best_note()))

  def _best_note(self) -> str:
    """The progress note: the best world and the queries it meets."""
    best = self.steps[-1]
    note = f"best world {best.world}: {best.satisfied} of {self.n_queries} met"
    if not self.places.all():
      note += f" ({best.places} of {int(self.places.sum())} places)"
    return note

  def _alone_met(self, bank: Bank) -> np.ndarray:
    if not self.alone:
      return np.zeros((bank.n_worlds, 0), bool)
    return query_gaps(bank, [query for _, _, query in self.alone]) == 0

  def _add(self, new: Bank, gaps: np.ndarray, ties: np.ndarray) -> None:
    # Everything computed first and the bank set last: an interrupt on the way leaves rows past the
    # bank's, which interrupted() drops, never a bank row without its gaps.
    bank = self.bank.append(new)
    all_gaps = np.concatenate([self.gaps, gaps])
    all_ties = np.concatenate([self.ties, ties])
    alone_met = np.concatenate([self.alone_met, self._alone_met(new)])
    self.gaps, self.met, self.ties, self.alone_met = all_gaps, all_gaps == 0, all_ties, alone_met
    self.bank = bank

  def interrupted(self) -> SolveResult:
    """What the search holds when interrupted: its bank (every refinement
    finished), its best world and a message saying so; reported to no
    progress callback (the interrupt may come from it)."""
    n = self.bank.n_worlds
    self.gaps, self.met, self.ties, self.alone_met = (self.gaps[:n], self.met[:n], self.ties[:n],
                                                      self.alone_met[:n])
    self.progress = None
    self.note()  # the best world among every row kept
    return self.result("interrupted", throw=False)

  def repair_target(self, row: int, q: int) -> tuple[list[str], object, np.ndarray]:
    """What repairing query ``q`` in world ``row`` changes: (objects, the
    query their restart time is judged by, bool[W] the worlds meeting it).

    A ``mode: any`` query over several objects leaves alone each object that
    is the only one meeting another such query in this world (:func:`spare_objects`):
    on SIGGRAPH the G in one G slot stays while the other G is moved to the
    other slot. With one object left, the restart time follows that object
    alone.
    """
    objects = self.queries[q].objects(self.bank)
    meeting: dict[int, list[str]] = {}  # another query -> the objects meeting it alone here
    for v, (other, obj, _) in enumerate(self.alone):
      if other != q and self.alone_met[row, v]:
        meeting.setdefault(other, []).append(obj)
    # An object holds a query only as the one object meeting it: of two Gs in one slot, either may move.
    spare = spare_objects(objects, {objs[0] for objs in meeting.values() if len(objs) == 1})
    if len(spare) == 1 and len(objects) > 1:
      for v, (other, obj, query) in enumerate(self.alone):
        if other == q and obj == spare[0]:
          return spare, query, self.alone_met[:, v]
    return spare, self.queries[q], self.met[:, q]

  def add_guided(self, goal, rounds: int, batch: int, key: jax.Array) -> None:
    """Guided sampling toward ``goal``, its worlds added to the bank."""
    result = guided_sample(sampler_for(self.bank, self.backend), goal, rounds=rounds, batch=batch, key=key,
                           first_world=self.bank.next_world_id)
    self._add(result.bank, query_gaps(result.bank, self.queries), metric(result.bank, self.tie_metric))
    self.spent_steps += int(result.bank.steps.sum())

  def reseed(self, best_world: int, reseed_rounds: int, batch: int) -> None:
    """On a plateau: the best world's unmet query that refinements have met
    least often (as a share of those aimed at it) may be out of reach from
    these worlds (their initial conditions decide it). Adds worlds guided
    toward it; lexicase selection works on them where they meet it."""
    if reseed_rounds <= 0:
      return
    row = self.bank.row_of(best_world)
    unmet = np.flatnonzero(~self.met[row])
    if unmet.size == 0:
      return
    rate = self.hits[unmet] / np.maximum(self.attempts[unmet], 1)
    blocking = int(unmet[np.lexsort((-self.attempts[unmet], rate))[0]])
    try:  # more worlds where the blocking query holds (its objects' initial conditions)
      self.add_guided([self.queries[blocking]], reseed_rounds, batch,
                      stream_key(self.key, KeyStream.RESEED, self.refinements))
    except MwbxError:
      pass  # nothing randomized to guide

  def refine(self, row: int, world: int, objects, t_min: float, repaired: list[int]) -> bool:
    """Refines ``objects`` of ``world`` (at ``row``) from ``t_min``; keeps
    ``keep`` valid children in the bank, each a lexicase pick, the first with
    the ``repaired`` queries first. Returns whether it gained: some child
    meets more places than the parent, or as many and more queries."""
    # Contact events of every child only where a query reads them; else of the kept children alone.
    events = any(q.needs_events for q in self.queries)
    done = run_refinement(self.bank, RefineRequest(world, objects, t_min=t_min, n_samples=self.options.samples,
                                               backend=self.backend,
                                               key=stream_key(self.key, KeyStream.REFINE, self.refinements),
                                               events=events))
    children, stats = done.new, done.stats
    self.refinements += 1
    self.spent_steps += int(stats.world_steps)
    c_gaps = query_gaps(children, self.queries)
    c_ties = metric(children, self.tie_metric)
    c_met = c_gaps == 0
    valid = np.flatnonzero(children.valid)
    self.hits[repaired] += c_met[valid][:, repaired].any(axis=0)
    if valid.size == 0:
      return False
    first = list(repaired) + [q for q in query_order(self.places, self.rng) if q not in repaired]
    orders = [np.asarray(first)] + [query_order(self.places, self.rng) for _ in range(self.options.keep - 1)]
    score = nearness(c_gaps[valid], c_ties[valid], self.scale)
    kept = np.sort(valid[lexicase_keep(c_met[valid], score, self.options.keep, orders)])
    dropped = np.setdiff1d(np.arange(children.n_worlds), kept)
    chosen = children.drop(children.world_ids[dropped]) if dropped.size else children
    if not events and self.bank.events is not None:
      found, actors = refined_events(done.parent_bank, done.plan.row, done.plan.first_frame, chosen.qpos_store,
                                     sampler_for(done.parent_bank, self.backend))
      chosen = dataclasses.replace(chosen, events=found, event_actors=actors)
    parent = (int(self.met[row, self.places].sum()), int(self.met[row].sum()))
    self._add(chosen, c_gaps[kept], c_ties[kept])
    best = max((int(c_met[k, self.places].sum()), int(c_met[k].sum())) for k in valid)
    return best > parent

  def result(self, reason: str, throw: bool) -> SolveResult:
    """What the search found, with one line saying so."""
    if self.progress is not None:  # the bar ends at the refinements made, not the budget's estimate
      self.progress(Progress(SOLVE_PHASE, self.refinements, max(self.refinements, 1), self.spent_steps,
                             self._best_note()))
    last = self.steps[-1]
    row = self.bank.row_of(last.world)
    unmet = tuple(_label(self.queries[q], q) for q in range(self.n_queries) if not self.met[row, q])
    spent = f"{self.refinements} refinements, {self.spent_steps:,} world-steps, {self.elapsed():.0f} s"
    solved = last.satisfied == self.n_queries
    if solved:
      message = f"solved: world {last.world} meets all {self.n_queries} queries ({spent})"
    else:
      message = (f"not solved ({reason}; {spent}): best world {last.world} meets {last.satisfied} of"
                 f" {self.n_queries} queries; unmet: {', '.join(unmet)}")
      if throw:
        raise MwbxError(f"solve: {message}")
    return SolveResult(self.bank, last.world, last.satisfied, self.n_queries, solved, unmet, message,
                       tuple(self.steps), "" if solved else self.advice(row))

  def advice(self, row: int) -> str:
    """What is closest to a solution, what blocks it and what to try, in one
    short paragraph (the best world at ``row``)."""
    valid = np.asarray(self.bank.valid, bool)
    n_valid = int(valid.sum())
    meeting = self.met[valid].sum(axis=0)  # worlds meeting each query
    unmet = [q for q in range(self.n_queries) if not self.met[row, q]]
    blocking = sorted(unmet, key=lambda q: (int(meeting[q]), q))[:4]
    named = ", ".join(f"{_label(self.queries[q], q)} ({int(meeting[q])} of {n_valid} worlds)" for q in blocking)
    best = int(self.met[row].sum())
    runner_up = int((valid & (self.met.sum(axis=1) == best - 1)).sum()) if best else 0
    close = f"; {runner_up} more worlds meet one query fewer" if runner_up else ""
    sampled = self.sampled
    gains = [s for prev, s in zip(self.steps, self.steps[1:]) if s.satisfied > prev.satisfied]
    last_gain = gains[-1] if gains else self.steps[0]
    share = last_gain.seconds / max(self.elapsed(), 1e-9)
    budget = ("the best world was still improving late (its last gain at "
              f"{share:.0%} of the time spent): a larger budget may finish it" if share > 0.5 else
              f"the best world last improved at {share:.0%} of the time spent: more budget alone may not help")
    none_meet = [q for q in blocking if meeting[q] == 0]
    one = len(none_meet) == 1
    loosen = (f"; no world meets {', '.join(_label(self.queries[q], q) for q in none_meet)}: loosen"
              f" {'it' if one else 'them'} or refine the objects {'it names' if one else 'they name'} by hand"
              ) if none_meet else ""
    return (f"Closest: world {self.steps[-1].world} ({best} of {self.n_queries} queries{close})."
            f" Blocking: {named}. To try: {budget}; more sampled"
            f" worlds (the search started from {sampled}: `mwbx sample CONFIG --worlds {sampled} --out BANK` adds as"
            f" many){loosen}.")


def progress_plot(steps: Sequence[SolveStep], path, title: str = "") -> str:
  """Writes the search's curve (queries met by the best world against
  world-steps and wall time, and the places it meets where the steps record
  them apart: :attr:`SolveStep.places`) as a PNG; returns its path."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  steps = list(steps)
  met = [s.satisfied for s in steps]
  places = [s.places for s in steps]
  show_places = all(p >= 0 for p in places) and places != met
  fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.2), sharey=True)
  for ax, x in ((a, [s.world_steps / 1e6 for s in steps]), (b, [s.seconds for s in steps])):
    ax.step(x, met, where="post", label="queries")
    if show_places:
      ax.step(x, places, where="post", label="places (ranked first)")
    ax.grid(alpha=0.3)
  a.set_xlabel("world-steps (millions)")
  a.set_ylabel("met by the best world")
  b.set_xlabel("wall time (s)")
  if show_places:
    b.legend(loc="lower right", fontsize=8)
  fig.suptitle(title or f"solve: {len([s for s in steps if s.refined >= 0])} refinements")
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)
  return str(path)
