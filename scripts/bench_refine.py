"""Refinement against sampling from scratch, measured in one run (paper §5).

On configs/pachinko.yaml: sample N whole worlds (the baseline), then refine one
object of one of them from mid-way into N new worlds, on the same backend and
batch size. Reported:
  - refined samples/s vs whole worlds/s (stepping time, and wall time without
    compilation: stepping + bookkeeping + compression),
  - cost per simulated world-step, refinement over sampling (target <= 1.2),
    against whole worlds and against plain sampling of the same time span
    (every object simulated from the state at t_min): the scene's later,
    contact-heavy part costs more per step than its free-fall start,
  - the end-to-end speedup that starting at t_min gives,
  - how many objects ended up active,
  - on the native backend, the same refinement with inactive objects put on
    their stored path at frame boundaries only (playback="frame"; the
    default does it before every physics step).
Compile time is kept apart and never counted; both paths are warmed up first.

  .venv/bin/python scripts/bench_refine.py [--worlds 64] [--object NAME] [--few NAME] [--backend native]

Two cases: the object still moving most after mid-way (it meets others), and
``--few`` (default ball_6), one that touches few others.

Writes out/bench/refine.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import time

import jax
import numpy as np

import mwbx
from mwbx.refinement import RefineRequest, run_refinement

REPO = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--few", default="ball_6",
                      help="a second object to refine, one that touches few others (empty: none)")
  parser.add_argument("--config", default=str(REPO / "configs" / "pachinko.yaml"))
  parser.add_argument("--worlds", type=int, default=64)
  parser.add_argument("--object", default=None,
                      help="object to refine (default: the one that moves most after t_min)")
  parser.add_argument("--backend", default="native", choices=("native", "mjx"))
  parser.add_argument("--parent", type=int, default=0, help="id of the world to refine")
  parser.add_argument("--repeats", type=int, default=3, help="interleaved timed runs (fastest kept)")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "refine.json"))
  args = parser.parse_args()
  cases = []
  for obj in [args.object] + ([args.few] if args.few else []):
    args.object = obj
    cases.append(measure(args))
  result = dict(cases[0], cases=cases)
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(json.dumps(result, indent=2))
  print(f"wrote {out}")


def measure(args) -> dict:
  """One refinement case against sampling (see the module docstring); prints its table."""
  config = mwbx.load_config(args.config)
  n = args.worlds
  sampler = mwbx.Sampler(config, backend=args.backend, chunk_size=n)
  sampler.run(n, jax.random.key(99))  # warm-up: compile kernels and codec

  def sample_once():
    start = time.perf_counter()
    bank, stats = sampler.run(n, jax.random.key(0))
    return bank, stats, time.perf_counter() - start - stats.compile_seconds

  bank, s, sample_wall = sample_once()
  row = bank.row_of(args.parent)
  if not bank.valid[row]:
    row = int(np.flatnonzero(bank.valid)[0])
  parent = int(bank.world_ids[row])
  t_min = 0.5 * (int(bank.frame_count[row]) - 1) / bank.record_fps
  if args.object is None:  # the object still moving most after t_min
    p0 = int(t_min * bank.query_fps)
    path = bank.com[row, p0:int(bank.com_count[row])]
    travel = {name: float(np.linalg.norm(np.diff(path[:, bank.select_bodies(name)], axis=0), axis=-1).sum())
              for name in bank.objects}
    args.object = max(travel, key=travel.get)

  def refine_once(playback, loop, progress=None):
    start = time.perf_counter()
    done = run_refinement(bank, RefineRequest(parent, [args.object], t_min=t_min, n_samples=n, key=jax.random.key(1),
                                          backend=args.backend, chunk_size=n, playback=playback, loop=loop), progress)
    new, stats = done.new, done.stats
    return new, stats, time.perf_counter() - start - stats.compile_seconds

  # name -> (playback, loop): the compiled per-world loop is the default; the
  # lockstep rollout loop (per step and per frame playback) is the one it replaced.
  variants = ({"compiled": ("step", "compiled"), "lockstep": ("step", "lockstep"), "frame": ("frame", "lockstep")}
              if args.backend == "native" else {"mjx": ("step", "auto")})
  main_variant = next(iter(variants))
  for playback, loop in variants.values():  # warm-up
    run_refinement(bank, RefineRequest(parent, [args.object], t_min=t_min, n_samples=n, key=jax.random.key(98),
                                   backend=args.backend, chunk_size=n, playback=playback, loop=loop))
  # Plain sampling of the same time span: every object simulated and perturbed
  # from the parent's state at t_min (same phase of the scene as refinement).
  from mwbx.refinement import stored_motion
  from mwbx.batch_sim.sampler import world_keys
  model = sampler.scene.model
  f0 = int(np.floor(t_min * bank.record_fps + 1e-6))
  stored = stored_motion.stored_path(model, bank.qpos_frames(parent), sampler.scene.body_ids, sampler.n_frames + 2,
                                 1 / bank.record_fps)
  qpos0 = np.tile(stored.qpos[f0], (n, 1))
  qvel0 = np.tile(stored_motion.central_velocity(model, stored, f0, 1 / bank.record_fps), (n, 1))
  span_keys = world_keys(jax.random.key(2), np.arange(n))[2]

  def span_once():
    out = sampler.backend.run_chunk(sampler.scene, sampler.params, qpos0, qvel0, span_keys, np.ones(n, bool),
                                    sampler.n_frames - f0)
    return out.run_seconds, int(out.steps.sum())

  span_once()  # warm-up
  # Interleaved repeats, fastest of each kept: the machine is shared.
  best = {}
  for _ in range(args.repeats):
    span = span_once()
    if "span" not in best or span[0] < best["span"][0]:
      best["span"] = span
    runs = {"sample": sample_once()[1:]}
    for name, (playback, loop) in variants.items():
      new_v, stats, wall = refine_once(playback, loop)
      runs[name] = (stats, wall)
      if name == main_variant:
        new = new_v
    for name, (stats, wall) in runs.items():
      if name not in best or stats.run_seconds < best[name][0].run_seconds:
        best[name] = (stats, wall)
  # When the first refined world is done (worlds finish one by one in the
  # compiled loop; the lockstep loop finishes them together).
  first_done = {}
  clock = time.perf_counter()

  def watch(p):
    if p.phase == "refining" and p.done >= 1 and "t" not in first_done:
      first_done["t"] = time.perf_counter() - clock
  refine_once(*variants[main_variant], progress=watch)
  sampler.close()
  s, sample_wall = best["sample"]
  r, refine_wall = best[main_variant]

  def variant(name):
    if name not in best:
      return None
    rs = best[name][0]
    return {"world_steps": rs.world_steps, "run_s": rs.run_seconds,
                      "us_per_world_step": 1e6 * rs.run_seconds / rs.world_steps,
                      "step_cost_ratio": (rs.run_seconds / rs.world_steps) / (s.run_seconds / s.world_steps),
                      "speedup_run": s.run_seconds / rs.run_seconds, "wall_s": best[name][1]}

  sample_step = s.run_seconds / s.world_steps
  refine_step = r.run_seconds / r.world_steps
  span_step = best["span"][0] / best["span"][1]
  frame_playback, lockstep = variant("frame"), variant("lockstep")
  for v in (frame_playback, lockstep):
    if v is not None:
      v["step_cost_ratio_same_span"] = v["us_per_world_step"] * 1e-6 / span_step
  active = np.array([len(new.lineage[str(int(i))]["active"]) for i in new.world_ids])
  # Activation against an exact test (MuJoCo's geom distance, same margin).
  from mwbx.refinement import exact_active
  both = bank.append(new)
  exact_sets = [set(exact_active(both, int(i))) for i in new.world_ids]
  exact = np.array([len(e) for e in exact_sets])
  subset = all(e <= set(new.lineage[str(int(i))]["active"]) for e, i in zip(exact_sets, new.world_ids))
  result = {
      "machine": f"{os.cpu_count()}-core {platform.machine()} CPU, no GPU" if jax.default_backend() == "cpu"
                 else jax.devices()[0].device_kind,
      "config": pathlib.Path(args.config).name, "backend": s.backend, "worlds": n, "repeats": args.repeats,
      "object": args.object, "parent": parent, "t_min_s": float(new.refine_time[0]),
      "parent_frames": int(bank.frame_count[row]),
      "sample": {"world_steps": s.world_steps, "run_s": s.run_seconds, "wall_s": sample_wall,
                 "worlds_per_s_run": n / s.run_seconds, "worlds_per_s_wall": n / sample_wall,
                 "us_per_world_step": 1e6 * sample_step, "compile_s": s.compile_seconds},
      "refine": {"world_steps": r.world_steps, "run_s": r.run_seconds, "wall_s": refine_wall,
                 "samples_per_s_run": n / r.run_seconds, "samples_per_s_wall": n / refine_wall,
                 "us_per_world_step": 1e6 * refine_step, "compile_s": r.compile_seconds,
                 "mean_active_objects": float(active.mean()), "max_active_objects": int(active.max()),
                 "max_perturbation_ratio": float(r.max_perturbation_ratio.max()),
                 "first_world_s": first_done.get("t"), "loop": variants[main_variant][1]},
      "activation": {"sphere_active": active.tolist(), "exact_active": exact.tolist(),
                     "ratio_mean": float(active.sum() / exact.sum()), "ratio_max": float((active / exact).max()),
                     "never_fewer": bool(subset)},
      "step_cost_ratio": refine_step / sample_step,
      "span_sampling": {"world_steps": best["span"][1], "run_s": best["span"][0],
                        "us_per_world_step": 1e6 * span_step},
      "step_cost_ratio_same_span": refine_step / span_step,
      "speedup_run": s.run_seconds / r.run_seconds,
      "speedup_wall": sample_wall / refine_wall,
      "steps_fraction": r.world_steps / s.world_steps,
      "refine_frame_playback": frame_playback,
      "refine_lockstep": lockstep,
  }
  print(f"{result['machine']}; {result['config']} on {result['backend']}, {n} worlds,"
        f" refining {args.object} of world {parent} from t_min = {result['t_min_s']:.3f} s"
        f" (parent {result['parent_frames']} frames)")
  print(f"{'':28}{'sampling':>14}{'refinement':>14}{'ratio':>10}")
  rows = [
      ("world-steps", s.world_steps, r.world_steps, r.world_steps / s.world_steps, "{:,.0f}"),
      ("us per world-step", 1e6 * sample_step, 1e6 * refine_step, result["step_cost_ratio"], "{:.2f}"),
      ("worlds/s (stepping)", n / s.run_seconds, n / r.run_seconds, result["speedup_run"], "{:.2f}"),
      ("worlds/s (wall, no compile)", n / sample_wall, n / refine_wall, result["speedup_wall"], "{:.2f}"),
      ("compile s", s.compile_seconds, r.compile_seconds, float("nan"), "{:.1f}"),
  ]
  for name, a, b, ratio, fmt in rows:
    print(f"{name:28}{fmt.format(a):>14}{fmt.format(b):>14}{ratio:>10.2f}")
  print(f"plain sampling of the same span (all objects simulated from t_min): {1e6 * span_step:.2f} us"
        f" per world-step; refinement / that = {refine_step / span_step:.2f}")
  if frame_playback is not None:
    print(f"with frame-boundary playback: {frame_playback['us_per_world_step']:.2f} us per world-step"
          f" (ratio {frame_playback['step_cost_ratio']:.2f}; {frame_playback['step_cost_ratio_same_span']:.2f}"
          f" against the same span), speedup {frame_playback['speedup_run']:.2f}")
  if lockstep is not None:
    print(f"lockstep rollout loop (the baseline it replaced): {lockstep['us_per_world_step']:.2f} us per world-step"
          f" ({lockstep['step_cost_ratio_same_span']:.2f} against the same span); compiled is"
          f" {lockstep['run_s'] / r.run_seconds:.2f}x faster")
  print(f"wall (warm, with compression) {refine_wall:.2f} s for {n} refined worlds; first world done after"
        f" {first_done.get('t', float('nan')):.2f} s")
  print(f"activation: sphere test {active.sum()} objects, exact geom-distance test {exact.sum()}"
        f" ({active.sum() / exact.sum():.2f}x; never fewer: {result['activation']['never_fewer']})")
  print(f"active objects per refined world: mean {active.mean():.2f}, max {active.max()}"
        f" (of {len(bank.objects)}); largest |perturbation|/(alpha|dv|) {r.max_perturbation_ratio.max():.3f}")
  return result


if __name__ == "__main__":
  main()
