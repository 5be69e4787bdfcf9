"""The paper's scenes on both backends: how many worlds come out valid or
unstable, and how many meet each query (no timings).

  .venv/bin/python scripts/scene_counts.py [--native-worlds 64] [--mjx-worlds 16] [--scenes siggraph,...]

Writes out/bench/scenes.json (docs/benchmarks.md is generated from it) and prints a table.
MJX runs on whatever device JAX has (a CPU here: slow, so fewer worlds).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import time

import jax

import mwbx
from mwbx.progress import reporter

REPO = pathlib.Path(__file__).resolve().parents[1]
SCENES = ("siggraph", "spiral_staircase", "refrigerator_toy")


def counts(scene: str, backend: str, worlds: int) -> dict:
  config = mwbx.load_config(REPO / "configs" / f"{scene}.yaml")
  start = time.perf_counter()
  with reporter(f"{scene} ({backend})") as update:
    bank = mwbx.sample(config, worlds, jax.random.key(0), backend=backend, progress=update)
  queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{scene}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  return {"scene": scene, "backend": backend, "worlds": worlds, "valid": int(bank.valid.sum()),
          "unstable": int((bank.flags & mwbx.FLAG_UNSTABLE > 0).sum()),
          "sim_errors": int((bank.flags & mwbx.FLAG_SIM_ERROR > 0).sum()),
          "at_rest": int(bank.at_rest.sum()),
          "per_query": {q.name: int(n) for q, n in zip(queries.queries, each.sum(axis=0))},
          "all_met": int(each.all(axis=1).sum()), "wall_seconds": time.perf_counter() - start,
          "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                   text=True).stdout.strip()}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--scenes", default=",".join(SCENES))
  parser.add_argument("--native-worlds", type=int, default=64)
  parser.add_argument("--mjx-worlds", type=int, default=16)
  parser.add_argument("--mjx-scenes", default=",".join(SCENES), help="scenes to sample on MJX too")
  parser.add_argument("--mjx-note", default="", help="why a scene was left off MJX, for the docs")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "scenes.json"))
  args = parser.parse_args()
  rows = []
  for scene in args.scenes.split(","):
    for backend, worlds in (("native", args.native_worlds), ("mjx", args.mjx_worlds)):
      if worlds > 0 and (backend == "native" or scene in args.mjx_scenes.split(",")):
        rows.append(counts(scene, backend, worlds))
        r = rows[-1]
        print(f"{scene:<18} {backend:<7} {r['valid']}/{r['worlds']} valid, {r['unstable']} unstable,"
              f" {r['sim_errors']} MuJoCo errors; all queries met by {r['all_met']}; {r['per_query']}", flush=True)
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  # Rows not run now (scene and backend) stay as they were measured (each names its commit).
  done = {(r["scene"], r["backend"]) for r in rows}
  kept = ([r for r in json.loads(out.read_text())["rows"] if (r["scene"], r["backend"]) not in done]
          if out.exists() else [])
  order = {name: i for i, name in enumerate(SCENES)}
  rows = sorted(kept + rows, key=lambda r: (order.get(r["scene"], len(order)), r["backend"] != "native"))
  previous_note = json.loads(out.read_text()).get("mjx_note") if out.exists() else None
  out.write_text(json.dumps({"machine": f"{os.cpu_count()}-core {platform.machine()}, JAX on "
                                        f"{jax.default_backend()}", "rows": rows,
                             "mjx_note": args.mjx_note or previous_note or "not run"}, indent=1))
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
