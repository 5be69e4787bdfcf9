"""Unattended goal-seeking (mwbx.solve) and guided sampling, measured in one run.

Three parts, each against a baseline measured here:

  siggraph   sample worlds of configs/siggraph.yaml, then `mwbx.solve` for all
             eight letters in their slots within a wall-time budget. Baseline:
             plain sampling's odds, estimated from the sampled bank as the
             product of the per-letter rates (the paper: ~1e-11), and the
             paper's person, about an hour.
  staircase  the same on configs/spiral_staircase.yaml (reach the ground floor
             without falling off) within a budget.
  guided     queries about 1 % of plain worlds meet: the toss's ball lands in
             one of the two far bins (configs/toss.yaml: decided mostly by the
             throw, the randomized velocity) and quickstart's box_a ends at the
             back (decided mostly by perturbations at its collisions). Guided
             sampling (`mwbx.search.guided_sample`, R rounds of M worlds)
             against plain sampling of at least as many world-steps, once per
             seed (3 by default), pooled: matching worlds per million
             world-steps, guided over plain (goal >= 10x). Also the share of
             guided matches whose initial state matches again under fresh
             perturbations (what a proposal over initial states can control).

  robustness siggraph and staircase again with other seeds (--robustness-seeds 1,2).
  chain      configs/chain_reaction.yaml: 16 worlds sampled per seed (--chain-seeds
             0,1,2), those already meeting every query dropped, then solve for
             the whole ordered chain of contact events within the budget.

  .venv/bin/python scripts/bench_solve.py [--parts siggraph,staircase,guided,robustness,chain] [--budget-s 600]

Writes out/bench/solve.json (and solve_<scene>.png progress plots) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import shutil
import subprocess
import time

import jax
import numpy as np

import mwbx
from mwbx.progress import reporter
from mwbx.queries import Query

REPO = pathlib.Path(__file__).resolve().parents[1]
# quickstart's box_a (it slides down the upper ramp) ends at the back of the floor.
RARE_QUERY = Query.region((-1.4, 0.5, 0.0), (1.4, 1.2, 0.5), bodies="box_a", window=(3.5, None),
                          name="box_a_ends_at_the_back")
# The toss's ball (mwbx/assets/toss.xml) lands in one of the two far bins.
FAR_BINS = Query.region((1.3, -0.1, 0.0), (1.8, 0.1, 0.25), bodies="ball", window=(2.5, None), name="far_bins")
GUIDED_CASES = {"toss": ("toss.yaml", FAR_BINS), "quickstart": ("quickstart.yaml", RARE_QUERY)}
REPEATS = 8  # fresh perturbation draws per guided match, for the repeat rate


def _machine() -> dict:
  commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                          text=True).stdout.strip()
  return {"cpus": os.cpu_count(), "machine": platform.machine(), "backend": jax.default_backend(),
          "commit": commit, "load_average": os.getloadavg()[0]}


def solve_scene(name: str, worlds: int, budget_s: float, samples: int, out: pathlib.Path, seed: int = 0,
                save_bank: bool = False, unsolved_start: bool = False, budget_steps: float | None = None) -> dict:
  """Samples ``worlds`` worlds of the scene and solves its query file; ``seed``
  keys both the sampling and the search. ``save_bank``: keep the solved bank
  in ``out/../solve_<scene>_seed<seed>``. ``unsolved_start``: drop the sampled
  worlds that already meet every query first (the search must make one).
  ``budget_steps``: a world-step budget instead of ``budget_s`` (the search
  then takes the same path whatever else the machine runs)."""
  config = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  load_before = os.getloadavg()[0]  # 1-minute load average: the machine may be shared
  start = time.perf_counter()
  with reporter(f"{name}: sample") as update:
    bank = mwbx.sample(config, worlds, jax.random.key(seed), backend="native", progress=update)
  sample_s = time.perf_counter() - start
  queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{name}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  rates = each[bank.valid].mean(axis=0)
  dropped = 0
  if unsolved_start and each.all(axis=1).any():
    dropped = int(each.all(axis=1).sum())
    bank = bank.drop(bank.world_ids[each.all(axis=1)])
  with reporter(f"{name}: solve") as update:
    budget = (mwbx.search.Budget(world_steps=int(budget_steps)) if budget_steps else
              mwbx.search.Budget(seconds=budget_s))
    options = mwbx.SolveOptions(budget=budget, key=jax.random.key(seed),
                                samples=samples, backend="native")
    result = mwbx.solve(bank, queries, options, progress=update)
  wall = time.perf_counter() - start
  load_after = os.getloadavg()[0]
  refined = [s for s in result.steps if s.refined >= 0]
  print(f"{name} seed {seed}: {result.message}", flush=True)
  if save_bank:  # the solved world's bank, e.g. for scripts/paper_scenes.py --bank; replaces an older run's
    keep = out.parent / f"solve_{name}_seed{seed}"
    shutil.rmtree(keep, ignore_errors=True)
    result.bank.save(keep)
  plot = mwbx.search.progress_plot(result.steps, out.parent / (f"solve_{name}.png" if seed == 0 else
                                                             f"solve_{name}_seed{seed}.png"),
                                   title=f"{name}: queries met by the best world")
  return {
      "scene": name, "seed": seed, "worlds_sampled": worlds, "sample_seconds": sample_s,
      "valid": int(bank.valid.sum()), "unstable": int((~bank.valid).sum()),
      "queries": [q.name for q in queries.queries], "per_query_rate": rates.tolist(),
      "sampled_best_met": int(each.sum(axis=1).max()), "sampled_all_met": int(each.all(axis=1).sum()),
      "dropped_before_solving": dropped,
      "independent_estimate": float(np.prod(rates)),
      "budget_seconds": budget_s, "samples_per_refinement": samples,
      **({"budget_world_steps": int(budget_steps)} if budget_steps else {}),
      "solved": bool(result.solved), "satisfied": result.satisfied, "n_queries": result.n_queries,
      "message": result.message, "world": result.world,
      "lineage_depth": int(len(result.bank.ancestors(result.world))),
      "refinements": len(refined), "world_steps": result.steps[-1].world_steps,
      "solve_seconds": result.steps[-1].seconds, "wall_seconds": wall,
      "first_all_met_seconds": next((s.seconds for s in result.steps if s.satisfied == result.n_queries), None),
      "curve": [[s.seconds, s.world_steps, s.satisfied] for s in result.steps],
      "places_curve": [s.places for s in result.steps],
      "plot": pathlib.Path(plot).name,
      "load_average_before": load_before, "load_average_after": load_after,
  }


def guided_vs_plain(case: str, rounds: int, batch: int, seeds: list[int]) -> dict:
  """Per seed: guided sampling (default optimiser), then plain sampling of at
  least as many world-steps; pooled over the seeds. Plus the repeat rate: the
  guided matches' initial states rerun with fresh perturbations."""
  config_name, query = GUIDED_CASES[case]
  config = mwbx.load_config(REPO / "configs" / config_name)
  runs = []
  with mwbx.Sampler(config, backend="native") as sampler:
    sampler.run(8, jax.random.key(99))  # warm-up: compile once, outside both timings
    for seed in seeds:
      start = time.perf_counter()
      with reporter(f"{case}: guided (seed {seed})") as update:
        guided = mwbx.search.guided_sample(sampler, [query], rounds=rounds, batch=batch,
                                           key=jax.random.key(seed), progress=update)
      guided_s = time.perf_counter() - start
      g_steps = int(guided.bank.steps.sum())
      hits = mwbx.evaluate(guided.bank, [query])
      g_match = int(hits.sum())
      late = guided.rounds[rounds // 2:]
      start = time.perf_counter()
      p_steps, p_match, p_worlds = 0, 0, 0
      with reporter(f"{case}: plain (seed {seed})") as update:
        while p_steps < g_steps:
          part, _ = sampler.run(batch, jax.random.key(1000 + seed), first_world=p_worlds, progress=update)
          p_steps += int(part.steps.sum())
          p_match += int(mwbx.evaluate(part, [query]).sum())
          p_worlds += part.n_worlds
      plain_s = time.perf_counter() - start
      # Up to 16 guided matches, each rerun REPEATS times from its own initial state.
      ids = guided.bank.world_ids[hits][:16]
      noise = np.array([guided.bank.lineage[str(int(i))]["proposal"]["noise"] for i in ids], np.float32)
      repeat = None
      if len(noise):
        again, _ = sampler.run(len(noise) * REPEATS, jax.random.key(5000 + seed),
                               noise=np.repeat(noise, REPEATS, axis=0))
        repeat = float(mwbx.evaluate(again, [query]).mean())
      runs.append({
          "seed": seed, "guided_worlds": guided.bank.n_worlds, "guided_world_steps": g_steps,
          "guided_matches": g_match, "guided_seconds": guided_s,
          "late_matches": sum(r.matches for r in late), "late_world_steps": sum(r.world_steps for r in late),
          "per_round_matches": [r.matches for r in guided.rounds],
          "per_round_scale": [r.scale_mean for r in guided.rounds],
          "plain_worlds": p_worlds, "plain_world_steps": p_steps, "plain_matches": p_match,
          "plain_seconds": plain_s, "repeat_rate": repeat, "repeated_matches": int(len(noise))})
  total = lambda key: sum(r[key] for r in runs)
  plain_rate = total("plain_matches") / total("plain_world_steps") * 1e6
  guided_rate = total("guided_matches") / total("guided_world_steps") * 1e6
  late_rate = total("late_matches") / total("late_world_steps") * 1e6
  for r in runs:
    r["ratio"] = (r["guided_matches"] / r["guided_world_steps"]) / max(r["plain_matches"] / r["plain_world_steps"], 1e-30)
  repeats = [r["repeat_rate"] for r in runs if r["repeat_rate"] is not None]
  return {
      "case": case, "config": f"configs/{config_name}", "query": query.name, "rounds": rounds, "batch": batch,
      "optimizer": f"adam({mwbx.search.guided.MEAN_LEARNING_RATE}) on means, "
                   f"adam({mwbx.search.guided.SCALE_LEARNING_RATE}) on log scales",
      "seeds": runs,
      "guided": {"worlds": total("guided_worlds"), "world_steps": total("guided_world_steps"),
                 "matches": total("guided_matches"), "per_million_steps": guided_rate,
                 "late_per_million_steps": late_rate},
      "plain": {"worlds": total("plain_worlds"), "world_steps": total("plain_world_steps"),
                "matches": total("plain_matches"), "rate": total("plain_matches") / total("plain_worlds"),
                "per_million_steps": plain_rate},
      "ratio": guided_rate / plain_rate if plain_rate else None,
      "late_ratio": late_rate / plain_rate if plain_rate else None,
      "repeat_rate": float(np.mean(repeats)) if repeats else None,
  }


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--parts", default="siggraph,staircase,guided")
  parser.add_argument("--budget-s", type=float, default=600.0, help="solve budget per scene, s (paper goal 600)")
  parser.add_argument("--staircase-budget-s", type=float, default=300.0)
  parser.add_argument("--worlds", type=int, default=64, help="worlds sampled before solving")
  parser.add_argument("--samples", type=int, default=32, help="refined worlds per refinement")
  parser.add_argument("--rounds", type=int, default=24)
  parser.add_argument("--batch", type=int, default=64)
  parser.add_argument("--seeds", default="1,2,3", help="guided vs plain: one run per seed, pooled")
  parser.add_argument("--guided-cases", default="toss,quickstart", help=f"of {', '.join(GUIDED_CASES)}")
  parser.add_argument("--robustness-seeds", default="",
                      help="part 'robustness': siggraph and staircase again with these seeds, e.g. 1,2")
  parser.add_argument("--robustness-scenes", default="siggraph,spiral_staircase")
  parser.add_argument("--budget-world-steps", type=float, default=None,
                      help="robustness: a world-step budget instead of the scenes' seconds (the same search path"
                           " under any load; its time is then world-steps over --reference-rate)")
  parser.add_argument("--reference-rate", type=float, default=27000.0,
                      help="world-steps/s of a solve alone on this machine (with --budget-world-steps)")
  parser.add_argument("--chain-seeds", default="0,1,2", help="part 'chain': one solve per seed")
  parser.add_argument("--save-banks", action="store_true",
                      help="robustness: keep each solved bank in out/bench/solve_<scene>_seed<seed>")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "solve.json"))
  args = parser.parse_args()
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  parts = args.parts.split(",")
  result = json.loads(out.read_text()) if out.exists() else {}
  for key in ("siggraph", "staircase", "guided"):  # parts kept from an earlier run keep its machine line
    if key in result and "machine" not in result[key] and "machine" in result:
      result[key]["machine"] = result["machine"]
  result["machine"] = _machine()
  if "siggraph" in parts:
    result["siggraph"] = solve_scene("siggraph", args.worlds, args.budget_s, args.samples, out)
    result["siggraph"]["machine"] = result["machine"]
    out.write_text(json.dumps(result, indent=1))
  if "staircase" in parts:
    result["staircase"] = solve_scene("spiral_staircase", args.worlds, args.staircase_budget_s, args.samples, out)
    result["staircase"]["machine"] = result["machine"]
    out.write_text(json.dumps(result, indent=1))
  if "robustness" in parts and args.robustness_seeds:
    runs = list(result.get("robustness", {}).get("runs", []))
    for seed in (int(x) for x in args.robustness_seeds.split(",")):
      for name in args.robustness_scenes.split(","):
        budget = args.budget_s if name == "siggraph" else args.staircase_budget_s
        steps = args.budget_world_steps
        r = solve_scene(name, args.worlds, budget, args.samples, out, seed, save_bank=args.save_banks,
                        budget_steps=steps)
        runs = [x for x in runs if (x["scene"], x["seed"]) != (name, seed)]
        extra = ({"budget_world_steps": r["budget_world_steps"], "reference_rate": args.reference_rate,
                  "budget_seconds": r["budget_world_steps"] / args.reference_rate} if steps else {})
        runs.append({k: r[k] for k in ("scene", "seed", "solved", "satisfied", "n_queries", "refinements",
                                       "world_steps", "solve_seconds", "message", "world", "worlds_sampled",
                                       "queries", "per_query_rate", "independent_estimate", "load_average_before",
                                       "load_average_after", "budget_seconds")} | extra
                    | {"commit": result["machine"]["commit"]})
        print(f"{name} seed {seed}: {r['message']}", flush=True)
        result["robustness"] = {"runs": sorted(runs, key=lambda x: (x["scene"], x["seed"]))}
        out.write_text(json.dumps(result, indent=1))
  if "chain" in parts:
    runs = []
    for seed in (int(x) for x in args.chain_seeds.split(",")):
      r = solve_scene("chain_reaction", 16, args.budget_s, args.samples, out, seed, unsolved_start=True)
      runs.append({k: r[k] for k in ("seed", "solved", "satisfied", "n_queries", "refinements", "world_steps",
                                     "solve_seconds", "message", "world", "queries", "per_query_rate",
                                     "sampled_all_met", "dropped_before_solving", "load_average_before",
                                     "load_average_after")} | {"commit": result["machine"]["commit"]})
      result["chain"] = {"runs": runs, "budget_seconds": args.budget_s, "machine": result["machine"]}
      out.write_text(json.dumps(result, indent=1))
  if "guided" in parts:
    result["guided"] = {case: guided_vs_plain(case, args.rounds, args.batch, [int(x) for x in args.seeds.split(",")])
                        for case in args.guided_cases.split(",")}
    result["guided"]["machine"] = result["machine"]
  result["machine"]["load_average_after"] = os.getloadavg()[0]
  out.write_text(json.dumps(result, indent=1))

  m = result["machine"]
  print(f"{m['cpus']}-core {m['machine']} ({m['backend']}), commit {m['commit']}")
  for key in ("siggraph", "staircase"):
    if key in result:
      r = result[key]
      print(f"{r['scene']:<17} {r['message']}; plain-sampling estimate {r['independent_estimate']:.1e} per world")
  for g in (v for k, v in result.get("guided", {}).items() if k != "machine"):
    print(f"guided {g['case']:<10} {g['guided']['matches']} of {g['guided']['worlds']} worlds match"
          f" ({g['guided']['per_million_steps']:.1f} per million world-steps; last half"
          f" {g['guided']['late_per_million_steps']:.1f}) vs plain {g['plain']['matches']} of"
          f" {g['plain']['worlds']} ({g['plain']['per_million_steps']:.1f}): ratio"
          f" {g['ratio'] or float('nan'):.1f}x (last half {g['late_ratio'] or float('nan'):.1f}x);"
          f" repeat rate {g['repeat_rate'] if g['repeat_rate'] is not None else float('nan'):.0%}")
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
