"""Recording rates: how often a world's qpos frames and COM polylines are kept.

The physics step is the MJCF's own ``<option timestep>`` (or ``sim.timestep``);
changing it would change the physics, so the rates follow it instead. A stored
frame is a whole number of physics steps, and a query point a whole number of
frames:

* ``sim.record_fps`` unset: ``1 / (k · timestep)`` for the whole ``k`` that
  brings it nearest to 120 fps (0.002 s: 4 steps, 125 fps; 0.005 s: 2 steps,
  100 fps; 0.02 s: 1 step, 50 fps; a timestep dividing 1/120 s keeps 120 fps).
* ``sim.query_fps`` unset: ``record_fps / s`` for the whole ``s`` that brings it
  nearest to 30 fps (120 fps: every 4th frame, 30 fps; 125 fps: every 4th,
  31.25 fps; 100 fps: every 3rd, 33.3 fps; 50 fps: every 2nd, 25 fps).

Values the config sets are kept; only values that contradict each other are an
error, and its message names both.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mwbx.config import Config
from mwbx.errors import MwbxError

# The rates chosen for a timestep that allows them exactly (the shipped scenes).
DEFAULT_RECORD_FPS = 120.0
DEFAULT_QUERY_FPS = 30.0
# Relative slack of "a whole number": MJCF timesteps are written in decimal
# (1/480 s as 0.00208333333333333).
_WHOLE_TOLERANCE = 1e-6


class Rates(NamedTuple):
  """The rates a scene samples at.

  Attributes:
    timestep: physics step, s.
    timestep_from: where it comes from (``sim.timestep`` or the MJCF).
    steps_per_frame: physics steps per stored qpos frame.
    record_fps: stored qpos frames per second, Hz.
    query_stride: stored frames per COM polyline point.
    query_fps: COM polyline points per second, Hz.
    chosen: the fields chosen here (not set by the config).
  """

  timestep: float
  timestep_from: str
  steps_per_frame: int
  record_fps: float
  query_stride: int
  query_fps: float
  chosen: tuple[str, ...]

  def describe(self) -> str:
    """One line: the step, the frame and query rates, and which were chosen."""
    every = {1: "every frame", 2: "every 2nd frame", 3: "every 3rd frame"}.get(
        self.query_stride, f"every {self.query_stride}th frame")
    steps = "1 step" if self.steps_per_frame == 1 else f"{self.steps_per_frame} steps"
    source = "sim.timestep" if self.timestep_from == "sim.timestep" else "MJCF"
    chosen = f"chosen from the step: {', '.join(self.chosen)}" if self.chosen else "as the config sets them"
    return (f"rates: physics step {self.timestep:g} s ({source}), {steps} a frame: record"
            f" {self.record_fps:.6g} fps, query {self.query_fps:.6g} fps ({every}); {chosen}")


def _whole(x: float) -> int | None:
  """round(x) if x is a whole number >= 1 (within the tolerance), else None."""
  n = round(x)
  return int(n) if n >= 1 and abs(x - n) <= _WHOLE_TOLERANCE * x else None


def _fps(steps: int, timestep: float) -> float:
  """1 / (steps · timestep), snapped to a whole number of Hz where that is one
  within the tolerance (so 1/480 s written in decimal still records 120 fps)."""
  fps = 1.0 / (steps * timestep)
  snapped = float(round(fps))
  return snapped if snapped >= 1 and _whole(1.0 / (snapped * timestep)) == steps else fps


def _nearest(candidates, target: float):
  """The candidate (value, ...) whose value is nearest ``target`` (the higher on a tie)."""
  return min(candidates, key=lambda c: (round(abs(c[0] - target), 9), -c[0]))


def resolve(config: Config, timestep: float) -> Rates:
  """The rates of ``config`` for a physics step, chosen where it leaves them unset.

  Args:
    config: the validated config; ``sim.record_fps`` and ``sim.query_fps``
      count as set when its YAML (or a copy made with them) names them with a
      number (null: choose).
    timestep: the physics step the scene runs at, s (``sim.timestep`` if
      set, else the MJCF's ``<option timestep>``).

  Returns:
    the :class:`Rates`.

  Raises:
    MwbxError: values the config sets contradict each other or the MJCF's
      timestep; the message names both.
  """
  source = config.source or "<config>"
  sim = config.sim
  given = sim.model_fields_set
  step_name = "sim.timestep" if sim.timestep is not None else "the MJCF's <option timestep>"
  step_text = f"{step_name} = {timestep:g} s"
  if not (timestep > 0 and math.isfinite(timestep)):
    raise MwbxError(f"{source}: {step_text}: must be a positive number of seconds")
  record_set = "record_fps" in given and sim.record_fps is not None
  query_set = "query_fps" in given and sim.query_fps is not None
  if record_set:
    steps = _whole(1.0 / (sim.record_fps * timestep))
    if steps is None:
      near = max(1, round(1.0 / (sim.record_fps * timestep)))
      raise MwbxError(
          f"{source}: sim.record_fps: {sim.record_fps:g} fps and {step_text} contradict each other: a frame"
          f" (1/{sim.record_fps:g} s) must be a whole number of physics steps; leave sim.record_fps unset"
          f" to record at {_fps(near, timestep):.6g} fps ({near} steps a frame)")
    record_fps = float(sim.record_fps)
  elif query_set:
    # Only frame rates of whole steps whose query stride is whole too.
    options = []
    for steps in range(1, max(1, math.floor(1.0 / (sim.query_fps * timestep) * (1 + _WHOLE_TOLERANCE))) + 1):
      fps = _fps(steps, timestep)
      if _whole(fps / sim.query_fps) is not None:
        options.append((fps, steps))
    if not options:
      raise MwbxError(
          f"{source}: sim.query_fps: {sim.query_fps:g} fps and {step_text} contradict each other: no frame"
          f" rate of whole physics steps is a whole number of query points apart; leave sim.query_fps"
          f" unset or set sim.record_fps")
    record_fps, steps = _nearest(options, DEFAULT_RECORD_FPS)
  else:
    exact = _whole(1.0 / (DEFAULT_RECORD_FPS * timestep))
    if exact is not None:
      record_fps, steps = DEFAULT_RECORD_FPS, exact
    else:
      guess = 1.0 / (DEFAULT_RECORD_FPS * timestep)
      options = {max(1, math.floor(guess)), max(1, math.ceil(guess))}
      record_fps, steps = _nearest([(_fps(k, timestep), k) for k in options], DEFAULT_RECORD_FPS)
  if query_set:
    stride = _whole(record_fps / sim.query_fps)
    if stride is None:
      raise MwbxError(
          f"{source}: sim.query_fps: {sim.query_fps:g} fps and sim.record_fps: {record_fps:.6g} fps contradict"
          f" each other: query points must be a whole number of frames apart")
    query_fps = float(sim.query_fps)
  else:
    guess = record_fps / DEFAULT_QUERY_FPS
    options = {max(1, math.floor(guess)), max(1, math.ceil(guess))}
    query_fps, stride = _nearest([(record_fps / s, s) for s in options], DEFAULT_QUERY_FPS)
  chosen = tuple(f"sim.{name}" for name, was_set in (("record_fps", record_set), ("query_fps", query_set))
                 if not was_set)
  return Rates(float(timestep), step_name, int(steps), float(record_fps), int(stride), float(query_fps), chosen)


def with_rates(config: Config, rates: Rates) -> Config:
  """A copy of ``config`` whose ``sim.record_fps``/``sim.query_fps`` are the
  given rates (counted as set from then on: the bank's config states them)."""
  sim = config.sim.model_copy(update={"record_fps": rates.record_fps, "query_fps": rates.query_fps})
  return config.model_copy(update={"sim": sim})
