"""The backend protocol and how ``backend: auto`` picks one.

A backend steps a batch of worlds of one scene, applying a wrench at each
tracked body's centre of mass, and reports the tracked bodies' sensor block
(see :data:`mwbx.scene.SENSORS`). The sampling loops live with each backend
(``mjx_backend.run_chunk`` as one jitted scan per block of frames in lockstep,
``native_backend.run_chunk`` as one compiled call per world on a thread per
core, :mod:`compiled_world`); both return a :class:`ChunkResult`, which
:func:`mwbx.batch_sim.rows.rows_from_chunks` turns into bank rows.
Refinement's entry points into each backend are in
:mod:`mwbx.refinement.runners` (refinement sits above batch_sim).
"""

from __future__ import annotations

import importlib.util
from typing import Callable, NamedTuple, Protocol, runtime_checkable

import jax
import numpy as np

from mwbx.errors import MwbxError


class ChunkResult(NamedTuple):
  """What one lockstep batch of C worlds produced (host arrays).

  Attributes:
    qpos: f32[C, F, nq] frames at the record rate; rows past ``frame_count``
      repeat the last recorded frame.
    com: f32[C, F, B, 3] tracked COM positions at the record rate, m.
    frame_count: i32[C] frames recorded.
    status: i32[C] world.RUNNING / AT_REST / END_TIME / UNSTABLE / SIM_ERROR.
    metrics: f32[C, B, M] per-body metric table.
    perturbations: i32[C] perturbations applied.
    steps: i32[C] physics steps taken.
    compile_seconds: time spent compiling, s.
    run_seconds: time spent stepping (excluding compilation), s.
    physics_seconds: of which inside the physics engine (native backend; NaN
      where physics and bookkeeping run fused, as on mjx), s.
    errors: (chunk row, MuJoCo's message) of each world stopped by a MuJoCo
      error (status ``world.SIM_ERROR``).
    contact_overflow: bool[C] a step of the world may have needed more
      contacts than the batched engine's budget (None: the backend has none).
    event_rows, event_strength, event_count: the contact episodes found at
      every physics step (:mod:`mwbx.events.steps`): i32[C, cap, 4] rows
      ``(a, b, first, last)`` in steps, f32[C, cap, 2] their strength, i64[C]
      how many (more than cap: overflowed); None where the engine did not
      report its steps' contacts (events are then found on the stored frames).
    tree_frames: i64[C, 2] per world, summed over the frames it stepped: the
      kinematic trees asleep at the frame's end (MuJoCo skipped their physics)
      and the model's trees; None where the engine did not sleep.
  """

  qpos: np.ndarray
  com: np.ndarray
  frame_count: np.ndarray
  status: np.ndarray
  metrics: np.ndarray
  perturbations: np.ndarray
  steps: np.ndarray
  compile_seconds: float
  run_seconds: float
  physics_seconds: float = float("nan")
  errors: tuple = ()
  contact_overflow: np.ndarray | None = None
  event_rows: np.ndarray | None = None
  event_strength: np.ndarray | None = None
  event_count: np.ndarray | None = None
  tree_frames: np.ndarray | None = None

  def first(self, n: int) -> ChunkResult:
    """The result of the first ``n`` worlds (a padded chunk without its padding)."""
    return ChunkResult(*(x[:n] if isinstance(x, np.ndarray) else x for x in self))


class FinishedWorlds(NamedTuple):
  """Worlds of a chunk that finished while others still run, handed over
  before the chunk ends (they can be compressed meanwhile).

  Attributes:
    rows: i64[k] their chunk rows.
    qpos: f32[k, F, nq] their frames (past ``frame_count`` undefined).
    frame_count: i32[k] frames recorded.
  """

  rows: np.ndarray
  qpos: np.ndarray
  frame_count: np.ndarray


@runtime_checkable
class Backend(Protocol):
  """What the sampler needs of a backend (``NativeBackend``, ``MjxBackend``).

  A backend is bound to one ``MjModel`` (with the observation sensors) and
  owns whatever it compiled or started for it (threads, jitted blocks).
  """

  model: object

  def run_chunk(self, scene, params, qpos0: np.ndarray, qvel0: np.ndarray, step_keys: jax.Array,
                active: np.ndarray, n_frames: int,
                progress: Callable[[int, int], None] | None = None,
                finished: Callable[[FinishedWorlds], None] | None = None) -> ChunkResult:
    """Runs C worlds from their initial states until every one has finished.

    Args:
      scene: the :class:`mwbx.scene.Scene`.
      params: bookkeeping constants (:class:`mwbx.batch_sim.world.WorldParams`).
      qpos0: f32[C, nq]; qvel0: f32[C, nv] initial states.
      step_keys: key[C] per-world step key roots.
      active: bool[C] false for padding slots.
      n_frames: frames per world at most (end_frame + 1).
      progress: optional callback(world_steps, worlds_finished) within the chunk.
      finished: optional callback given batches of worlds that have finished
        while the chunk still runs, one call at a time from a thread of the
        backend's (a backend that steps in lockstep never calls it); the
        result holds every world all the same.
    """

  def close(self) -> None:
    """Releases threads and buffers; the backend is unusable afterwards."""


def resolve_backend(name: str) -> str:
  """``auto`` → ``mjx`` on a GPU/TPU, ``native`` on CPU."""
  if name == "auto":
    return "mjx" if jax.default_backend() in ("gpu", "cuda", "rocm", "tpu") else "native"
  if name not in ("mjx", "native"):
    raise MwbxError(f"backend: unknown backend {name!r} (use auto, mjx or native)")
  return name


def resolve_mjx_impl(name: str) -> str:
  """``auto`` → ``warp`` when MuJoCo Warp imports and a GPU is present, else ``jax``."""
  if name == "warp" and importlib.util.find_spec("warp") is None:
    raise MwbxError("sim.mjx_impl: warp needs the warp-lang package (pip install -e '.[gpu]',"
                    " or pip install warp-lang)")
  if name != "auto":
    return name
  if jax.default_backend() not in ("gpu", "cuda"):
    return "jax"
  # MuJoCo Warp ships inside mujoco-mjx; it needs the warp-lang package.
  return "warp" if importlib.util.find_spec("warp") is not None else "jax"


def fill_tail(frames: np.ndarray, frame_count: np.ndarray) -> np.ndarray:
  """Repeats each world's last recorded frame over the unrecorded tail (in place).

  Args:
    frames: [C, F, ...] frame buffers.
    frame_count: i32[C].
  """
  for w, n in enumerate(frame_count):
    if 0 < n < frames.shape[1]:
      frames[w, n:] = frames[w, n - 1]
  return frames
