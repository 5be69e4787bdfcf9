"""``backend: auto`` where there is a choice: a short timed probe of each engine.

On a machine without a GPU, ``auto`` is native (MuJoCo C on every core) and
nothing here runs: no MJX is compiled. Where JAX sees a GPU, the sampler
first sizes the contact budget (the native pilot), then times each available
engine (native on all cores, mjx:warp, mjx:jax) on a few chunks of the
scene's first :data:`PROBE_SECONDS`, prints a small table and samples on the
fastest; an engine the probe found slower than native is never chosen.

:func:`probe_engines` is the choice itself, over engines given as callables
(testable with fake engines); :func:`probe_scene` builds the real ones.
"""

from __future__ import annotations

import importlib.util
import sys
from typing import Callable, Mapping, NamedTuple

import jax

from mwbx.batch_sim import sleep as sleep_lib
from mwbx.errors import MwbxError
from mwbx.qpos_store import RawQposStore
from mwbx.scene import Scene

# Simulated seconds of each world a probe runs (from t = 0: the scene's start,
# which may be quieter than its middle) and chunks per engine (each at the
# batch size a run uses). Not tuned on a GPU: no GPU figures for the probe yet.
PROBE_SECONDS = 0.5
PROBE_CHUNKS = 2
PROBE_SEED = 0
BASELINE = "native"
# mjx:warp with island sleep (under Newton), probed where sleep is on for the
# native engine: a scene of many resting bodies may run faster so on a GPU, or
# slower (nothing asleep costs: the compaction), which only a timing tells.
WARP_SLEEP = "mjx:warp+sleep"

# An engine run of the probe: () -> (world-steps taken, seconds spent stepping, compile excluded).
EngineRun = Callable[[], "tuple[int, float]"]


class ProbeRow(NamedTuple):
  """One engine's probe.

  Attributes:
    engine: ``native``, ``mjx:warp`` or ``mjx:jax``.
    world_steps: physics steps summed over the probe's worlds.
    seconds: stepping time, s (compile excluded).
    error: why the engine could not run (then it is not chosen), else None.
  """

  engine: str
  world_steps: int
  seconds: float
  error: str | None = None

  @property
  def world_steps_per_second(self) -> float:
    ok = self.error is None and self.seconds > 0 and self.world_steps > 0
    return self.world_steps / self.seconds if ok else 0.0


class ProbeResult(NamedTuple):
  """The probe's rows (in the order timed) and the engine chosen."""

  choice: str
  rows: tuple

  def table(self) -> str:
    """The rows as a small table, then the choice."""
    base = next((r.world_steps_per_second for r in self.rows if r.engine == BASELINE), 0.0)
    lines = [f"  {'engine':<16}{'world-steps/s':>15}{'vs native':>11}"]
    for r in self.rows:
      if r.error is not None:
        lines.append(f"  {r.engine:<16}  failed: {r.error}")
        continue
      ratio = f"{r.world_steps_per_second / base:.2f}x" if base > 0 else "-"
      lines.append(f"  {r.engine:<16}{r.world_steps_per_second:>15,.0f}{ratio:>11}")
    lines.append(f"  chosen: {self.choice}")
    return "\n".join(lines)


def gpu_visible() -> bool:
  """Whether JAX sees a GPU (``jax.devices('gpu')`` non-empty)."""
  try:
    return len(jax.devices("gpu")) > 0
  except RuntimeError:  # no GPU platform: JAX raises rather than returning []
    return False


def probe_engines(engines: Mapping[str, EngineRun], out=None, header: str = "") -> ProbeResult:
  """Times each engine once and chooses the fastest, never one slower than native.

  Args:
    engines: engine name -> its run (``() -> (world_steps, seconds)``), timed
      in this order; ``native`` among them is the baseline. An engine whose
      run raises is shown as failed and not chosen.
    out: where the table goes (a text stream; None: ``sys.stderr``).
    header: a line printed above the table.

  Returns:
    the :class:`ProbeResult`: the fastest engine by world-steps/s among
    native and those strictly faster than native (a tie keeps native); where
    native itself failed, the fastest that ran.

  Raises:
    MwbxError: no engine ran.
  """
  rows = []
  for name, run in engines.items():
    try:
      steps, seconds = run()
      rows.append(ProbeRow(name, int(steps), float(seconds)))
    except Exception as err:  # pylint: disable=broad-except  # e.g. out of GPU memory: that engine is out
      rows.append(ProbeRow(name, 0, 0.0, f"{type(err).__name__}: {' '.join(str(err).split())}"[:160]))
  ran = [r for r in rows if r.world_steps_per_second > 0]
  if not ran:
    raise MwbxError("backend auto: no engine ran in the probe: "
                    + "; ".join(f"{r.engine}: {r.error or 'no steps'}" for r in rows))
  base = next((r for r in ran if r.engine == BASELINE), None)
  eligible = ran if base is None else [base] + [r for r in ran if r.world_steps_per_second >
                                                base.world_steps_per_second]
  best = eligible[0]
  for r in eligible[1:]:
    if r.world_steps_per_second > best.world_steps_per_second:
      best = r
  result = ProbeResult(best.engine, tuple(rows))
  stream = sys.stderr if out is None else out
  if header:
    print(header, file=stream)
  print(result.table(), file=stream, flush=True)
  return result


def probe_scene(sampler_cls, scene, budget, warp_solver=None, out=None) -> ProbeResult:
  """Probes the engines available for ``scene`` (:func:`probe_engines`).

  Args:
    sampler_cls: :class:`mwbx.batch_sim.sampler.Sampler` (passed in: the
      sampler calls this module, which does not import it back).
    scene: the :class:`mwbx.scene.Scene`.
    budget: the MJX contact budget (after the pilot) the MJX engines run under.
    warp_solver: mjx:warp's solver settings (None: chosen from the model).
    out: where the table goes (None: ``sys.stderr``).
  """
  engines = {BASELINE: _engine_run(sampler_cls, scene, "native", None, budget, warp_solver)}
  cfg = scene.config
  for impl in _mjx_impls(cfg.sim.mjx_impl):
    engines[f"mjx:{impl}"] = _engine_run(sampler_cls, scene, "mjx", impl, budget, warp_solver)
    if impl == "warp" and warp_solver is None and sleep_lib.resolve(
        scene.model, cfg.sim.sleep, cfg.sim.sleep_tolerance).enabled:
      engines[WARP_SLEEP] = _engine_run(sampler_cls, scene, "mjx", impl, budget, None, sleep=True)
  header = (f"mwbx: backend auto: a GPU is visible; timing each engine on {PROBE_CHUNKS} chunks of the first"
            f" {min(PROBE_SECONDS, scene.config.sim.end_time):g} s (compile excluded)")
  return probe_engines(engines, out=out, header=header)


def _mjx_impls(mjx_impl: str) -> list[str]:
  """The MJX impls the probe times for the config's ``sim.mjx_impl``."""
  if mjx_impl != "auto":
    return [mjx_impl]
  return (["warp"] if importlib.util.find_spec("warp") is not None else []) + ["jax"]


def _engine_run(sampler_cls, scene, backend: str, impl: str | None, budget, warp_solver,
                sleep: bool | None = None) -> EngineRun:
  """One engine's probe run: a ``sampler_cls`` of the scene's first
  PROBE_SECONDS on that engine, PROBE_CHUNKS full chunks, qpos kept raw (no
  codec); ``sleep``: the run's ``sim.sleep`` (None: the config's)."""

  def run():
    cfg = scene.config
    sim = {"end_time": min(PROBE_SECONDS, cfg.sim.end_time)}
    if impl is not None:
      sim["mjx_impl"] = impl
    if sleep is not None:
      sim["sleep"] = sleep
    probe_cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update=sim)})
    with sampler_cls(Scene(probe_cfg), backend=backend, contact_budget=budget, warp_solver=warp_solver,
                 store=RawQposStore(scene.model.nq)) as sampler:
      n_worlds = PROBE_CHUNKS * sampler.batch_size(1 << 30)  # whole chunks, as a long run has them
      _, stats = sampler.run(n_worlds, jax.random.key(PROBE_SEED))
    return stats.world_steps, stats.run_seconds

  return run
