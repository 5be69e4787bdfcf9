"""The batched engines against native MuJoCo, per scene, in one run.

For each scene and the same randomized initial states (batch 64 by default):
  native     bare ``mujoco.rollout``, a thread per core (the CPU reference)
  mjx:bare   ``jax.vmap(mjx.step)``, impl jax, no contact budget (dense contacts)
  mjx:jax    the same with the scene's contact budget (``mjx_backend.backend_for``:
             mwbx's step, each world's solve over its rows in use)
  mjx:jax every row  (engine ``every``) the same with MJX's solve over every
             budget row (``sim.mjx.pack_rows: false``)
  mjx:warp   MuJoCo Warp through MJX, pools sized from the same budget, under
             mwbx's solver settings (``warp_solver.warp_solver_settings``);
             ``--warp-variants`` adds other settings of the same engine as rows
             of their own (``mjx:warp shipped``, ``clamped``, ``capped``, ``cg``;
             see WARP_VARIANTS), ``--warp-solver/--warp-tolerance/
             --warp-iterations`` one chosen on the command line
each in world-steps/s (compile time apart, best of the repeats, which
alternate since the machine is shared), with its ratio to native. All step the
scene's model with mwbx's sensors, un-perturbed, from the same states.

For a GPU, on paper: per world-step, XLA's own cost analysis of one compiled
batched step (flops, bytes accessed) and the roofline bound it implies on a
named GPU, next to published figures. These are estimates, not measurements:
XLA's CPU cost model is not the GPU's, and MuJoCo Warp's kernels are custom
calls XLA does not see into.

  .venv/bin/python scripts/bench_backends.py [--scenes siggraph,trebuchet_tower] [--batch 64]
      [--warp-variants shipped,clamped,capped,cg | --warp-solver cg --warp-tolerance 1e-6 --warp-iterations N]

Writes out/bench/backends.json (docs/benchmarks.md is generated from it).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco import rollout as mj_rollout
from mujoco.mjx._src import constraint, forward, smooth, solver

import mwbx
from mwbx.batch_sim import contact_budget, mjx_backend, mjx_collision, mjx_packed_solve, warp_solver
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.batch_sim.native_backend import exact_pose
from mwbx.config import MjxSection
from mwbx.batch_sim.sampler import resolve_contact_budget
from mwbx.batch_sim.sampler import world_keys

# Run as `python scripts/bench_backends.py`: scripts/ is on sys.path, and the native
# baseline is bench_sampler's bare `mujoco.rollout`, the same in both benchmarks.
from bench_sampler import ROLLOUT_STATE, bench_rollout, rollout_states  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[1]
SCENES = ("quickstart", "pachinko", "toss", "siggraph", "spiral_staircase", "refrigerator_toy", "trebuchet_tower")
# A roofline for a GPU (vendor figures) and published throughputs, all for comparison only.
GPU = {"name": "NVIDIA H200", "hbm_bytes_per_s": 4.8e12, "fp32_flops_per_s": 67e12}
PUBLISHED = [
    {"what": "MJX, humanoid", "device": "NVIDIA A100", "steps_per_s": 950e3,
     "source": "published figure, quoted for scale, not measured here"},
    {"what": "MuJoCo Warp (nightly), humanoid", "device": "NVIDIA RTX 6000 Ada", "steps_per_s": 5.7e6,
     "source": "published figure, quoted for scale, not measured here"},
]


# mjx:warp's solver variants by name (``--warp-variants``), each the config
# overrides it stands for (``shipped``: the model's own options, unchanged).
# ``capped``'s 10 Newton iterations: MuJoCo C takes 1-2 a step on the tower
# (docs: ECOSYSTEM notes), so 10 leaves room; not tuned on a GPU.
CAPPED_ITERATIONS = 10
WARP_VARIANTS = {
    "auto": {},  # mwbx's choice: CG above warp_solver.NEWTON_MAX_NV, tolerance raised to 1e-6
    "shipped": None,  # the model's solver, tolerance and iterations as its MJCF has them
    "clamped": {"solver": "newton"},  # Newton with the tolerance raised to float32's 1e-6
    "capped": {"solver": "newton", "iterations": CAPPED_ITERATIONS},
    "cg": {"solver": "cg"},
}


def warp_variants(args, model, config) -> list[tuple[str, warp_solver.WarpSolverSettings]]:
  """(row label, settings) of each mjx:warp variant asked for: ``--warp-variants``
  by name, else the one of ``--warp-solver/--warp-tolerance/--warp-iterations``,
  else mwbx's choice (``mjx:warp``)."""
  out = []
  for name in args.warp_variants:
    if name not in WARP_VARIANTS:
      raise SystemExit(f"bench_backends: --warp-variants: unknown variant {name!r} (use {', '.join(WARP_VARIANTS)})")
    label = "mjx:warp" if name == "auto" else f"mjx:warp {name}"
    overrides = WARP_VARIANTS[name]
    settings = (warp_solver.as_shipped(model) if overrides is None
                else warp_solver.warp_solver_settings(model, config.sim.mjx.model_copy(update=overrides)))
    out.append((label, settings))
  if out:
    return out
  if args.warp_solver is None and args.warp_tolerance is None and args.warp_iterations is None:
    return [("mjx:warp", warp_solver.warp_solver_settings(model, config.sim.mjx))]
  if args.warp_solver == "shipped":
    settings = warp_solver.as_shipped(model)
    settings = settings._replace(
        tolerance=settings.tolerance if args.warp_tolerance is None else args.warp_tolerance,
        iterations=settings.iterations if args.warp_iterations is None else args.warp_iterations)
  else:
    settings = warp_solver.warp_solver_settings(model, MjxSection(
        solver=args.warp_solver or "auto", tolerance=args.warp_tolerance, iterations=args.warp_iterations))
  return [(f"mjx:warp {settings.solver} tol {settings.tolerance:g} it {settings.iterations}", settings)]


def _commit() -> str:
  """HEAD's short hash, with "+changes" where the package differs from it."""
  git = lambda *a: subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.strip()
  changed = git("status", "--porcelain", "--untracked-files=all", "--", "mwbx")
  return git("rev-parse", "--short", "HEAD") + ("+changes" if changed else "")


def machine() -> dict:
  """Where this ran: platform, cores, JAX device, load average at the start."""
  info = {"platform": platform.platform(), "machine": platform.machine(), "cores": os.cpu_count(),
          "jax": jax.__version__, "jax_backend": jax.default_backend(), "mujoco": mujoco.__version__,
          "load_average": os.getloadavg()[0], "commit": _commit()}
  if jax.default_backend() != "cpu":
    info["device"] = jax.devices()[0].device_kind
  return info


def initial_states(sampler, n: int) -> tuple[np.ndarray, np.ndarray]:
  """qpos f64[n, nq], qvel f64[n, nv]: the sampler's randomized initial states of worlds 0..n-1."""
  _, init_keys, _ = world_keys(jax.random.key(0), np.arange(n))
  qpos0, qvel0 = sampler._init(init_keys)  # pylint: disable=protected-access
  return np.asarray(qpos0, np.float64), np.asarray(qvel0, np.float64)


def advance(model, qpos0: np.ndarray, qvel0: np.ndarray, seconds: float) -> tuple[np.ndarray, np.ndarray]:
  """The states after ``seconds`` of un-perturbed MuJoCo C from (qpos0, qvel0) f64[n, ...]: a
  timed run from there measures the scene in contact (from t = 0 the bodies may still be falling).
  ``mujoco.rollout`` on every core, the same steps as ``mj_step`` in a loop."""
  threads = os.cpu_count() or 1
  with mj_rollout.Rollout(nthread=threads) as pool:
    trajectory, _ = pool.rollout(model, [mujoco.MjData(model) for _ in range(threads)],
                                 rollout_states(model, qpos0, qvel0), nstep=round(seconds / model.opt.timestep))
  data = mujoco.MjData(model)
  qpos, qvel = qpos0.copy(), qvel0.copy()
  for w in range(len(qpos0)):
    mujoco.mj_setState(model, data, trajectory[w, -1], ROLLOUT_STATE)
    qpos[w], qvel[w] = data.qpos, data.qvel
  return qpos, qvel


def cost_per_world_step(step, d, batch: int) -> dict:
  """XLA's cost analysis of one compiled batched step, divided by the batch."""
  analysis = jax.jit(step).lower(d).compile().cost_analysis()
  if isinstance(analysis, (list, tuple)):  # older JAX: one dict per device
    analysis = analysis[0] if analysis else {}
  analysis = analysis or {}
  flops = float(analysis.get("flops", 0.0)) / batch
  bytes_accessed = float(analysis.get("bytes accessed", 0.0)) / batch
  bound = None
  if flops > 0 or bytes_accessed > 0:
    seconds = max(flops / GPU["fp32_flops_per_s"], bytes_accessed / GPU["hbm_bytes_per_s"])
    bound = 1.0 / seconds
  return {"flops": flops, "bytes_accessed": bytes_accessed, "roofline_steps_per_s": bound,
          "bound_by": (None if bound is None else
                       "memory" if bytes_accessed / GPU["hbm_bytes_per_s"] >= flops / GPU["fp32_flops_per_s"]
                       else "compute")}


def stage_times(backend, d0, repeats: int = 3) -> tuple[dict, dict]:
  """(milliseconds per batched step of the parts of mjx:jax's step, each jitted apart
  on the batch's states: smooth dynamics (kinematics to the mass matrix and
  ``fwd_velocity``/``fwd_acceleration``), collision (broadphase and narrow phase),
  the constraint rows, the solver (each world over its rows in use), MJX's solver
  over every row apart, and the whole step; :func:`solver_detail` of the solver's input)."""
  mx = backend.mx

  def position(d):
    for f in (smooth.kinematics, smooth.com_pos, smooth.crb, smooth.factor_m):
      d = f(mx, d)
    return d

  def velocity(d):
    for f in (smooth.transmission, forward.fwd_velocity, forward.fwd_actuation, forward.fwd_acceleration):
      d = f(mx, d)
    return d

  each = lambda f: jax.vmap(f)  # a stage of one world, vmapped
  stages = [("smooth (position)", each(position)), ("collision", each(lambda d: mjx_collision.collision(mx, d))),
            ("constraint rows", each(lambda d: constraint.make_constraint(mx, d))),
            ("smooth (velocity)", each(velocity)),
            # The solve the step runs (each world over its rows in use) and MJX's over every row.
            ("solver", lambda d: mjx_packed_solve.solve_batch(mx, d)),
            ("solver (every row)", each(lambda d: solver.solve(mx, d)))]
  out, d, solver_input = {}, d0, None
  for name, f in stages:  # each stage from the states the previous ones give
    compiled = jax.jit(f).lower(d).compile()
    d_next = jax.block_until_ready(compiled(d))
    best = min(_timed(compiled, d) for _ in range(repeats))
    if name == "solver":
      solver_input = d
    out[name] = 1e3 * best
    if name != "solver (every row)":  # it starts from the states the solver had
      d = d_next
  compiled = jax.jit(lambda d: backend.batched_step(mx, d)).lower(d0).compile()
  jax.block_until_ready(compiled(d0))
  out["whole step"] = 1e3 * min(_timed(compiled, d0) for _ in range(repeats))
  return out, solver_detail(solver_input, repeats)


def solver_detail(d, repeats: int = 3) -> dict:
  """What the dense Newton solver works on, from the solver's input states ``d``
  (batched): its constraint rows per world, how many have a non-zero Jacobian
  (mean over the batch: the rest are budget slots without a contact), and the
  milliseconds per batched step of one dense Hessian build (J^T D J over every
  row) and of one Cholesky factorization of it, the work each solver iteration
  repeats."""
  impl = getattr(d, "_impl", d)
  jac = jnp.asarray(impl.efc_J)  # f32[W, rows, nv]
  weight = jnp.ones(jac.shape[:2], jac.dtype)
  hessian = jax.jit(lambda j, w: jnp.einsum("bri,br,brj->bij", j, w, j)).lower(jac, weight).compile()
  h = jax.block_until_ready(hessian(jac, weight)) + jnp.eye(jac.shape[-1], dtype=jac.dtype)
  factor = jax.jit(lambda h: jnp.linalg.cholesky(h)).lower(h).compile()
  jax.block_until_ready(factor(h))

  return {"rows": int(jac.shape[1]), "nv": int(jac.shape[2]),
          "nonzero_rows_mean": float((np.abs(np.asarray(jac)).sum(-1) > 0).sum(-1).mean()),
          "hessian_build_ms": 1e3 * min(_timed(hessian, jac, weight) for _ in range(repeats)),
          "cholesky_ms": 1e3 * min(_timed(factor, h) for _ in range(repeats))}


def _timed(compiled, *args) -> float:
  start = time.perf_counter()
  jax.block_until_ready(compiled(*args))
  return time.perf_counter() - start


def mjx_engine(backend_step, make_data, qpos0, qvel0, n_steps: int, overflow=None):
  """(timed() -> world-steps/s, compile seconds, overflow count fn, data, one-step fn) of a
  jitted scan of ``n_steps`` batched steps."""
  d0 = make_data(jnp.asarray(qpos0, jnp.float32), jnp.asarray(qvel0, jnp.float32))
  nbody = d0.xfrc_applied.shape[1]
  xfrc = jnp.zeros((qpos0.shape[0], nbody, 6), jnp.float32)

  def one(d):
    return backend_step(d, xfrc)

  def run(d):
    def body(carry, _):
      d, flagged = carry
      d = one(d)
      if overflow is not None:
        flagged = flagged | overflow(d)
      return (d, flagged), None
    flagged = jnp.zeros(qpos0.shape[0], bool)
    return jax.lax.scan(body, (d, flagged), None, length=n_steps)[0]

  start = time.perf_counter()
  compiled = jax.jit(run).lower(d0).compile()
  compile_seconds = time.perf_counter() - start
  last = {}

  def timed() -> float:
    start = time.perf_counter()
    d, flagged = jax.block_until_ready(compiled(d0))
    rate = qpos0.shape[0] * n_steps / (time.perf_counter() - start)
    last["flagged"] = int(np.asarray(flagged).sum())
    last["finite"] = bool(np.isfinite(np.asarray(d.qpos)).all())
    return rate

  return timed, compile_seconds, last, d0, one


def bench_scene(name: str, args) -> dict:
  path = pathlib.Path(name) if name.endswith(".yaml") else REPO / "configs" / f"{name}.yaml"
  config = mwbx.load_config(path)
  distinct = min(args.distinct_states or args.batch, args.batch)
  with mwbx.Sampler(config, backend="native", chunk_size=args.batch) as sampler:
    scene = sampler.scene
    qpos0, qvel0 = initial_states(sampler, distinct)
  model = scene.model
  if args.start_time > 0:
    qpos0, qvel0 = advance(model, qpos0, qvel0, args.start_time)
  elif args.sleep:  # bodies asleep from the start stay so only at the MJCF's exact pose
    qpos0 = exact_pose(qpos0, model)
  # --distinct-states: the batch repeats the first N worlds (N worlds' advance, not the batch's).
  repeat = lambda x: np.tile(x, (-(-args.batch // distinct), 1))[:args.batch]
  qpos0, qvel0 = repeat(qpos0), repeat(qvel0)
  threads = os.cpu_count()
  # --sleep: island sleep on both sides (native: MuJoCo C; mjx:warp: MuJoCo Warp under Newton);
  # its rows are named "+sleep" and sit beside the awake ones.
  sleep = sleep_lib.resolve(model, True, config.sim.sleep_tolerance) if args.sleep else None
  native_model = model if sleep is None else sleep_lib.sleeping_copy(model, sleep)
  tag = "+sleep" if sleep is not None else ""
  start = time.perf_counter()
  budget = resolve_contact_budget(scene, config.sim.mjx)
  if sleep is not None and not budget.nvmax:  # the pilot slept only where the config's sim.sleep says
    budget = budget._replace(nvmax=model.nv)
  pilot_seconds = time.perf_counter() - start
  engines = {}
  if "bare" in args.engines:
    bare_mx = mjx.put_model(model, impl="jax")
    bare_base = mjx.make_data(model, impl="jax")
    engines["mjx:bare"] = mjx_engine(
        lambda d, x: jax.vmap(mjx.step, in_axes=(None, 0))(bare_mx, d.replace(xfrc_applied=x)),
        lambda q, v: jax.vmap(lambda q, v: bare_base.replace(qpos=q, qvel=v))(q, v),
        qpos0, qvel0, args.bare_steps)
  backends = {}
  for impl, name, packed in (("jax", "jax", None), ("jax", "every", False)):
    if name in args.engines:
      backend = backends[name] = mjx_backend.backend_for(scene, impl, budget, pack_rows=packed)
      key = "mjx:jax every row" if name == "every" else f"mjx:{impl}"
      engines[key] = mjx_engine(backend.step, backend.make_data, qpos0, qvel0, args.steps, backend.overflow)
  settings_of, same_as = {}, {}  # mjx:warp variants: settings per row; a variant equal to an earlier one is not rerun
  if "warp" in args.engines:
    for key, settings in warp_variants(args, model, config):
      earlier = next((k for k, s in settings_of.items() if s[:3] == settings[:3]), None)
      settings_of[key] = settings
      if earlier is not None:
        same_as[key] = earlier
        continue
      if sleep is not None:  # MuJoCo Warp sleeps under Newton only
        key = f"{key}{tag}"
        settings = warp_solver.warp_solver_settings(sleep_lib.sleeping_copy(model, sleep), config.sim.mjx)
        settings_of[key] = settings
      backend = backends[key] = mjx_backend.backend_for(scene, "warp", budget, warp_solver=settings, sleep=sleep)
      engines[key] = mjx_engine(backend.step, backend.make_data, qpos0, qvel0, args.steps, backend.overflow)
  rates = {"native": 0.0, **{k: 0.0 for k in engines}}
  extra = {k: {} for k in engines}
  for _ in range(args.repeats):  # alternate, keep each one's best: the machine is shared
    rates["native"] = max(rates["native"], bench_rollout(native_model, qpos0, qvel0, args.native_steps, threads))
    for key, (timed, _, last, _, _) in engines.items():
      rates[key] = max(rates[key], timed())
      extra[key] = dict(last)
  rows = [{"engine": f"native{tag}", "what": f"bare mujoco.rollout, {threads} threads{', island sleep' * bool(tag)}",
           "batch": args.batch,
           "steps": args.native_steps, "world_steps_per_s": rates["native"], "compile_s": None}]
  for key, (_, compile_seconds, _, d0, one) in engines.items():
    row = {"engine": key, "batch": args.batch, "steps": args.bare_steps if key == "mjx:bare" else args.steps,
           "world_steps_per_s": rates[key], "compile_s": compile_seconds,
           "ratio_to_native": rates[key] / rates["native"], "native_world_steps_per_s": rates["native"],
           **extra[key]}
    row["what"] = {"mjx:bare": "jax.vmap(mjx.step), no budget",
                   "mjx:jax": "MJX impl jax, box broadphase, contact budget, solver limits, each world's"
                              " solve over its rows in use",
                   "mjx:jax every row": "mjx:jax with MJX's solve over every budget row (sim.mjx.pack_rows: false)",
                   }.get(key, "MuJoCo Warp via MJX, pools from the budget"
                         + (f", island sleep (nvmax {budget.nvmax})" if tag and key.endswith(tag) else ""))
    if key in settings_of:
      row["what"] += f"; solver {settings_of[key].describe()}"
      row["warp_solver"] = settings_of[key]._asdict()
    if key == "mjx:jax" and not backends["jax"].pack_rows:  # the default off the CPU
      row["what"] = "MJX impl jax, box broadphase, contact budget, solver limits, solve over every row"
    if args.cost and key.startswith("mjx:warp"):  # its kernels are custom calls: XLA's cost analysis sees nothing
      row["cost"] = {"error": "MuJoCo Warp's kernels are custom calls XLA's cost analysis does not see into"}
    elif args.cost:
      try:
        row["cost"] = cost_per_world_step(one, d0, args.batch)
      except Exception as err:  # pylint: disable=broad-except
        row["cost"] = {"error": f"{type(err).__name__}: {err}"[:200]}
    if args.stages and key == "mjx:jax":
      row["stages_ms"], row["solver_detail"] = stage_times(backends["jax"], d0)
    rows.append(row)
  for key, earlier in same_as.items():  # the same settings as a row run above: its figures, under this name too
    row = dict(next(r for r in rows if r["engine"] == earlier), engine=key, same_as=earlier)
    row["what"] = f"{row['what']} (the same settings as {earlier}: not run again)"
    rows.append(row)
  by = {r["engine"]: r for r in rows}
  ratios = {k: r["world_steps_per_s"] / rates["native"] for k, r in by.items() if k != f"native{tag}"}
  if "mjx:bare" in by and "mjx:jax" in by:
    ratios["jax_over_bare"] = by["mjx:jax"]["world_steps_per_s"] / by["mjx:bare"]["world_steps_per_s"]
  return {"rows": rows, "ratios": ratios, "budget": budget._asdict(), "pilot_s": pilot_seconds,
          "start_time": args.start_time, "distinct_states": distinct,
          "mjx_solver": {"iterations": min(int(model.opt.iterations), mjx_backend.SOLVER_ITERATIONS),
                         "ls_iterations": min(int(model.opt.ls_iterations), mjx_backend.LS_ITERATIONS)},
          "nbody": model.nbody, "nv": model.nv, "ngeom": model.ngeom, "timestep": model.opt.timestep}


def time_sample(worlds: int) -> dict:
  """Times ``mwbx sample configs/siggraph.yaml --backend mjx --worlds N`` once, as a user first runs it
  (a fresh process with an empty compilation cache: pilot and compile included)."""
  with tempfile.TemporaryDirectory() as tmp:
    command = ["mwbx", "sample", "configs/siggraph.yaml", "--backend", "mjx", "--worlds", str(worlds)]
    load = os.getloadavg()[0]
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "mwbx.cli", *command[1:], "--out", f"{tmp}/bank"], cwd=REPO,
                   check=True, env=dict(os.environ, MWBX_CACHE_DIR=f"{tmp}/jax-cache"))
    wall = time.perf_counter() - start
    bank = mwbx.Bank.load(f"{tmp}/bank")
    return {"command": " ".join(command), "wall_s": wall, "worlds": worlds, "valid": int(bank.valid.sum()),
            "over_budget": int((bank.flags & mwbx.FLAG_CONTACT_OVERFLOW > 0).sum()), "load_average": load}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--scenes", default=",".join(SCENES), help="shipped scene names or config paths")
  parser.add_argument("--engines", default="bare,jax,warp",
                      help="MJX engines to run besides native (bare, jax, every: jax solving over every"
                           " budget row, warp)")
  parser.add_argument("--batch", type=int, default=64, help="worlds per batch (every engine)")
  parser.add_argument("--steps", type=int, default=50, help="steps per timed run of mjx:jax and mjx:warp")
  parser.add_argument("--bare-steps", type=int, default=5, help="steps per timed run of bare MJX (slow)")
  parser.add_argument("--native-steps", type=int, default=500, help="steps per timed run of native")
  parser.add_argument("--repeats", type=int, default=2)
  parser.add_argument("--previous", metavar="JSON",
                      help="an earlier run's backends.json (e.g. of an earlier commit): its mjx:jax row of each"
                           " scene is kept beside the new one")
  parser.add_argument("--stages", action="store_true",
                      help="also time the parts of mjx:jax's step (collision, solver, ...) apart")
  parser.add_argument("--start-time", type=float, default=0.0, metavar="S",
                      help="time every engine from the states after S seconds of un-perturbed MuJoCo C")
  parser.add_argument("--no-cost", dest="cost", action="store_false", help="skip XLA's cost analysis")
  parser.add_argument("--time-sample", type=int, default=0, metavar="N",
                      help="also time `mwbx sample configs/siggraph.yaml --backend mjx --worlds N` once")
  parser.add_argument("--keep-engines", action="store_true",
                      help="keep the rows of engines not run now from --out's earlier run of the same scene"
                           " (scripts/gpu_check.sh runs each engine in its own process)")
  parser.add_argument("--warp-solver", choices=("auto", "newton", "cg", "shipped"),
                      help="mjx:warp under this solver (shipped: the model's own options) instead of mwbx's choice")
  parser.add_argument("--warp-tolerance", type=float, help="mjx:warp's solver tolerance (default: mwbx's choice)")
  parser.add_argument("--warp-iterations", type=int, help="mjx:warp's solver iterations (default: the model's)")
  parser.add_argument("--warp-variants", default="", metavar="A,B",
                      help=f"run mjx:warp under each of these named settings, a row each, in one process"
                           f" ({', '.join(WARP_VARIANTS)}; overrides the three options above)")
  parser.add_argument("--distinct-states", type=int, default=0, metavar="N",
                      help="draw (and advance to --start-time) only N worlds; the batch repeats them")
  parser.add_argument("--sleep", action="store_true",
                      help="island sleep on both sides: native and mjx:warp (Newton); rows named +sleep")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "backends.json"))
  args = parser.parse_args()
  args.engines = args.engines.split(",")
  args.warp_variants = [v for v in args.warp_variants.split(",") if v]
  if (args.warp_tolerance is not None and not 0 < args.warp_tolerance < 1) or (
      args.warp_iterations is not None and args.warp_iterations < 1):
    parser.error("--warp-tolerance must be in (0, 1) and --warp-iterations at least 1")
  out = pathlib.Path(args.out)
  result = {"machine": machine(), "batch": args.batch, "gpu_roofline": GPU, "published": PUBLISHED, "scenes": {}}
  if out.exists():  # scenes not run now stay as they were measured (each names its machine)
    old = json.loads(out.read_text())
    result["scenes"] = old.get("scenes", {})
    if "sample_timing" in old:
      result["sample_timing"] = old["sample_timing"]
  m = result["machine"]
  print(f"machine: {m['platform']}, {m['cores']} cores, jax {m['jax']} on {m['jax_backend']}, "
        f"load {m['load_average']:.1f}", flush=True)
  if args.time_sample:
    result["sample_timing"] = time_sample(args.time_sample)
    print(f"{result['sample_timing']}", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
  previous = json.loads(pathlib.Path(args.previous).read_text())["scenes"] if args.previous else {}
  for name in filter(None, args.scenes.split(",")):
    s = bench_scene(name, args)
    s["machine"] = m
    earlier = result["scenes"].get(pathlib.Path(name).stem)
    if args.keep_engines and earlier:  # each kept row's ratio is to the native of its own run
      ran = {(r["engine"], r["batch"]) for r in s["rows"]}  # a row per engine and batch (the tower at 512 and 2048)
      s["rows"] += [r for r in earlier["rows"] if (r["engine"], r["batch"]) not in ran]
      s["ratios"] = {**earlier.get("ratios", {}), **s["ratios"]}
    old = previous.get(pathlib.Path(name).stem)
    if old:  # the same scene's mjx:jax as an earlier commit ran it
      row = next((r for r in old["rows"] if r["engine"] == "mjx:jax"), None)
      s["previous"] = {"mjx:jax": row, "budget": old["budget"], "machine": old["machine"],
                       "start_time": old.get("start_time", 0.0), "mjx_solver": old.get("mjx_solver")}
    result["scenes"][pathlib.Path(name).stem] = s
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"\n{name} (budget: {contact_budget.ContactBudget(**s['budget']).describe()})")
    print(f"  {'engine':20}{'batch':>6}{'steps':>6}{'world-steps/s':>15}{'vs native':>11}{'compile s':>11}"
          f"{'flagged':>9}{'flops/step':>12}{'bytes/step':>12}{'H200 bound':>12}")
    for r in s["rows"]:
      cost = r.get("cost") or {}
      bound = cost.get("roofline_steps_per_s")
      print(f"  {r['engine']:20}{r['batch']:>6}{r['steps']:>6}{r['world_steps_per_s']:>15,.0f}"
            f"{r.get('ratio_to_native', 1.0):>10.3f}x{(r['compile_s'] or 0):>11.1f}"
            f"{r.get('flagged', 0):>9}{cost.get('flops', 0):>12.3g}{cost.get('bytes_accessed', 0):>12.3g}"
            f"{(f'{bound:,.0f}' if bound else '-'):>12}", flush=True)
  print(f"\nwrote {out}")


if __name__ == "__main__":
  main()
