"""The native backend: MuJoCo C on a thread per core. The fast path on CPUs.

Sampling runs each world from start to finish in one compiled call
(:mod:`compiled_world`: ``mj_step`` through MuJoCo's C library, then the
observation, bookkeeping and recording of each frame), a thread per core
pulling worlds from a shared counter, each thread with its own ``MjData``.

Where MuJoCo's C library cannot be bound (:func:`mujoco_c.available`), and for
refinement (:meth:`NativeBackend.step`), worlds advance in lockstep through
``mujoco.rollout``'s thread pool instead: one call per frame (steps_per_frame
physics steps) for every running world, the perturbation wrenches of each step
passed as ``xfrc_applied`` controls, the bookkeeping of the worlds that ran
(:mod:`host_bookkeeping`, compiled) between calls.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from typing import Callable, NamedTuple

import jax
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from mwbx.batch_sim import free_bodies as free_bodies_lib
from mwbx import controls
from mwbx.batch_sim import host_bookkeeping, host_loops, mujoco_c, world, compiled_world
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.batch_sim.backend import ChunkResult, FinishedWorlds, fill_tail
from mwbx.events import actors as events_lib
from mwbx.errors import MwbxError

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
# Worlds of one chunk MuJoCo may raise errors in before the run stops: each
# parks a thread for good (see ``mujoco_c.trap_errors``).
MAX_SIM_ERRORS = 32
_CONTROL = mujoco.mjtState.mjSTATE_XFRC_APPLIED
# With actuator controls: rollout's control vector is ctrl then xfrc_applied
# (mj_getState order: the spec's bits in increasing order).
_CONTROL_CTRL = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED


def exact_pose(qpos: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
  """f64[W, nq] initial qpos: the worlds' f32[W, nq], except that in the
  trees that start asleep (sleep policy ``init``) a value equal to the MJCF's
  pose ``model.qpos0`` rounded to float32 (nothing randomized it) is the
  MJCF's value itself.

  MuJoCo wakes a sleeping tree whose ``qpos`` changed: a tree that starts
  asleep stays asleep only at the very pose it was put to sleep at, and a
  float32 rounding of it is another pose. Other trees keep the rounding
  (their worlds stay those of banks sampled before).
  """
  qpos0 = np.asarray(model.qpos0, np.float64)
  exact = sleep_lib.starts_asleep(model) & (qpos == qpos0.astype(np.float32))
  return np.where(exact, qpos0, qpos.astype(np.float64))


class _Chunk(NamedTuple):
  """Host state of one chunk of C worlds.

  Attributes:
    buffers: the :class:`host_bookkeeping.ChunkBuffers` both sampling loops write.
    free_bodies: :class:`free_bodies.FreeBodies` to observe from the states,
      or None to read MuJoCo's sensors.
    active: bool[C] false for padding slots.
    running: bool[C] worlds that need another frame.
  """

  buffers: host_bookkeeping.ChunkBuffers
  free_bodies: free_bodies_lib.FreeBodies | None
  active: np.ndarray
  running: np.ndarray


class NativeBackend:
  """A persistent rollout thread pool and per-thread ``MjData`` for one model.

  Args:
    model: the scene model (with mwbx sensors).
    threads: pool size; 0 means one per CPU core.
    event_gap: physics steps apart that end a contact episode
      (:mod:`mwbx.events.steps`; the sampler's: a query point's steps).
  """

  def __init__(self, model: mujoco.MjModel, threads: int = 0, event_gap: int = 1):
    self.model = model
    self.threads = threads or os.cpu_count() or 1
    self.pool = mj_rollout.Rollout(nthread=self.threads)
    self.datas = [mujoco.MjData(model) for _ in range(self.threads)]
    self.nstate = mujoco.mj_stateSize(model, _STATE)
    self._models: list = []  # rollout wants one model per world with skip_checks
    self._quiet_model = None
    self._step_events = None
    self.event_gap = int(event_gap)

  @property
  def quiet_model(self) -> mujoco.MjModel:
    """A copy of :attr:`model` that steps with sensors disabled."""
    if self._quiet_model is None:
      self._quiet_model = free_bodies_lib.quiet_copy(self.model)
    return self._quiet_model

  def close(self) -> None:
    self.pool.close()

  def initial_states(self, qpos: np.ndarray, qvel: np.ndarray, act: np.ndarray | None = None) -> np.ndarray:
    """f64[W, nstate] full physics states (time 0) from qpos f32[W, nq], qvel
    f32[W, nv] and, optionally, actuator activations f[W, na]."""
    m = self.model
    data = mujoco.MjData(m)
    states = np.zeros((len(qpos), self.nstate))
    qpos = exact_pose(np.asarray(qpos), m)
    for w in range(len(qpos)):
      mujoco.mj_resetData(m, data)
      data.qpos[:] = qpos[w]
      data.qvel[:] = qvel[w]
      if act is not None:
        data.act[:] = act[w]
      mujoco.mj_getState(m, data, states[w], _STATE)
    return states

  def step(self, states: np.ndarray, wrench: np.ndarray, warmstart: np.ndarray, models: list | None = None,
           *, sensors: bool = True, out: tuple[np.ndarray, np.ndarray] | None = None,
           ctrl: np.ndarray | None = None):
    """The S physics steps of one frame for a batch.

    Args:
      states: f64[n, nstate] full physics states s_k.
      wrench: f64[n, S, nbody * 6] ``xfrc_applied`` during each step.
      warmstart: f64[n, nv] solver warm start.
      models: optional model per world, each a copy of :attr:`model` that
        differs only in values (default: :attr:`model` for all).
      sensors: False steps :attr:`quiet_model` (unless ``models`` are given)
        and returns no sensors.
      out: optional (f64[N, S, nstate], f64[N, S, nsensordata or 0]) buffers,
        N ≥ n, whose first n rows receive the result (no allocation per frame).
      ctrl: optional f64[S, nu] actuator controls of the steps, the same for
        every world (:mod:`mwbx.controls`); None or width 0 leaves ``ctrl`` at 0.

    Returns:
      (f64[n, S, nstate] states s_{k+1} … s_{k+S},
       f64[n, S, nsensordata] sensors of steps k … k+S-1; width 0 without sensors).
    """
    n, n_steps = wrench.shape[:2]
    if out is None:
      out = (np.empty((n, n_steps, self.nstate)), np.empty((n, n_steps, self.model.nsensordata if sensors else 0)))
    out_state, out_sensor = out[0][:n], out[1][:n]
    if models is None:
      model = self.model if sensors else self.quiet_model
      if len(self._models) < n or self._models[0] is not model:
        self._models = [model] * max(n, len(self._models))
      models = self._models[:n]
    spec = _CONTROL
    if ctrl is not None and ctrl.shape[-1] > 0:
      spec = _CONTROL_CTRL
      wrench = np.concatenate([np.broadcast_to(ctrl, (n,) + ctrl.shape), wrench], axis=-1)
    self.pool.rollout(
        models, self.datas, states, wrench, control_spec=spec, nstep=n_steps,
        initial_warmstart=warmstart, state=out_state, sensordata=out_sensor if sensors else None,
        skip_checks=True, chunk_size=max(1, n // (4 * self.threads)))
    return out_state, out_sensor

  def absorb_frame(self, rows: np.ndarray, before: np.ndarray, after: np.ndarray,
                   sensors: np.ndarray, sensordata: np.ndarray, warmstart: np.ndarray,
                   states: np.ndarray, free_bodies=None) -> None:
    """What one frame of :meth:`step` output means for the sampling loop, in place.

    Args:
      rows: i64[n] chunk row of each stepped world.
      before: f64[n, nstate] states s_k the frame started from.
      after: f64[n, S, nstate] states returned by :meth:`step`.
      sensors: f64[n, S, nsensordata] sensors returned by :meth:`step`.
      sensordata: f32[C, S, nsensordata] out: the sensors, NaN for worlds MuJoCo
        reset (mj_step resets a diverging world to time 0: NaN marks it unstable).
      warmstart: f64[C, nv] out: warm start for the next frame.
      states: f64[C, nstate] out: states s_{k+S}.
      free_bodies: :class:`free_bodies.FreeBodies` to compute the sensor block
        from the states (``sensors`` then has width 0).
    """
    m = self.model
    rows = np.asarray(rows, np.int64)
    host_loops.absorb_rows(rows, before, after, sensors, m.opt.timestep, 1 + m.nq, sensordata,
                           warmstart, states)
    if free_bodies is not None:
      host_loops.observe_free_bodies(rows, before, after, m.opt.timestep, m.opt.gravity, 1, 1 + m.nq,
                                     free_bodies, sensordata)

  def _chunk(self, scene, params: world.WorldParams, qpos0, qvel0, step_keys, active,
             n_frames: int) -> _Chunk:
    """The host buffers both sampling loops share, for C worlds at time 0."""
    m = self.model
    c = len(qpos0)
    n_bodies = len(scene.body_ids)
    spf = params.steps_per_frame
    active = np.asarray(active)
    buffers = host_bookkeeping.ChunkBuffers(
        params=host_bookkeeping.host_params(params),
        key_data=np.asarray(jax.random.key_data(step_keys), np.uint32),
        tracked_ids=np.asarray(scene.body_ids, np.int64),
        states=self.initial_states(np.asarray(qpos0), np.asarray(qvel0)),
        warmstart=np.zeros((c, m.nv)),
        sensordata=np.zeros((c, spf, m.nsensordata), np.float32),
        wrench_full=np.zeros((c, spf, m.nbody, 6)),
        qpos_buf=np.zeros((c, n_frames, m.nq), np.float32),
        com_buf=np.zeros((c, n_frames, n_bodies, 3), np.float32),
        carry=host_bookkeeping.init_carry(n_bodies, active))
    return _Chunk(
        buffers=buffers,
        # Free bodies are observed from their states: MuJoCo then steps without sensors.
        free_bodies=free_bodies_lib.free_bodies(m, scene.body_ids),
        active=active,
        running=active.copy())

  @staticmethod
  def _result(ch: _Chunk, compile_seconds: float, run_seconds: float,
              physics_seconds: float) -> ChunkResult:
    b = ch.buffers
    carry = b.carry
    frame_count = carry.frame_count.astype(np.int32)
    return ChunkResult(
        qpos=fill_tail(b.qpos_buf, frame_count), com=fill_tail(b.com_buf, frame_count),
        frame_count=frame_count, status=carry.status.astype(np.int32),
        metrics=world.finalize_metrics(carry).astype(np.float32), perturbations=carry.perturbations.astype(np.int32),
        steps=carry.step.astype(np.int32), compile_seconds=compile_seconds, run_seconds=run_seconds,
        physics_seconds=physics_seconds)

  def run_chunk(self, scene, params: world.WorldParams, qpos0, qvel0, step_keys, active,
                n_frames: int, progress=None, finished=None) -> ChunkResult:
    """Runs C worlds until all have finished, each from start to finish on one
    thread (:mod:`compiled_world`), or in lockstep where that is not available.
    ``finished``: as :meth:`mwbx.batch_sim.backend.Backend.run_chunk`, in
    batches of :func:`handover_batch` worlds.

    Args:
      scene: the :class:`mwbx.scene.Scene`.
      params: bookkeeping constants.
      qpos0: f32[C, nq]; qvel0: f32[C, nv] initial states.
      step_keys: key[C] per-world step key roots.
      active: bool[C] false for padding slots.
      n_frames: frames per world at most (end_frame + 1).
      progress: optional callback(world_steps_done, worlds_finished).
    """
    if not mujoco_c.available():
      return self.run_chunk_lockstep(scene, params, qpos0, qvel0, step_keys, active, n_frames,
                                     progress)
    m = self.model
    c = len(qpos0)
    ch = self._chunk(scene, params, qpos0, qvel0, step_keys, active, n_frames)
    buffers, running, active = ch.buffers, ch.running, ch.active
    carry = buffers.carry
    initial = buffers.states.copy()  # buffers.states moves on with each world
    free, bodies = free_bodies_lib.host_arrays(ch.free_bodies)
    model = self.quiet_model if free else m
    inputs = compiled_world.WorldInputs(
        ctrl_table=controls.scene_table(scene, n_frames * params.steps_per_frame), n_frames=n_frames,
        timestep=m.opt.timestep, gravity=np.asarray(m.opt.gravity, np.float64), free=free, free_bodies=bodies,
        rest_when_asleep=bool(m.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP)))

    events = self.step_events(scene.object_names)
    found = compiled_world.event_buffers(c, events)
    tree_frames = np.zeros((c, 2), np.int64)

    views: dict[int, tuple] = {}  # id(data) -> (data, its views): each thread's, made once

    def run(row, data, running_flags):
      if id(data) not in views:
        views[id(data)] = (data, mujoco_c.data_views(model, data))  # data held: its id is not reused
      return compiled_world.run_world(row, views[id(data)][1], inputs, initial, buffers,
                                      running_flags, events, found, tree_frames)

    # The first call compiles the loop, or loads it from numba's cache (no world
    # is marked running, so it returns at once).
    t0 = time.perf_counter()
    run(0, mujoco.MjData(model), np.zeros(c, bool))
    compile_seconds = time.perf_counter() - t0

    def poll():
      if progress is not None:
        progress(int(carry.step.sum()), int((~running & active).sum()))

    handover = None if finished is None else _Handover(finished, buffers, handover_batch(c))

    def work(row, data):
      seconds = run(row, data, running)
      if handover is not None:
        handover.put(row)
      return seconds

    t0 = time.perf_counter()
    try:
      physics, busy, sim_errors = self.run_per_world(np.flatnonzero(active), work, model, running, carry.status,
                                                     poll)
    finally:
      if handover is not None:
        handover.close()
    run_seconds = time.perf_counter() - t0
    if progress is not None:
      progress(int(carry.step.sum()), int(active.sum()))
    # The share of the threads' time spent inside mj_step, applied to the wall time.
    physics_seconds = run_seconds * float(physics / max(busy, 1e-12))
    result = self._result(ch, compile_seconds, run_seconds, physics_seconds)._replace(errors=tuple(sim_errors))
    if events.on:
      result = result._replace(event_rows=found.rows, event_strength=found.strength, event_count=found.count)
    if inputs.rest_when_asleep:
      result = result._replace(tree_frames=tree_frames)
    return result

  def step_events(self, object_names) -> compiled_world.StepEventInputs:
    """How the compiled loops find the contact events of the scene (its
    ``object_names``) at every step (kept per backend)."""
    if self._step_events is None:
      self._step_events = compiled_world.step_event_inputs(
          self.model, events_lib.actors_of(self.model, object_names), self.event_gap)
    return self._step_events

  def run_per_world(self, rows, work, model: mujoco.MjModel, running: np.ndarray, status: np.ndarray, poll=None):
    """Runs ``work(row, data)`` for every row on the backend's threads, each
    thread with its own ``MjData`` of ``model`` (reused from world to world),
    with MuJoCo errors trapped (:func:`mujoco_c.trap_errors`).

    Args:
      rows: the rows to run, in order (threads pull the next one when free).
      work: ``work(row, data) -> seconds inside mj_step``; runs without the GIL
        where it calls compiled loops.
      model: the model the threads' data are made for.
      running: bool[C]; status: i[C] (out): a world MuJoCo raises an error in
        stops running with status ``world.SIM_ERROR`` (its thread is parked
        for good and a fresh one takes its place).
      poll: optional callable, called about every 0.25 s while the threads run.

    Returns:
      (seconds inside mj_step, seconds the threads were busy, summed over
      threads; [(row, message)] of the worlds MuJoCo raised an error in).

    Raises:
      the first exception a ``work`` call raised, after the threads stopped;
      MwbxError after more than MAX_SIM_ERRORS MuJoCo errors.
    """
    rows = iter(np.asarray(rows).tolist())
    lock = threading.Lock()
    physics, busy = [], []
    errors: list = []  # Python exceptions, re-raised here
    sim_errors: list = []  # (row, message) of worlds MuJoCo raised an error in
    stop = threading.Event()
    current: dict[int, int] = {}  # thread ident -> row it is running
    parked: set[int] = set()  # idents of threads parked inside MuJoCo's error call
    threads: list = []

    def worker(t):
      start = time.perf_counter()
      data = mujoco.MjData(model)
      try:
        while not stop.is_set():
          with lock:
            row = next(rows, None)
          if row is None:
            break
          current[threading.get_ident()] = row
          physics[t] += work(row, data)
      except BaseException as exc:  # noqa: BLE001 - re-raised on the calling thread
        errors.append(exc)
        stop.set()
      busy[t] = time.perf_counter() - start

    def start_worker():
      physics.append(0.0)
      busy.append(0.0)
      thread = threading.Thread(target=worker, args=(len(threads),), daemon=True)
      threads.append(thread)
      thread.start()

    def on_error(message):
      """On the erring thread: flag its world; a fresh thread takes its place."""
      row = current[threading.get_ident()]
      running[row] = False
      status[row] = world.SIM_ERROR
      with lock:
        parked.add(threading.get_ident())
        sim_errors.append((row, message))
        if len(sim_errors) > MAX_SIM_ERRORS:
          errors.append(MwbxError(f"MuJoCo raised errors in more than {MAX_SIM_ERRORS} worlds of one"
                                  f" chunk; stopped (the first: {sim_errors[0][1].splitlines()[0]})"))
          stop.set()
        else:
          start_worker()

    def working():
      with lock:
        return [th for th in threads if th.is_alive() and th.ident not in parked]

    with mujoco_c.trap_errors(on_error), mujoco_c.engine_timers_off():
      with lock:
        for _ in range(self.threads):
          start_worker()
      try:
        while live := working():
          live[0].join(0.25)
          if poll is not None:
            poll()
      finally:
        stop.set()  # e.g. on Ctrl-C: the threads stop after the world they are on
        for thread in working():
          thread.join()
    if errors:
      raise errors[0]
    return float(sum(physics)), float(sum(busy)), sim_errors

  def run_chunk_lockstep(self, scene, params: world.WorldParams, qpos0, qvel0, step_keys, active,
                         n_frames: int, progress=None) -> ChunkResult:
    """Runs C worlds in lockstep through ``mujoco.rollout`` until all have
    finished; arguments as :meth:`run_chunk`."""
    m = self.model
    c = len(qpos0)
    spf = params.steps_per_frame
    ch = self._chunk(scene, params, qpos0, qvel0, step_keys, active, n_frames)
    b = ch.buffers
    states, warmstart, wrench_full, sensordata = b.states, b.warmstart, b.wrench_full, b.sensordata
    running, active, free_bodies = ch.running, ch.active, ch.free_bodies

    def bookkeeping(rows, before, frame):
      host_bookkeeping.frame_update(rows, b, before, 1, frame, running)

    t0 = time.perf_counter()
    bookkeeping(np.zeros(0, np.int64), states[:0], 0)  # compile, or load from numba's cache
    compile_seconds = time.perf_counter() - t0

    t0 = time.perf_counter()
    frame = 0
    world_steps = 0
    physics_seconds = 0.0
    all_rows = np.arange(c)
    # Buffers reused every frame; the running worlds use their first rows.
    before_buf = np.empty_like(states)
    out = (np.empty((c, spf, self.nstate)), np.empty((c, spf, m.nsensordata if free_bodies is None else 0)))
    ctrl_table = controls.scene_table(scene, n_frames * spf)
    while running.any():
      everyone = running.all()
      # While every world runs, whole arrays stand in for gathers.
      idx = all_rows if everyone else np.flatnonzero(running)
      n_run = len(idx)
      before = before_buf[:n_run]  # s_k, kept: states moves on below
      if everyone:
        np.copyto(before, states)
      else:
        np.take(states, idx, axis=0, out=before)
      wrench_in = wrench_full.reshape(c, spf, -1) if everyone else wrench_full[idx].reshape(n_run, spf, -1)
      warm_in = warmstart if everyone else warmstart[idx]
      physics_start = time.perf_counter()
      ctrl = ctrl_table[frame * spf:(frame + 1) * spf]
      after, sensors = self.step(before, wrench_in, warm_in, sensors=free_bodies is None, out=out, ctrl=ctrl)
      physics_seconds += time.perf_counter() - physics_start
      self.absorb_frame(idx, before, after, sensors, sensordata, warmstart, states, free_bodies)
      world_steps += n_run * spf
      bookkeeping(idx, before, frame)
      frame += 1
      if progress is not None and frame % 16 == 0:
        progress(world_steps, int((~running & active).sum()))
    run_seconds = time.perf_counter() - t0
    if progress is not None:
      progress(world_steps, int(active.sum()))
    return self._result(ch, compile_seconds, run_seconds, physics_seconds)


def handover_batch(chunk_worlds: int) -> int:
  """Finished worlds handed over at a time: an eighth of the chunk, at least
  16 (fewer calls cost the codec less; the last batch waits for the chunk's end)."""
  return max(16, chunk_worlds // 8)


class _Handover:
  """Hands finished worlds over in batches, on a thread of its own."""

  def __init__(self, finished: Callable[[FinishedWorlds], None], buffers, batch: int):
    self._rows: queue.SimpleQueue = queue.SimpleQueue()
    self._errors: list = []
    self._thread = threading.Thread(target=self._run, args=(finished, buffers, batch), name="mwbx-finished",
                                    daemon=True)
    self._thread.start()

  def put(self, row: int) -> None:
    """World ``row`` has finished: its buffers are final."""
    self._rows.put(row)

  def _run(self, finished, b, batch: int) -> None:
    rows: list[int] = []
    while (row := self._rows.get()) is not None:
      rows.append(row)
      if len(rows) < batch or self._errors:
        continue
      taken, rows = np.asarray(rows, np.int64), []
      try:
        finished(FinishedWorlds(taken, b.qpos_buf[taken], b.carry.frame_count[taken].copy()))
      except BaseException as exc:  # noqa: BLE001 - re-raised by close() on the calling thread
        self._errors.append(exc)

  def close(self) -> None:
    """Waits for the batch in hand; raises what ``finished`` raised."""
    self._rows.put(None)
    self._thread.join()
    if self._errors:
      raise self._errors[0]
