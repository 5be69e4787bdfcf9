"""The sampling loop: worlds in chunks (batches), recorded into a bank.

World ``i`` of a run draws all its randomness from ``fold_in(run_key, i)``:
its initial state from one half of that key, the perturbation of step ``k``
from ``fold_in(other half, k)``. So a world does not depend on the batch size,
the chunking or the order worlds run in.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import bank as bank_lib
from mwbx import rates as rates_lib
from mwbx.bank.stores import store_for
from mwbx.batch_sim import engine_probe, memory, world
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.batch_sim import rows as rows_lib
from mwbx.batch_sim.backend import ChunkResult, FinishedWorlds, resolve_backend, resolve_mjx_impl
from mwbx.batch_sim.native_backend import NativeBackend, exact_pose
from mwbx.config import Config, MjxSection
from mwbx import events as events_lib
from mwbx.errors import MwbxError
from mwbx.events import EventRecord
from mwbx.host_device import host_cpu
from mwbx.progress import Progress, ProgressFn
from mwbx.qpos_store import QposStore, RawQposStore
from mwbx.scene import Scene


@dataclasses.dataclass
class SampleStats:
  """Timing of a sampling run (compile time kept apart from run time).

  Attributes:
    backend: backend used (``native``, ``mjx:jax``, ``mjx:warp``).
    world_steps: physics steps summed over worlds.
    run_seconds: stepping time, s.
    compile_seconds: compilation time, s.
    codec_seconds: compressing recorded qpos, s (on the native backend most of it
      while other worlds still step: :class:`_ChunkStore`).
    events_seconds: finding the contact events in the stored worlds, s.
    physics_seconds: inside the physics engine (native backend; NaN on mjx), s.
    wall_seconds: everything, s.
    sim_errors: (world id, MuJoCo's message) of each world a MuJoCo error
      stopped (flagged ``FLAG_SIM_ERROR``; the run went on).
    asleep_tree_frames, tree_frames: summed over the frames the worlds
      stepped, the kinematic trees asleep at a frame's end (MuJoCo skipped
      their physics) and all of them (0 where the engine did not sleep).
  """

  backend: str = ""
  world_steps: int = 0
  run_seconds: float = 0.0
  compile_seconds: float = 0.0
  codec_seconds: float = 0.0
  events_seconds: float = 0.0
  physics_seconds: float = 0.0
  wall_seconds: float = 0.0
  sim_errors: list = dataclasses.field(default_factory=list)
  asleep_tree_frames: int = 0
  tree_frames: int = 0

  @property
  def asleep_share(self) -> float | None:
    """The share of tree-frames asleep (None where none were counted)."""
    return self.asleep_tree_frames / self.tree_frames if self.tree_frames else None

  @property
  def world_steps_per_second(self) -> float:
    return self.world_steps / self.run_seconds if self.run_seconds > 0 else 0.0


# World ids a sampled world may have: fold_in(run_key, id) reads 32 bits.
MAX_WORLD_ID = (1 << 32) - 1
# Physics steps a world may take (counted in int32 in the bank).
MAX_STEPS = 1 << 31


def frame_rates(config: Config, timestep: float) -> tuple[int, int, int]:
  """(steps per frame, frames per query point, last frame index), validated.

  The rates the config leaves unset are chosen from ``timestep``
  (:func:`mwbx.rates.resolve`); values it sets that contradict each other
  are an error naming both.
  """
  chosen = rates_lib.resolve(config, timestep)
  end_frame = int(round(config.sim.end_time * chosen.record_fps))
  steps = end_frame * chosen.steps_per_frame
  if steps >= MAX_STEPS:  # steps are counted in int32
    raise MwbxError(f"{config.source or '<config>'}: sim.end_time: {config.sim.end_time:g} s is {steps:.3g}"
                    f" physics steps; at most {MAX_STEPS - 1:,} (try a shorter end_time)")
  return chosen.steps_per_frame, chosen.query_stride, end_frame


def world_keys(key: jax.Array, world_ids: np.ndarray) -> tuple[jax.Array, jax.Array, jax.Array]:
  """(world keys, init keys, step key roots), each key[W], from the run key.

  Raises:
    MwbxError: an id outside ``0 … MAX_WORLD_ID``: ``fold_in`` takes 32 bits,
      so id 2³² would draw the key of id 0.
  """
  world_ids = np.asarray(world_ids)
  if world_ids.size and (world_ids.min() < 0 or world_ids.max() > MAX_WORLD_ID):
    bad = world_ids[(world_ids < 0) | (world_ids > MAX_WORLD_ID)][0]
    raise MwbxError(f"world id {int(bad)}: sampled world ids must be in 0..{MAX_WORLD_ID:,} (a world's key"
                    f" folds its id in as 32 bits)")
  if not jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
    key = jax.random.wrap_key_data(jnp.asarray(key, jnp.uint32))
  keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.asarray(world_ids, jnp.uint32))
  split = jax.vmap(jax.random.split)(keys)
  return keys, split[:, 0], split[:, 1]


def per_world(fn):
  """``fn`` of one world, applied to a batch so that each world's result does
  not depend on the batch: ``xs[W, ...] -> fn(xs[i])`` stacked.

  lax.map, not vmap: XLA vectorizes a vmapped batch and rounds the worlds of
  a partial SIMD vector differently (one world in 30 of a crate pile moved by
  an ulp with the batch size, and its metrics with it); a scan runs one
  world's program for every world. A batch of one runs as two: XLA inlines a
  one-trip loop and compiles that differently again. It runs on the host's
  CPU (:func:`mwbx.host_device.host_cpu`): a world's initial state is then
  the same on a GPU machine as on any other.
  """
  mapped = jax.jit(lambda xs: jax.lax.map(fn, xs))

  def call(xs):
    with jax.default_device(host_cpu()):
      if len(xs) != 1:
        return mapped(xs)
      return jax.tree_util.tree_map(lambda x: x[:1], mapped(xs[np.zeros(2, np.int64)]))

  return call


class Sampler:
  """A scene bound to a backend, reusable across runs (compiled once).

  Args:
    scene: the loaded scene (or a config, loaded here).
    backend: ``auto``, ``mjx`` or ``native`` (default: the config's). ``auto``
      where JAX sees a GPU: the engine a short timed probe finds fastest
      (:mod:`mwbx.batch_sim.engine_probe`, after the contact-budget pilot;
      never one slower than native), kept in ``probe``; otherwise ``mjx`` on a
      TPU, ``native`` on CPUs, without probing.
    chunk_size: worlds per chunk, simulated and compressed together (default: the
      config's).
    store: an empty :class:`~mwbx.qpos_store.QposStore` the runs' stores are made
      like (``store.empty()``); default: compressed under the config's ``codec``
      bounds. ``mwbx.qpos_store.RawQposStore(nq)`` keeps float32 frames.
    contact_budget: MJX: the :class:`~mwbx.batch_sim.contact_budget.ContactBudget`
      (or its dict, as a bank's ``run`` stores it) to use; default: the
      config's ``sim.mjx`` values, the rest sized by a native pilot.
    warp_solver: mjx:warp: the
      :class:`~mwbx.batch_sim.warp_solver.WarpSolverSettings` (or its dict, as
      a bank's ``run`` stores it) to use; default: chosen from the model and
      the config's ``sim.mjx`` (:func:`~mwbx.batch_sim.warp_solver.warp_solver_settings`).
    sleep: native and mjx:warp: the :class:`~mwbx.batch_sim.sleep.SleepSettings` (or its
      dict, as a bank's ``run`` stores it) to step with; default: resolved
      from the config's ``sim.sleep`` (:func:`~mwbx.batch_sim.sleep.resolve`).
  """

  def __init__(self, scene: Scene | Config, backend: str | None = None, chunk_size: int | None = None,
               store: QposStore | None = None, contact_budget=None, warp_solver=None, sleep=None):
    self.scene = scene if isinstance(scene, Scene) else Scene(scene)
    self.store = store if store is not None else store_for(self.scene)
    cfg = self.scene.config
    requested, impl = backend or cfg.sim.backend, None
    self.probe = None  # backend auto with a GPU visible: the engine_probe.ProbeResult
    if requested == "auto" and engine_probe.gpu_visible():
      contact_budget = self._budget(contact_budget)  # the pilot first: the MJX engines run under it
      self.probe = engine_probe.probe_scene(Sampler, self.scene, contact_budget, warp_solver)
      requested, _, impl = self.probe.choice.partition(":")
      if self.probe.choice == engine_probe.WARP_SLEEP:  # mjx:warp, measured faster with sleep on
        impl = "warp"
        sleep = sleep or sleep_lib.resolve(self.scene.model, True, cfg.sim.sleep_tolerance)._replace(
            reason=f"backend auto: the engine probe chose {engine_probe.WARP_SLEEP}")
    self.backend_name = resolve_backend(requested)
    self.chunk_size = int(chunk_size or cfg.sim.chunk_size)
    if self.chunk_size < 1:
      raise MwbxError(f"chunk_size: must be a positive number of worlds, got {self.chunk_size}")
    model = self.scene.model  # its timestep is the config's (Scene sets it; the sampler changes nothing)
    spf, self.query_stride, end_frame = frame_rates(cfg, model.opt.timestep)
    self.n_frames = end_frame + 1
    self.params = world.world_params(self.scene, spf, end_frame)
    self.contact_budget = None
    self.sleep = None  # native and mjx:warp: the SleepSettings it steps with
    self.warp_solver = None  # mjx:warp: the WarpSolverSettings it runs with
    self.pack_rows = False  # MJX jax: each world's solve over its rows in use (sim.mjx.pack_rows)
    if self.backend_name == "mjx":
      # Lazy on purpose: imports mujoco.mjx (seconds), which native runs never need.
      from mwbx.batch_sim.mjx_backend import backend_for
      impl = impl or resolve_mjx_impl(cfg.sim.mjx_impl)
      if impl == "warp":  # MuJoCo Warp sleeps too (under Newton); MJX's jax step does not
        self.sleep = self._sleep(sleep, model, sleep_lib.resolve_warp)
      # A contact episode ends after a query point's steps apart: see mwbx.events.steps.
      self.backend = backend_for(self.scene, impl, self._budget(contact_budget), pack_rows=cfg.sim.mjx.pack_rows,
                                 warp_solver=warp_solver, sleep=self.sleep, event_gap=spf * self.query_stride)
      self.pack_rows = self.backend.pack_rows
      self.contact_budget = self.backend.budget
      self.warp_solver = self.backend.warp_solver
      self.backend_label = f"mjx:{impl}" + (" (every row)" if impl == "jax" and not self.pack_rows else "")
    else:
      self.sleep = self._sleep(sleep, model, sleep_lib.resolve)
      # A contact episode ends after a query point's steps apart: see mwbx.events.steps.
      self.backend = NativeBackend(sleep_lib.sleeping_copy(model, self.sleep), cfg.sim.threads,
                                   event_gap=spf * self.query_stride)
      self.backend_label = "native"
    self.event_actors = events_lib.actors_of(self.scene.model, self.scene.object_names)
    self._init = per_world(self.scene.initial_state)
    self._init_from_noise = per_world(self.scene.initial_state_from_noise)

  def _sleep(self, given, model, resolve) -> sleep_lib.SleepSettings:
    """The sleep settings: ``given`` (SleepSettings or a run record's dict),
    else the config's under ``resolve`` (the engine's rule)."""
    if isinstance(given, dict):
      return sleep_lib.SleepSettings.from_record(given)
    cfg = self.scene.config
    return given or resolve(model, cfg.sim.sleep, cfg.sim.sleep_tolerance)

  def _budget(self, given):
    """The MJX contact budget: ``given`` (a ContactBudget or its dict), else
    the config's values with the rest from a native pilot."""
    from mwbx.batch_sim import contact_budget as budget_lib  # lazy: imports mujoco.mjx
    if isinstance(given, dict):
      return budget_lib.ContactBudget.from_dict(given)
    return given if given is not None else resolve_contact_budget(self.scene, self.scene.config.sim.mjx)

  def close(self) -> None:
    self.backend.close()

  def __enter__(self):
    return self

  def __exit__(self, *exc):
    self.close()

  def run(self, n_worlds: int, key: jax.Array, *, first_world: int = 0, ids=None,
          store: QposStore | None = None, noise=None,
          progress: ProgressFn | None = None) -> tuple[bank_lib.Bank, SampleStats]:
    """Samples worlds ``first_world … first_world + n_worlds - 1`` (or ``ids``).

    Args:
      n_worlds: how many worlds.
      key: the run key (``jax.random.key(seed)``).
      first_world: id of the first world (to continue an existing bank).
      ids: i64[n_worlds] world ids to sample instead (any order is kept; a
        world depends only on ``key`` and its id), e.g. the ones a killed run
        did not finish.
      store: how this run keeps qpos (default: the sampler's ``store``).
      noise: f32[n_worlds, D] each world's unit noise (``scene.noise_slots``;
        e.g. from a guided proposal, :mod:`mwbx.search`) instead of the draws
        of its key; perturbations still come from the key.
      progress: optional callback taking a :class:`mwbx.progress.Progress`
        (``simulating`` / ``compressing``; e.g. :class:`mwbx.progress.reporter`).

    Returns:
      (the bank of these worlds, timing stats).
    """
    self.check_memory(n_worlds, in_memory=True)
    parts = []
    for part, stats in self.run_chunks(n_worlds, key, first_world=first_world, ids=ids, store=store,
                                       noise=noise, progress=progress):
      parts.append(part)
    return bank_lib.Bank.concatenate(parts), stats

  def batch_size(self, n_worlds: int) -> int:
    """Worlds simulated per batch for a run of ``n_worlds``.

    Sized to the work: no more than the run needs (a run of 8 worlds
    simulates 8). Native: at most ``chunk_size``. MJX: ``chunk_size`` is per
    device, a device's share is rounded up to a whole ``mjx_backend.LANE``
    (padding with finished copies), and every device runs the same compiled
    block on its share: a world is bit-identical across runs with the same
    per-device batch, on any number of devices. Across per-device batch
    shapes XLA may round differently in the last bit (contacts then amplify
    it; tests/batch_sim/test_mjx.py states the agreement).
    """
    if self.backend_name != "mjx":
      return min(self.chunk_size, n_worlds)
    n_dev, lane = len(self.backend.devices), self.backend.lane
    per_device = min(self.chunk_size, -(-n_worlds // n_dev))
    return -(-per_device // lane) * lane * n_dev

  def run_chunks(self, n_worlds: int, key: jax.Array, *, first_world: int = 0, ids=None,
                 store: QposStore | None = None, noise=None, progress: ProgressFn | None = None):
    """:meth:`run` one chunk at a time, for writing each as it finishes.

    Yields:
      (the bank of one chunk of worlds, the run's stats so far).
    """
    ids = (np.arange(first_world, first_world + n_worlds, dtype=np.int64) if ids is None
           else np.asarray(ids, np.int64).reshape(-1))
    if ids.size < 1 or (ids.size != n_worlds):
      raise MwbxError(f"n_worlds: must be at least 1 and match the ids given, got {n_worlds}"
                      f" ({ids.size} ids)")
    if noise is not None:
      noise = np.asarray(noise, np.float32)
      width = sum(slot.width for slot in self.scene.noise_slots)
      if noise.shape != (n_worlds, width) or not np.all(np.isfinite(noise)):
        raise MwbxError(f"noise: expected finite f32[{n_worlds}, {width}] unit noise (one row per world),"
                        f" got shape {noise.shape}")
    start_wall = time.perf_counter()
    stats = SampleStats(backend=self.backend_label)
    keys, init_keys, step_keys = world_keys(key, ids)
    template = self.store if store is None else store
    c = self.batch_size(n_worlds)
    self.check_memory(n_worlds)
    done_worlds = 0
    for lo in range(0, n_worlds, c):
      n = min(c, n_worlds - lo)
      # Pad the last chunk to the batch shape: one compiled program per run,
      # and the same per-world arithmetic whatever the batch holds.
      pad = np.concatenate([np.arange(lo, lo + n), np.full(c - n, lo)])
      active = np.arange(c) < n
      if noise is None:
        qpos0, qvel0 = self._init(init_keys[pad])
      else:
        qpos0, qvel0 = self._init_from_noise(noise[pad])
      base_steps = stats.world_steps

      def report(world_steps, finished, _base=base_steps, _done=done_worlds):
        if progress is not None:
          progress(Progress("simulating", _done + finished, n_worlds, _base + world_steps))

      # Compress as worlds are produced (those that finish early while the others
      # still step): raw qpos never outlives its chunk.
      chunk_store = _ChunkStore(template, n)
      result = self.backend.run_chunk(
          self.scene, self.params, np.asarray(qpos0), np.asarray(qvel0), step_keys[pad],
          active, self.n_frames, progress=report, finished=chunk_store.add)
      result = result.first(n)
      stats.sim_errors.extend((int(ids[lo + row]), message) for row, message in result.errors)
      chunk_steps = base_steps + int(result.steps.sum())
      if progress is not None:
        progress(Progress("compressing", done_worlds, n_worlds, chunk_steps))
      store, result = chunk_store.finish(result)
      stats.codec_seconds += chunk_store.seconds
      if progress is not None:
        progress(Progress("compressing", done_worlds + n, n_worlds, chunk_steps))
      events_start = time.perf_counter()
      events = self.chunk_events(result, store, progress=progress and (
          lambda p, _done=done_worlds, _steps=chunk_steps: progress(p._replace(
              done=_done + p.done, total=n_worlds, world_steps=_steps))))
      stats.events_seconds += time.perf_counter() - events_start
      stats.world_steps += int(result.steps.sum())
      stats.run_seconds += result.run_seconds
      stats.compile_seconds += result.compile_seconds
      stats.physics_seconds += result.physics_seconds
      if result.tree_frames is not None:
        stats.asleep_tree_frames += int(result.tree_frames[:, 0].sum())
        stats.tree_frames += int(result.tree_frames[:, 1].sum())
      done_worlds += n
      part = self._assemble(ids[lo:lo + n], keys[lo:lo + n], [result], store, events)
      stats.wall_seconds = time.perf_counter() - start_wall
      yield part, stats

  def check_memory(self, n_worlds: int, in_memory: bool = False) -> None:
    """Refuses a run of ``n_worlds`` whose estimated host memory (:mod:`memory`)
    does not fit, with the figure.

    Args:
      n_worlds: worlds of the run.
      in_memory: the run's worlds are kept in one bank in memory
        (:meth:`run`), not written chunk by chunk (:meth:`run_chunks`).

    Raises:
      MwbxError: naming the chunk size, frames, sim.end_time and the figures.
    """
    n_worlds = max(int(n_worlds), 1)
    check_chunk_memory(self.scene, self.batch_size(n_worlds), n_worlds if in_memory else 0)

  def chunk_events(self, result: ChunkResult, store: QposStore, progress=None) -> EventRecord:
    """The contact events of a chunk's worlds: as the engine found them at
    every physics step (:mod:`mwbx.events.steps`), or, for worlds whose
    engine did not report its steps' contacts or whose episodes overflowed
    their buffer, on their stored frames (:meth:`events_of`)."""
    if result.event_count is None:
      return self.events_of(store, progress=progress)
    count, cap = np.asarray(result.event_count), result.event_rows.shape[1]
    rows = [result.event_rows[w, :n] for w, n in enumerate(count.tolist())]
    strengths = [result.event_strength[w, :n] for w, n in enumerate(count.tolist())]
    over = np.flatnonzero(count > cap)
    if over.size:
      found = self.events_of_frames(store.frames_of_rows(over))
      for i, w in enumerate(over.tolist()):
        rows[w], strengths[w] = found.world(i), found.strength[found.offsets[i]:found.offsets[i + 1]]
    return EventRecord.from_worlds(rows, strengths, ticks_per_frame=self.params.steps_per_frame)

  def events_of(self, store: QposStore, progress=None) -> EventRecord:
    """The contact events of stored worlds found on their stored frames
    (:mod:`mwbx.events.detect`), in physics steps (a frame's resolution).

    Args:
      store: their stored qpos.
      progress: optional callback (phase ``contact events``).
    """
    return self.events_of_frames(store.frames_of_rows(None), progress=progress)

  def events_of_frames(self, frames, first_frame=0, progress=None, active=None) -> EventRecord:
    """The contact events of worlds' stored frames (each f32[T, nq], from
    ``first_frame``: one for all or one per world), in physics steps;
    ``active``: optional bool[W, n_actors], pairs to test
    (:func:`mwbx.events.detect.detect_events`)."""
    return events_lib.detect_events(self.scene.model, self.event_actors, frames,
                                    events_lib.touch_margin(self.scene.config.codec.e_pos),
                                    progress=progress, total=len(frames), first_frame=first_frame,
                                    active=active).in_ticks(self.params.steps_per_frame)

  def _assemble(self, ids, keys, results: list[ChunkResult], store, events: EventRecord) -> bank_lib.Bank:
    scene = self.scene
    rows = rows_lib.rows_from_chunks(results, self.query_stride, scene.config.codec.com_step())
    cfg = scene.config
    return bank_lib.Bank(
        world_ids=ids, keys=np.asarray(jax.random.key_data(keys)), **rows._asdict(),
        parent_world=np.full(len(ids), -1, np.int64), refine_time=np.full(len(ids), np.nan, np.float32),
        qpos_store=store, body_names=scene.body_names, body_ids=scene.body_ids,
        objects=dict(scene.objects), groups=dict(scene.groups), metric_names=world.METRIC_NAMES,
        record_fps=cfg.sim.record_fps, query_fps=cfg.sim.query_fps, timestep=float(scene.model.opt.timestep),
        config=cfg.resolved(), mjcf_text=scene.mjcf_text, mjcf_includes=dict(scene.mjcf_includes),
        mjcf_assets=dict(scene.mjcf_assets),
        digest=scene.digest,
        run=self.run_record(), events=events, event_actors=self.event_actors.names,
    )

  def run_record(self) -> dict:
    """What a bank's ``run`` keeps of this sampler's engine settings so that
    refinement replays them: the MJX contact budget and mjx:warp's solver
    settings, the native engine's sleep settings (each only where used)."""
    run = {}
    if self.contact_budget is not None:
      run["contact_budget"] = self.contact_budget._asdict()
    if self.warp_solver is not None:
      run["warp_solver"] = self.warp_solver._asdict()
    if self.sleep is not None:
      run["sleep"] = self.sleep.as_record()
    return run


def check_chunk_memory(scene: Scene, batch: int, n_in_memory: int = 0) -> None:
  """Refuses a chunk of ``batch`` worlds (and a bank of ``n_in_memory`` worlds
  kept in memory) whose estimated host memory (:mod:`memory`) does not fit,
  with the figure; needs no sampler, so a command can check before it writes
  anything (:meth:`Sampler.check_memory` checks with its own batch).

  Raises:
    MwbxError: naming the chunk size, frames, sim.end_time and the figures.
  """
  m, cfg = scene.model, scene.config
  timestep = cfg.sim.timestep if cfg.sim.timestep is not None else m.opt.timestep
  spf, query_stride, end_frame = frame_rates(cfg, timestep)
  n_frames = end_frame + 1
  needed = memory.chunk_bytes(
      batch, n_frames, m.nq, len(scene.body_names), query_stride, nbody=m.nbody,
      nstate=mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS), nsensordata=m.nsensordata,
      steps_per_frame=spf)
  what = (f"a chunk of {batch:,} worlds of {n_frames:,} frames each (sim.end_time {cfg.sim.end_time:g} s at"
          f" sim.record_fps {cfg.sim.record_fps:g})")
  advice = "lower sim.end_time or the chunk size (sim.chunk_size, --chunk-size)"
  if n_in_memory:
    needed += n_in_memory * memory.stored_bytes_per_world(n_frames, len(scene.body_names), query_stride,
                                                          len(world.METRIC_NAMES))
    what = f"a bank of {n_in_memory:,} worlds in memory and {what}"
    advice = f"sample fewer worlds per call, or {advice}"
  memory.check(needed, what, advice)


class _ChunkStore:
  """The stored qpos of one chunk's first ``n`` worlds, compressed a batch at
  a time as the worlds finish (:meth:`add`, on the backend's thread, while
  other worlds still step), the rest once the chunk is done; in row order.

  Last guard of the promise that no NaN enters the bank: a world with a
  non-finite recorded frame is cut before it and flagged unstable. A world's
  stream does not depend on the batch it was compressed in.
  """

  def __init__(self, template: QposStore, n: int):
    self.template, self.n = template, n
    self.parts: list = []  # (rows i64[k], store, frames kept i32[k]) in the order compressed
    self.seconds = 0.0  # spent compressing

  def add(self, worlds: FinishedWorlds) -> None:
    """Compresses finished worlds (padding rows past ``n`` are dropped)."""
    keep = worlds.rows < self.n
    if not keep.any():
      return
    start = time.perf_counter()
    qpos, counts = worlds.qpos[keep], np.asarray(worlds.frame_count[keep]).astype(np.int32)
    bad = ~np.isfinite(qpos).all(axis=-1) & (np.arange(qpos.shape[1]) < counts[:, None])  # [k, T]
    cut = bad.any(axis=1)
    counts[cut] = np.argmax(bad[cut], axis=1)
    store = self.template.empty()
    store.append(qpos, counts)
    self.parts.append((worlds.rows[keep], store, counts))
    self.seconds += time.perf_counter() - start

  def finish(self, result: ChunkResult) -> tuple[QposStore, ChunkResult]:
    """(the chunk's store, the chunk without its qpos, frames cut and worlds
    flagged where a frame was not finite): compresses the worlds not added yet."""
    done = np.zeros(self.n, bool)
    for rows, _, _ in self.parts:
      done[rows] = True
    rest = np.flatnonzero(~done)
    if rest.size:
      self.add(FinishedWorlds(rest, result.qpos[rest], result.frame_count[rest]))
    rows = np.concatenate([part[0] for part in self.parts])
    store = self.parts[0][1]
    store.extend(*[part for _, part, _ in self.parts[1:]])
    if np.any(np.diff(rows) < 0):
      store = store.take(np.argsort(rows, kind="stable"))
    counts = np.asarray(result.frame_count).astype(np.int32).copy()
    counts[rows] = np.concatenate([part[2] for part in self.parts])
    status = np.asarray(result.status).copy()
    status[counts < result.frame_count] = world.UNSTABLE
    return store, result._replace(qpos=None, frame_count=counts, status=status)


def sample(scene: Scene | Config, n_worlds: int, key: jax.Array, *, backend: str | None = None,
           chunk_size: int | None = None, first_world: int = 0, store: QposStore | None = None,
           progress=None) -> bank_lib.Bank:
  """Samples ``n_worlds`` plausible worlds of a scene into a :class:`~mwbx.Bank`.

  Args:
    scene: a :class:`~mwbx.Config` (from :func:`mwbx.load_config`) or a loaded scene.
    n_worlds: number of worlds.
    key: run key, e.g. ``jax.random.key(0)``; world i uses ``fold_in(key, i)``.
    backend: ``auto`` | ``mjx`` | ``native`` (default: the config's ``sim.backend``).
    chunk_size: worlds per chunk (default: ``sim.chunk_size``).
    first_world: id of the first world, to continue a bank.
    store: how qpos is kept (see :class:`Sampler`); default compressed.
    progress: optional callback taking a :class:`mwbx.progress.Progress`.

  Returns:
    the bank. Unstable worlds are kept, flagged, and never contain NaN.

  Example::

    scene = mwbx.load_config("configs/quickstart.yaml")
    bank = mwbx.sample(scene, n_worlds=1024, key=jax.random.key(0))
  """
  with Sampler(scene, backend, chunk_size, store=store) as sampler:
    bank, _ = sampler.run(n_worlds, key, first_world=first_world, progress=progress)
  return bank


def empty_bank(scene: Scene, store: QposStore | None = None) -> bank_lib.Bank:
  """A bank of ``scene`` with no worlds (what a :class:`Sampler` of it would
  write, e.g. to start a bank directory's manifest before its first shard)."""
  cfg = scene.config
  b, m = len(scene.body_names), len(world.METRIC_NAMES)
  timestep = cfg.sim.timestep if cfg.sim.timestep is not None else scene.model.opt.timestep
  empty = lambda dtype, *shape: np.zeros((0, *shape), dtype)
  return bank_lib.Bank(
      world_ids=empty(np.int64), keys=empty(np.uint32, 2), flags=empty(np.uint8),
      frame_count=empty(np.int32), com=empty(np.float32, 1, b, 3), com_count=empty(np.int32),
      metrics=empty(np.float32, b, m), perturbations=empty(np.int32), steps=empty(np.int32),
      parent_world=empty(np.int64), refine_time=empty(np.float32),
      qpos_store=(store if store is not None else store_for(scene)).empty(),
      body_names=scene.body_names, body_ids=scene.body_ids, objects=dict(scene.objects),
      groups=dict(scene.groups), metric_names=world.METRIC_NAMES, record_fps=cfg.sim.record_fps,
      query_fps=cfg.sim.query_fps, timestep=float(timestep), config=cfg.resolved(),
      mjcf_text=scene.mjcf_text, mjcf_includes=dict(scene.mjcf_includes), mjcf_assets=dict(scene.mjcf_assets),
      digest=scene.digest,
      events=EventRecord.empty(0, ticks_per_frame=frame_rates(cfg, timestep)[0]),  # a physics step a tick
      event_actors=events_lib.actors_of(scene.model, scene.object_names).names)


def pilot_counts(scene: Scene, n_worlds: int = 8, seed: int = 0, end_time: float | None = None):
  """Runs ``n_worlds`` worlds of the scene on the native backend and counts,
  over every recorded frame, what MJX's and MuJoCo Warp's caps must hold.

  Args:
    scene: the scene (its config's perturbations, controls and randomization apply).
    n_worlds: pilot worlds (ids 0..n-1 of ``seed``).
    seed: run key seed of the pilot.
    end_time: stop the pilot worlds earlier than the config's end time, s.

  Returns:
    the :class:`~mwbx.batch_sim.contact_budget.PilotCounts`.
  """
  from mwbx.batch_sim import contact_budget as budget_lib  # lazy on purpose: imports mujoco.mjx
  cfg = scene.config
  if end_time is not None:
    cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"end_time": end_time})})
  pilot_scene = Scene(cfg) if end_time is not None else scene
  with Sampler(pilot_scene, backend="native", chunk_size=n_worlds,
               store=RawQposStore(scene.model.nq)) as sampler:
    bank, _ = sampler.run(n_worlds, jax.random.key(seed))
    counts = budget_lib.count_frames(scene, bank)
    if sampler.sleep.enabled:  # MuJoCo Warp's nvmax: the most dofs awake at once
      _, init_keys, _ = world_keys(jax.random.key(seed), np.arange(n_worlds))
      qpos0, qvel0 = (np.asarray(x) for x in sampler._init(init_keys))
      model = sampler.backend.model
      n_steps = (sampler.n_frames - 1) * sampler.params.steps_per_frame
      counts = counts._replace(awake_dofs=budget_lib.awake_dofs(
          model, exact_pose(qpos0, model), qvel0.astype(np.float64), n_steps))
  return counts._replace(dofs=int(scene.model.nv))


def resolve_contact_budget(scene: Scene, settings: MjxSection | None = None):
  """The scene's MJX contact budget: the config's ``sim.mjx`` values, the rest
  from a native pilot (:func:`pilot_counts`) with headroom.

  Args:
    scene: the scene.
    settings: the config's :class:`mwbx.config.MjxSection` (None: defaults).

  Returns:
    the :class:`~mwbx.batch_sim.contact_budget.ContactBudget`.
  """
  from mwbx.batch_sim import contact_budget as budget_lib  # lazy on purpose: imports mujoco.mjx
  settings = settings if settings is not None else MjxSection()
  given = budget_lib.given(settings)
  if all(v is not None for v in given.values()):
    return budget_lib.ContactBudget(source="config", **given)
  counts = pilot_counts(scene, settings.pilot_worlds)
  return budget_lib.budget_from_counts(counts, settings.headroom, given)
