"""Refinement's entry points into each sampling backend.

A refinement runs on the backend of a :class:`~mwbx.batch_sim.sampler.Sampler`
(:func:`mwbx.refinement.sampler_for`). What differs per backend is here, in
one class each, chosen once by :func:`runner_for`:

- what it cannot do (MJX cannot keep a removed object out of contact: one
  model steps the whole batch);
- what the loop needs besides the shared inputs: per-step playback targets,
  contact-free rollout models, free-body state addresses;
- which loop runs a batch (:mod:`mwbx.refinement.loop`,
  :mod:`mwbx.refinement.compiled_refinement`).

They live beside the loops, not on :class:`mwbx.batch_sim.backend.Backend`:
``batch_sim`` sits below ``refinement`` and never imports it.
"""

from __future__ import annotations

import copy
from typing import Callable, NamedTuple, Protocol

import mujoco
import numpy as np

from mwbx import scene as scene_lib

from mwbx.bank.versions import parked_columns
from mwbx.batch_sim import free_bodies, mujoco_c
from mwbx.errors import MwbxError
from mwbx.refinement import stored_motion
from mwbx.refinement import loop as refine_loop
from mwbx.refinement import compiled_refinement


class LoopExtras(NamedTuple):
  """A backend's own inputs of :class:`~mwbx.refinement.loop.RefineInputs`."""

  step_targets: np.ndarray | None
  models: stored_motion.ContactFreeModels | None
  free_bodies: free_bodies.FreeBodies | None


class RefineRunner(Protocol):
  """The refinement entry points of one backend."""

  def check(self, model: mujoco.MjModel, removed: tuple[str, ...], gone: tuple[str, ...]) -> None:
    """Raises MwbxError if this backend cannot refine with objects ``removed``
    at t_min or ``gone`` before it."""

  def loop_extras(self, scene, path: stored_motion.StoredPath, parked: tuple[str, ...]) -> LoopExtras:
    """The loop inputs of this backend for the parent's stored ``path``;
    ``parked``: objects removed or gone, colliding with nothing."""

  def run(self, inp: refine_loop.RefineInputs,
          progress: Callable[[int, int], None] | None = None) -> refine_loop.RefineOutput:
    """Runs one lockstep batch of refined worlds."""


class NativeRunner:
  """The native backend: ``playback="step"`` runs each world in compiled calls
  (``compiled``) or the batch through ``mujoco.rollout`` a step at a time;
  ``"frame"`` puts inactive objects on their path at frame boundaries only."""

  def __init__(self, backend, steps_per_frame: int, playback: str, compiled: bool):
    self.backend, self.steps_per_frame = backend, steps_per_frame
    self.playback, self.compiled = playback, compiled

  def check(self, model, removed, gone) -> None:
    pass  # a removed object collides with nothing in the rollout models

  def loop_extras(self, scene, path, parked) -> LoopExtras:
    model = scene.model
    targets = (stored_motion.step_targets(model, path, self.steps_per_frame, model.opt.timestep)
               if self.playback == "step" else None)
    # Free bodies are observed from their states, so the rollout models (and
    # their contact-free copies) step with sensors disabled.
    bodies = free_bodies.free_bodies(model, scene.body_ids)
    # The compiled loop keeps MjData from step to step, so inactive objects can sleep there.
    sleep_inactive = self.playback == "step" and self.compiled and mujoco_c.can_put_to_sleep()
    models = stored_motion.ContactFreeModels(
        removal_model(model if bodies is None else self.backend.quiet_model, parked), tuple(scene.object_names),
        sleep_inactive=sleep_inactive)
    return LoopExtras(targets, models, bodies)

  def run(self, inp, progress=None):
    if self.playback == "step" and self.compiled:
      return compiled_refinement.run_compiled(self.backend, inp, progress=progress)
    return refine_loop.run_native(self.backend, inp, progress=progress, every_step=self.playback == "step")


class MjxRunner:
  """The MJX backend: inactive objects go on their path every step, inside
  the jitted scan."""

  def __init__(self, backend, steps_per_frame: int, playback: str, compiled: bool):
    del playback, compiled  # MJX plays back every step, in its own loop
    self.backend, self.steps_per_frame = backend, steps_per_frame

  def check(self, model, removed, gone) -> None:
    if removed or any(not parked_columns(model, [o]).any() for o in gone):
      raise MwbxError("refine: the MJX backend cannot keep removed objects out of contact yet;"
                      " use backend='native'")

  def loop_extras(self, scene, path, parked) -> LoopExtras:
    model = scene.model
    return LoopExtras(stored_motion.step_targets(model, path, self.steps_per_frame, model.opt.timestep), None, None)

  def run(self, inp, progress=None):
    return refine_loop.run_mjx(self.backend, inp, progress=progress)


_RUNNERS = {"native": NativeRunner, "mjx": MjxRunner}


def runner_for(sampler, playback: str = "step", compiled: bool = True) -> RefineRunner:
  """The refinement entry points of ``sampler``'s backend."""
  return _RUNNERS[sampler.backend_name](sampler.backend, sampler.params.steps_per_frame, playback, compiled)


def removal_model(model: mujoco.MjModel, removed) -> mujoco.MjModel:
  """``model`` with the ``removed`` objects colliding with nothing and
  weightless (gravity compensated), so parked they stay put."""
  if not removed:
    return model
  out = copy.copy(model)  # mj_copyModel
  objects = scene_lib.find_objects(model, "refine")  # a flex's vertex bodies, or a root body's tree
  bodies = np.isin(np.arange(model.nbody), [b for name in removed for b in objects[name]])
  geoms = bodies[model.geom_bodyid]
  out.geom_contype[geoms] = 0
  out.geom_conaffinity[geoms] = 0
  out.body_gravcomp[bodies] = 1.0
  return out
