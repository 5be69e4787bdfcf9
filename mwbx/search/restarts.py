"""How early a repair restarts, and how many queries it takes on, chosen from
the gains the search has measured so far.

A repair restarts the objects of a world's unmet queries from a fraction of
the time they go wrong (:func:`mwbx.search.solver.restart_goal`): late
restarts keep more of what works, early ones move an object farther. Which
pays depends on the scene (a letter's slot is decided among the pegs, its
pose where it lands; a box's place by its last slide) and no constant fits
every scene. So each repair draws its *arm*, a fraction from a uniform grid
and whether it repairs one query or two together (objects that meet each
other, as the paper's user moved pairs), by Thompson sampling: each arm's
rate of gains so far is a Beta posterior (a uniform prior), one rate is
drawn from each and the highest wins. Arms that gain are drawn more, and
every arm keeps a chance while its rate is uncertain. Places and poses
(:attr:`mwbx.Query.goal`) learn apart: they are decided at different times.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# Restart fractions of the time the objects go wrong: a uniform grid over
# (0, 1). Never 0: a restart from the start is a resample, guided sampling's job.
FRACTIONS = (0.1, 0.3, 0.5, 0.7, 0.9)
# How many of a world's unmet queries one repair takes on.
GROUP_SIZES = (1, 2)
GOALS = ("place", "pose")  # Query.goal; another goal learns with the places


class RestartArm(NamedTuple):
  """One way to repair: restart from ``fraction`` of the time the objects go
  wrong, repairing ``group`` unmet queries together."""

  fraction: float
  group: int


ARMS = tuple(RestartArm(f, g) for g in GROUP_SIZES for f in FRACTIONS)


class RestartArms:
  """Thompson sampling over :data:`ARMS`, one posterior per goal.

  Example::

    arms = RestartArms()
    arm = arms.draw("place", max_group=2, rng=rng)
    arms.record("place", arm, gained=True)
    arms.rates("place")  # the posterior mean gain rate of each arm
  """

  def __init__(self):
    self.gains = np.zeros((len(GOALS), len(ARMS)))
    self.losses = np.zeros((len(GOALS), len(ARMS)))

  def draw(self, goal: str, max_group: int, rng: np.random.Generator) -> int:
    """The index into :data:`ARMS` of the arm to pull: the highest of one
    draw from each arm's posterior; only arms of at most ``max_group`` queries."""
    g = _goal_row(goal)
    sample = rng.beta(1.0 + self.gains[g], 1.0 + self.losses[g])
    sample[[arm.group > max_group for arm in ARMS]] = -1.0
    return int(np.argmax(sample))

  def record(self, goal: str, arm: int, gained: bool) -> None:
    g = _goal_row(goal)
    if gained:
      self.gains[g, arm] += 1
    else:
      self.losses[g, arm] += 1

  def rates(self, goal: str) -> np.ndarray:
    """f64[len(ARMS)] each arm's posterior mean rate of gains."""
    g = _goal_row(goal)
    return (1.0 + self.gains[g]) / (2.0 + self.gains[g] + self.losses[g])


def _goal_row(goal: str) -> int:
  return GOALS.index(goal) if goal in GOALS else 0
