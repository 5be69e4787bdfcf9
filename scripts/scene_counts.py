"""The shipped scenes on every backend: how many worlds come out valid,
unstable or over the contact budget, and how many meet each query (no timings
but the wall time of each run).

  .venv/bin/python scripts/scene_counts.py [--scenes siggraph,...] [--backends native,mjx:jax,mjx:warp]
      [--worlds native=64,mjx:jax=16,mjx:warp=8] [--end-time mjx:warp=2.0,trebuchet_tower/mjx:jax=1.0]

World counts and simulated seconds are chosen per backend (and, where a scene
needs it, per scene and backend) so every run finishes on the machine at hand;
the numbers used are written into each row. Writes out/bench/scenes.json
(docs/benchmarks.md is generated from it) and prints a table. MJX runs on
whatever device JAX has (a CPU here: slow, hence fewer worlds).
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
SCENES = ("quickstart", "pachinko", "toss", "siggraph", "spiral_staircase", "refrigerator_toy", "trebuchet_tower")
BACKENDS = ("native", "mjx:jax", "mjx:warp")
# On 2 shared CPU cores: MJX steps a few hundred to a few thousand worlds per
# second, MuJoCo Warp on the CPU fewer, so they get fewer worlds than native.
WORLDS = "native=64,mjx:jax=16,mjx:warp=8"
# The tower's 192 blocks make its MJX step slow on a CPU: a shorter horizon
# keeps its rows finishing (written into the rows and the doc).
END_TIME = "trebuchet_tower/mjx:jax=1.5,trebuchet_tower/mjx:warp=1.0"


def per_backend(spec: str, scene: str, backend: str, default):
  """The value for (scene, backend) in ``backend=V`` / ``scene/backend=V`` pairs
  (the scene-specific one wins)."""
  values = dict(item.split("=", 1) for item in spec.split(",") if item)
  for key in (f"{scene}/{backend}", backend):
    if key in values:
      return type(default)(values[key]) if default is not None else float(values[key])
  return default


def counts(scene: str, backend: str, worlds: int, end_time: float | None) -> dict:
  """One row: the counts of ``worlds`` worlds of ``scene`` sampled with seed 0."""
  config = mwbx.load_config(REPO / "configs" / f"{scene}.yaml")
  engine, _, impl = backend.partition(":")
  config = config.with_overrides(end_time=end_time, mjx_impl=impl or None)
  start = time.perf_counter()
  with reporter(f"{scene} ({backend})") as update:
    bank = mwbx.sample(config, worlds, jax.random.key(0), backend=engine, progress=update)
  query_file = REPO / "configs" / "queries" / f"{scene}.yaml"
  per_query, all_met = {}, None
  if query_file.exists():
    queries = mwbx.load_queries(query_file, bank=bank)
    each = mwbx.evaluate_each(bank, queries)
    per_query = {q.name: int(n) for q, n in zip(queries.queries, each.sum(axis=0))}
    all_met = int(each.all(axis=1).sum())
  return {"scene": scene, "backend": backend, "worlds": worlds, "end_time": config.sim.end_time,
          "valid": int(bank.valid.sum()),
          "unstable": int((bank.flags & mwbx.FLAG_UNSTABLE > 0).sum()),
          "over_budget": int((bank.flags & mwbx.FLAG_CONTACT_OVERFLOW > 0).sum()),
          "sim_errors": int((bank.flags & mwbx.FLAG_SIM_ERROR > 0).sum()),
          "at_rest": int(bank.at_rest.sum()), "per_query": per_query, "all_met": all_met,
          "wall_seconds": time.perf_counter() - start,
          "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                   text=True).stdout.strip()}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--scenes", default=",".join(SCENES))
  parser.add_argument("--backends", default=",".join(BACKENDS))
  parser.add_argument("--worlds", default=WORLDS, help="worlds per backend (or scene/backend)")
  parser.add_argument("--end-time", default=END_TIME,
                      help="simulated seconds per backend (or scene/backend); default: the config's")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "scenes.json"))
  args = parser.parse_args()
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  machine = {"platform": platform.platform(), "cores": os.cpu_count(), "jax_backend": jax.default_backend(),
             "load_average": os.getloadavg()[0]}
  old = json.loads(out.read_text()) if out.exists() else {}
  rows = [r for r in old.get("rows", []) if r.get("backend") in BACKENDS]  # rows of the old "mjx" label go
  order = {name: i for i, name in enumerate(SCENES)}
  for scene in args.scenes.split(","):
    for backend in args.backends.split(","):
      worlds = per_backend(args.worlds, scene, backend, 0)
      if worlds <= 0:
        continue
      r = counts(scene, backend, worlds, per_backend(args.end_time, scene, backend, None))
      r["machine"] = machine
      print(f"{scene:<18} {backend:<9} {r['valid']}/{r['worlds']} valid ({r['end_time']:g} s), "
            f"{r['unstable']} unstable, {r['over_budget']} over the contact budget, {r['sim_errors']} MuJoCo "
            f"errors; all queries met by {r['all_met']}; {r['per_query']}; {r['wall_seconds']:.0f} s", flush=True)
      # Rows not run now (scene and backend) stay as they were measured (each names its commit).
      rows = [x for x in rows if (x["scene"], x["backend"]) != (scene, backend)] + [r]
      rows.sort(key=lambda x: (order.get(x["scene"], len(order)), BACKENDS.index(x["backend"])))
      out.write_text(json.dumps({"machine": f"{machine['cores']}-core {platform.machine()}, JAX on "
                                            f"{machine['jax_backend']}", "rows": rows,
                                 "planned": {"scenes": SCENES, "backends": BACKENDS}}, indent=1))
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
