"""The MJX backend: the whole lockstep loop as one jitted ``lax.scan``.

A block of frames runs on device as a scan over frames whose body is a scan
over the physics steps of one frame (the MJX step vmapped over worlds: on
impl jax, :func:`mjx_collision.batched_step`: MJX's with a box broadphase,
each world's constraint solve over its rows in use), then
the bookkeeping kernel on the frame's observations. Finished worlds are frozen with ``jnp.where`` (lockstep);
the host only copies out the recorded frames after each block. This is the
path for GPUs and TPUs.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
from jax.extend import core as jax_core
import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mujoco import mjx

from mwbx import controls
from mwbx.batch_sim import contact_budget
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.batch_sim import mjx_collision
from mwbx.batch_sim import mjx_events
from mwbx.batch_sim import free_bodies as free_bodies_lib
from mwbx.batch_sim import warp_solver as warp_solver_lib
from mwbx.batch_sim import world
from mwbx.batch_sim.backend import ChunkResult, fill_tail
from mwbx.events import actors as events_lib

# Frames per jitted block at most: long enough to amortize dispatch, short
# enough for a live progress bar and an early exit once every world has
# finished. The frames a block runs are a traced loop bound (one compiled code
# for any count), sized while running so a block takes about
# BLOCK_SECONDS: Ctrl-C (handled between blocks) stops within a block or two.
FRAMES_PER_BLOCK = 30
BLOCK_SECONDS = 1.0

# Worlds per device are a multiple of this: XLA's CPU code works on 8 float32
# lanes, and a batch that fills no whole lane gets scalar code, slower and
# rounding differently.
LANE = 8

# impl jax: caps on the constraint solver's iterations and line-search steps
# per iteration (a model's lower limits stand): a vmapped batch iterates until
# its slowest world converges, which float32 rarely does at MuJoCo's 1e-8.
# Same accelerations within 1e-5 of |qacc| (tests/batch_sim/test_mjx_solver_limits.py).
SOLVER_ITERATIONS = 20
LS_ITERATIONS = 4


def frame_block(frame_fn, n_frames: int):
  """The one jitted block builder of the MJX paths (sampling and refinement).

  Args:
    frame_fn: ``frame_fn(consts, state) -> (state, outputs)``, one frame of a
      batch (outputs: a pytree of per-frame arrays).
    n_frames: frames per block at most.

  Returns:
    ``run(state, consts, count) -> (state, outputs)`` jitted: ``count`` frames
    (a traced bound, so one compile serves a shorter last block and no frame
    runs past the end), outputs stacked ``[n_frames, ...]``, rows past
    ``count`` zero.
  """

  def run(state, consts, count):
    # The frame traced once: its outputs' shapes size the buffers, and the loop
    # body replays its jaxpr (tracing MJX's step is seconds of Python; a second
    # trace for the shapes alone doubled a sampler's start).
    traced, shapes = jax.make_jaxpr(frame_fn, return_shape=True)(consts, state)
    one_frame = jax_core.jaxpr_as_fun(traced)
    outputs = jax.tree.map(lambda s: jnp.zeros((n_frames,) + s.shape, s.dtype), shapes[1])

    def body(i, loop):
      state, outputs = loop
      state, new = jax.tree.unflatten(jax.tree.structure(shapes), one_frame(*jax.tree.leaves((consts, state))))
      return state, jax.tree.map(lambda buf, x: buf.at[i].set(x), outputs, new)

    return jax.lax.fori_loop(0, count, body, (state, outputs))

  return jax.jit(run)


def scatter_wrench(xfrc_tracked: jax.Array, nbody: int, body_ids: jax.Array) -> jax.Array:
  """f32[W, nbody, 6] ``xfrc_applied`` from the tracked bodies' wrenches f32[W, B, 6]."""
  return jnp.zeros((xfrc_tracked.shape[0], nbody, 6), jnp.float32).at[:, body_ids].set(xfrc_tracked)


def hold_finished(running: jax.Array, new, old):
  """``new`` where a world is still running (bool[W]), else ``old``: finished
  worlds keep their last state. MuJoCo Warp's per-batch fields (its contact
  pool) are not per world: they are ``new``'s."""
  def pick(path, n, o):
    if not _per_world(new, path):
      return n
    return jnp.where(running.reshape((-1,) + (1,) * (n.ndim - 1)), n, o)
  return jax.tree_util.tree_map_with_path(pick, new, old)


def _per_world(tree, path) -> bool:
  """Whether a leaf of a batched ``mjx.Data`` has a world axis (all do on impl jax)."""
  if not isinstance(tree, mjx.Data) or tree.impl != mjx.Impl.WARP:
    return True
  from mujoco.mjx.warp import types as warp_types  # pylint: disable=g-import-not-at-top
  from mujoco.mjx._src.types import tree_path_to_attr_str  # pylint: disable=g-import-not-at-top
  return warp_types._BATCH_DIM["Data"].get(tree_path_to_attr_str(path), True)  # pylint: disable=protected-access


def backend_for(scene, impl: str, budget: contact_budget.ContactBudget, devices=None,
                pack_rows: bool | None = None, warp_solver=None, sleep=None,
                event_gap: int | None = None) -> "MjxBackend":
  """The MJX backend of a scene under a contact budget (the entry point for
  sampling and benchmarks: ``backend.make_data`` and ``backend.step`` are one
  budgeted batched step, ``backend.overflow`` its flag).

  Args:
    scene: the :class:`mwbx.scene.Scene` (its model's timestep is used).
    impl: ``jax`` or ``warp``.
    budget: the budget (:func:`mwbx.batch_sim.sampler.resolve_contact_budget`:
      the config's ``sim.mjx`` values, the rest from a native pilot).
    devices, pack_rows, event_gap: as for :class:`MjxBackend`.
    warp_solver: impl warp: the :class:`warp_solver.WarpSolverSettings` (or
      its dict, as a bank's ``run`` stores it) to use; None: chosen from the
      model and the config's ``sim.mjx`` (:func:`warp_solver.warp_solver_settings`).
    sleep: impl warp: the :class:`mwbx.batch_sim.sleep.SleepSettings` to step
      with (MuJoCo Warp sleeps under Newton only, which the solver choice then
      takes, with the budget's ``nvmax`` awake dofs a world); None or off: the
      model's own flag. Ignored on impl ``jax`` (MJX's jax step has no sleep).
  """
  # impl jax reads its caps from the model's numerics; warp sizes its pools from the budget.
  model = contact_budget.budgeted_model(scene, budget) if impl == "jax" else scene.model
  if impl == "warp" and sleep is not None and sleep.enabled:
    model = sleep_lib.sleeping_copy(model, sleep)
  if impl == "warp" and warp_solver is None:
    warp_solver = warp_solver_lib.warp_solver_settings(model, scene.config.sim.mjx)
  return MjxBackend(model, impl, devices, budget=budget, pack_rows=pack_rows, warp_solver=warp_solver,
                    event_gap=event_gap)


class MjxBackend:
  """MJX model on the default device plus the compiled block function.

  Args:
    model: the scene model (with mwbx sensors); for a contact budget on impl
      ``jax``, the budgeted model (:func:`contact_budget.budgeted_model`).
    impl: ``jax`` or ``warp``.
    devices: the devices a batch is split over (default: this process's).
    budget: the :class:`contact_budget.ContactBudget` (impl ``warp`` sizes its
      contact and constraint pools from it; None: MuJoCo Warp's defaults).
    pack_rows: impl ``jax``: solve each world over its own constraint rows in
      use (:mod:`mwbx.batch_sim.mjx_packed_solve`: 2-3.5x as fast as MJX's
      solve over every budget row on SIGGRAPH's 2-core CPU runs, a world the
      same bits in any batch). False: MJX's solve over every row, world by
      world (the reference the packed solve is tested against). None: on
      where the devices are CPUs; off on accelerators, where its groups of
      ``WORLDS_PER_SOLVE`` worlds, solved one after another, are not measured.
    warp_solver: impl ``warp``: MuJoCo Warp's solver settings
      (:class:`warp_solver.WarpSolverSettings` or its dict), applied to a copy
      of ``model`` before it is put on the device; None: chosen from the model
      alone (:func:`warp_solver.warp_solver_settings`). Ignored on impl ``jax``.
    event_gap: physics steps apart that end a contact episode: the scan then
      finds contact events at every step (:mod:`mjx_events`; the sampler's:
      a query point's steps); None: it does not (they are found on the
      stored frames).
  """

  def __init__(self, model: mujoco.MjModel, impl: str = "jax", devices=None,
               budget: contact_budget.ContactBudget | None = None, pack_rows: bool | None = None,
               warp_solver=None, event_gap: int | None = None):
    # impl warp: the solver settings in a copy of the model (the scene's model is shared).
    self.warp_solver = None
    if impl == "warp":
      if isinstance(warp_solver, dict):
        warp_solver = warp_solver_lib.WarpSolverSettings.from_dict(warp_solver)
      self.warp_solver = warp_solver or warp_solver_lib.warp_solver_settings(model)
      model = warp_solver_lib.solver_model(model, self.warp_solver)
    self.model = model
    self.impl = impl
    self.budget = budget
    # impl warp with the model's sleep flag on: MuJoCo Warp steps with island sleep.
    self.sleeps = impl == "warp" and bool(model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP))
    # This process's devices: a batch's worlds are split over them; under
    # jax.distributed every process runs its own worlds on its own devices.
    self.devices = list(devices) if devices is not None else jax.local_devices()
    if impl == "warp":
      contact_budget.quiet_warp()
    self.mx = self._put(model)
    # impl jax: MJX's step with pairs culled by world bounding boxes (what the budget is sized for).
    self.mjx_step = mjx_collision.step if impl == "jax" else mjx.step
    if pack_rows is None:
      pack_rows = all(device.platform == "cpu" for device in self.devices)
    self.pack_rows = impl == "jax" and pack_rows
    # A batch's step (with pack_rows on impl jax: each world's solve over its rows in use).
    self.batched_step = (mjx_collision.batched_step if self.pack_rows
                         else jax.vmap(self.mjx_step, in_axes=(None, 0)))
    # impl jax: flags a step that may have dropped contacts (never misses one).
    self.check = contact_budget.JaxOverflowCheck(model) if impl == "jax" else None
    self._quiet_mx = None
    self._blocks: dict = {}
    self.event_gap = None if event_gap is None else int(event_gap)
    self._event_inputs = None

  def _put(self, model: mujoco.MjModel):
    try:
      mx = mjx.put_model(model, device=self.devices[0], impl=self.impl)
    except NotImplementedError as err:  # e.g. "Flex not implemented for JAX backend."
      flexes = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_FLEX, f) for f in range(model.nflex)]
      what = f"the scene has flexes ({', '.join(flexes)}): " if flexes else ""
      raise MwbxError(f"sim.backend: mjx (impl {self.impl}) cannot run this scene: {what}{str(err).rstrip('.')};"
                      " use backend: native" + (" or mjx_impl: warp" if self.impl == "jax" else "")) from None
    if self.impl == "warp":  # overflows are read from its counters, not printed every step
      mx = mx.tree_replace({"opt._impl.warn_overflow": 0})
    else:
      mx = mx.tree_replace({"opt.iterations": min(int(model.opt.iterations), SOLVER_ITERATIONS),
                            "opt.ls_iterations": min(int(model.opt.ls_iterations), LS_ITERATIONS)})
    return mx

  @property
  def lane(self) -> int:
    """A device's share of a batch is a multiple of this many worlds."""
    return LANE

  @property
  def quiet_mx(self):
    """The MJX model with sensors disabled (put on the device when first needed)."""
    if self._quiet_mx is None:
      self._quiet_mx = self._put(free_bodies_lib.quiet_copy(self.model))
    return self._quiet_mx

  def close(self) -> None:
    pass

  def make_data(self, qpos: jax.Array, qvel: jax.Array, act: jax.Array | None = None) -> mjx.Data:
    """Batched ``mjx.Data`` at time 0 from qpos f32[W, nq], qvel f32[W, nv]
    and, optionally, actuator activations f32[W, na]."""
    sizes = {}
    if self.impl == "warp" and self.budget is not None:  # the contact pool is shared by the batch
      sizes = {"naconmax": self.budget.nconmax * qpos.shape[0], "njmax": self.budget.njmax}
      if self.sleeps and self.budget.nvmax:
        sizes["nvmax"] = min(self.budget.nvmax, self.model.nv)
    base = mjx.make_data(self.model, device=self.devices[0], impl=self.impl, **sizes)
    if act is not None:
      return jax.vmap(lambda q, v, a: base.replace(qpos=q, qvel=v, act=a.astype(base.act.dtype)))(qpos, qvel, act)
    return jax.vmap(lambda q, v: base.replace(qpos=q, qvel=v))(qpos, qvel)

  def step(self, d: mjx.Data, xfrc: jax.Array) -> mjx.Data:
    """One physics step of a batch; ``xfrc``: f32[W, nbody, 6]. Sensors describe s_k."""
    return self.batched_step(self.mx, d.replace(xfrc_applied=xfrc))

  def overflow(self, d_next: mjx.Data) -> jax.Array:
    """bool[W]: the step that produced ``d_next`` may have dropped contacts
    or constraints (over the contact budget)."""
    if self.impl == "warp":
      return contact_budget.warp_overflow(d_next)
    if not self.check.can_overflow:
      return jnp.zeros(d_next.qpos.shape[0], bool)
    return jax.vmap(self.check)(d_next)

  def block(self, params: world.WorldParams, body_ids: np.ndarray, n_frames: int,
            events: mjx_events.MjxEventInputs | None = None):
    """``run(state, ctrl_table, count)`` for up to ``n_frames`` sampled frames
    (cached; see :func:`frame_block`). ``ctrl_table``: f32[N, nu] control of
    each step (:mod:`mwbx.controls`), or None for a scene without controls.
    ``events``: find contact episodes at every step (:mod:`mjx_events`; the
    state's last entry is then the batch's trackers)."""
    cache_key = (id(params), n_frames, events is not None)
    if cache_key in self._blocks:
      return self._blocks[cache_key][1]
    nbody = self.model.nbody
    ids = jnp.asarray(body_ids)
    # Free bodies are observed from their states: MJX then steps without sensors.
    bodies = free_bodies_lib.free_bodies(self.model, body_ids)
    mx = self.mx if bodies is None else self.quiet_mx

    def observe(d_next, out):
      """f32[W, S, B * SENSOR_WIDTH] sensor block of the frame's steps."""
      if bodies is None:
        return jnp.swapaxes(out, 0, 1)
      qpos = jnp.concatenate([out[0], d_next.qpos[None]])  # [S + 1, W, nq]
      qvel = jnp.concatenate([out[1], d_next.qvel[None]])
      return jax.vmap(free_bodies_lib.observe, in_axes=(1, 1, None, None, None))(
          qpos, qvel, bodies, params.dt, params.gravity)

    def frame(ctrl_table, state):
      d, carry, wrench, keys, overflow, tracks = state  # wrench: f32[W, S, B, 6]; overflow: bool[W]
      qpos = d.qpos  # s_k at the frame boundary, recorded if `record`.
      running = carry.status == world.RUNNING

      def physics_step(stepping, inputs):
        d, tracks = stepping
        xfrc_tracked, ctrl, s = inputs  # ctrl: f32[W, nu] or None
        d = d.replace(xfrc_applied=scatter_wrench(xfrc_tracked, nbody, ids))
        if ctrl is not None:
          d = d.replace(ctrl=ctrl.astype(d.ctrl.dtype))
        d_next = self.batched_step(mx, d)
        if events is not None:  # the step's contacts are those of the state it started from: tick k0 + s
          tracks = mjx_events.track_step(tracks, d_next, self.impl, events, carry.step + s, running, params.dt)
        return (d_next, tracks), (d_next.sensordata if bodies is None else (d.qpos, d.qvel), self.overflow(d_next))

      ctrl = None
      if ctrl_table is not None:  # f32[N, nu]: row k is step k's control
        rows = jnp.minimum(carry.step[:, None] + jnp.arange(params.steps_per_frame), ctrl_table.shape[0] - 1)
        ctrl = jnp.swapaxes(ctrl_table[rows], 0, 1)  # [S, W, nu]
      (d_next, tracks), (out, step_overflow) = jax.lax.scan(
          physics_step, (d, tracks), (jnp.swapaxes(wrench, 0, 1), ctrl, jnp.arange(params.steps_per_frame)))
      overflow = overflow | (step_overflow.any(axis=0) & running)
      obs = jax.vmap(jax.vmap(lambda s: world.Observation.from_sensordata(s, params.gravity)))(
          observe(d_next, out))
      carry, out = world.frame_update(carry, obs, keys, params)
      d = hold_finished(out.running, d_next, d)
      return (d, carry, out.wrench, keys, overflow, tracks), (out.record, qpos, obs.com_pos[:, 0])

    fn = frame_block(frame, n_frames)
    self._blocks[cache_key] = (params, fn)
    return fn

  def event_inputs(self, object_names) -> mjx_events.MjxEventInputs | None:
    """How this backend's scans (sampling and refinement) find the contact
    events of a scene with these objects (cached); None where the backend
    was made without an event gap."""
    if self.event_gap is None:
      return None
    if self._event_inputs is None:
      self._event_inputs = mjx_events.event_inputs(self.model, events_lib.actors_of(self.model, object_names),
                                                   self.event_gap)
    return self._event_inputs

  def run_chunk(self, scene, params: world.WorldParams, qpos0, qvel0, step_keys, active,
                n_frames: int, progress=None, finished=None) -> ChunkResult:
    """Runs C worlds in lockstep until all have finished (see NativeBackend.run_chunk;
    in lockstep no world finishes before the chunk: ``finished`` is never called).

    With several devices, each runs C / devices of the worlds with the same
    compiled block a one-device run of that batch uses (dispatched to all,
    then gathered), so a world does not depend on how many devices there are.
    """
    m = self.model
    c = len(qpos0)
    active = np.asarray(active)
    body_ids = scene.body_ids
    block_frames = min(FRAMES_PER_BLOCK, n_frames)
    events = self.event_inputs(scene.object_names)
    fn = self.block(params, body_ids, block_frames, events)
    n_dev = len(self.devices)
    if c % n_dev:
      raise ValueError(f"a batch of {c} worlds does not split over {n_dev} devices")
    per = c // n_dev

    carry = jax.vmap(world.init_carry, in_axes=(None, 0))(len(body_ids), jnp.asarray(active))
    wrench = jnp.zeros((c, params.steps_per_frame, len(body_ids), 6), jnp.float32)
    tracks = None if events is None else mjx_events.new_tracks(c, events)
    rest = (carry, wrench, step_keys, jnp.zeros(c, bool), tracks)
    # Each device's Data is made for its share (MuJoCo Warp's contact pool is
    # per batch, not per world, so it is not sliced).
    states = [jax.device_put((self.make_data(jnp.asarray(qpos0[k * per:(k + 1) * per]),
                                             jnp.asarray(qvel0[k * per:(k + 1) * per])),)
                             + jax.tree.map(lambda x, k=k: x[k * per:(k + 1) * per], rest), device)
              for k, device in enumerate(self.devices)]
    table = controls.scene_table(scene, n_frames * params.steps_per_frame)
    tables = [None if table.shape[1] == 0 else jax.device_put(jnp.asarray(table, jnp.float32), device)
              for device in self.devices]

    t0 = time.perf_counter()
    compiled = [fn.lower(s, t, jnp.int32(block_frames)).compile() for s, t in zip(states, tables)]
    compile_seconds = time.perf_counter() - t0

    gather = lambda xs, axis=0: np.concatenate([np.asarray(x) for x in xs], axis=axis)
    qpos_buf = np.zeros((c, n_frames, m.nq), np.float32)
    com_buf = np.zeros((c, n_frames, len(body_ids), 3), np.float32)
    t0 = time.perf_counter()
    start = 0
    count = 1  # the first block measures a frame's cost
    while start < n_frames:
      stop = min(start + count, n_frames)
      block_start = time.perf_counter()
      outs = [run(s, t, jnp.int32(stop - start)) for run, s, t in zip(compiled, states, tables)]  # all devices
      states = [out[0] for out in outs]
      record, qpos, com = (gather([out[1][i] for out in outs], axis=1) for i in range(3))  # [F, C, ...]
      per_frame = (time.perf_counter() - block_start) / (stop - start)
      count = int(np.clip(BLOCK_SECONDS / max(per_frame, 1e-9), 1, block_frames))
      f, w = np.nonzero(record[: stop - start])
      qpos_buf[w, start + f] = qpos[f, w]
      com_buf[w, start + f] = com[f, w]
      start = stop
      status = gather([s[1].status for s in states])
      if progress is not None:
        steps = gather([s[1].step for s in states])
        progress(int(steps.sum()), int(((status != world.RUNNING) & active).sum()))
      if (status != world.RUNNING).all():
        break
    jax.block_until_ready(states)
    run_seconds = time.perf_counter() - t0

    carry = jax.tree.map(lambda *xs: gather(xs), *[s[1] for s in states])
    frame_count = np.asarray(carry.frame_count)
    found = {}
    if events is not None:
      tracks = jax.tree.map(lambda *xs: gather(xs), *[s[5] for s in states])
      rows, strength, count = mjx_events.finish_tracks(tracks, (frame_count - 1) * params.steps_per_frame,
                                                       events.n_actors)
      found = {"event_rows": rows, "event_strength": strength, "event_count": count}
    return ChunkResult(
        qpos=fill_tail(qpos_buf, frame_count), com=fill_tail(com_buf, frame_count),
        frame_count=frame_count, status=np.asarray(carry.status),
        metrics=world.finalize_metrics(carry), perturbations=np.asarray(carry.perturbations),
        steps=np.asarray(carry.step), compile_seconds=compile_seconds, run_seconds=run_seconds,
        contact_overflow=gather([s[4] for s in states]), **found)
