"""What refining some objects of one world would do from each of several
restart times: how many children meet more queries than the world, which
queries they gain and lose, and which objects the refinement makes active and
when (the others keep their stored paths).

A repair pays only where its objects can still reach their goal and the
objects they meet on the way keep theirs; this measures both, per restart
time. Every time draws its children from the same key, so the rows differ
only in where they restart. Nothing is added to the bank.

  .venv/bin/python scripts/restart_probe.py out/siggraph configs/queries/siggraph.yaml \\
      --world 8199 --objects letter_A --times 0.43,0.6,0.74,0.8,1.05 [--samples 32] [--json probe.json]
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

import mwbx
from mwbx.progress import reporter
from mwbx.queries.query import as_queries
from mwbx.refinement import RefineRequest, run_refinement
from mwbx.search.solver import _label  # the names mwbx solve gives queries (its steps' `repaired`)


def probe(bank, queries, world: int, objects, t_min: float, samples: int, key: jax.Array,
          backend: str | None = None, progress=None) -> dict:
  """Refines ``objects`` of ``world`` from ``t_min`` (``samples`` children,
  drawn from ``key``; ``progress``: as :func:`mwbx.run_refinement`'s)
  and says what the children met against the world.

  Returns:
    {"t_min": s, "valid": children without a flag, "parent_met": queries the
    world meets, "best_met" / "mean_met": over valid children, "better":
    valid children meeting more queries than the world, "gained" / "lost":
    {query name: valid children meeting it where the world does not / not
    meeting it where the world does}, "active_mean": objects active per
    child, "activated": {object: [children where it became active, median
    time it did, s]}}.
  """
  queries = as_queries(queries)
  names = [_label(q, i) for i, q in enumerate(queries)]
  parent = mwbx.evaluate_each(bank, queries)[bank.row_of(world)]
  children = run_refinement(bank, RefineRequest(world, list(objects), t_min=t_min, n_samples=samples, key=key,
                                            backend=backend), progress).new
  valid = np.asarray(children.valid, bool)
  met = mwbx.evaluate_each(children, queries)[valid]  # bool[V, Q]
  counts = met.sum(axis=1)
  active, when = [], {}
  for i in children.world_ids[valid]:
    lineage = children.lineage[str(int(i))]
    active.append(len(lineage["active"]))
    for obj, at in lineage["activated_at"].items():
      when.setdefault(obj, []).append(float(at))
  return {
      "t_min": float(t_min), "valid": int(valid.sum()), "parent_met": int(parent.sum()),
      "best_met": int(counts.max()) if counts.size else 0, "mean_met": float(counts.mean()) if counts.size else 0.0,
      "better": int((counts > parent.sum()).sum()),
      "gained": {names[q]: int(n) for q, n in enumerate((met & ~parent).sum(axis=0)) if n},
      "lost": {names[q]: int(n) for q, n in enumerate((~met & parent).sum(axis=0)) if n},
      "active_mean": float(np.mean(active)) if active else 0.0,
      "activated": {obj: [len(ts), float(np.median(ts))] for obj, ts in sorted(when.items())},
  }


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("bank")
  parser.add_argument("queries", help="query YAML")
  parser.add_argument("--world", type=int, required=True)
  parser.add_argument("--objects", required=True, help="comma-separated objects to refine")
  parser.add_argument("--times", required=True, help="comma-separated restart times, s")
  parser.add_argument("--samples", type=int, default=32)
  parser.add_argument("--seed", type=int, default=7, help="key of every time's children")
  parser.add_argument("--backend", default=None, choices=("native", "mjx"))
  parser.add_argument("--json", default=None, help="also write the rows here")
  args = parser.parse_args()
  bank = mwbx.Bank.load(args.bank)
  queries = mwbx.load_queries(args.queries, bank=bank)
  objects = args.objects.split(",")
  rows = []
  for t in (float(x) for x in args.times.split(",")):
    with reporter(f"restart at {t:.2f} s") as update:
      row = probe(bank, queries, args.world, objects, t, args.samples, jax.random.key(args.seed), args.backend,
                  progress=update)
    rows.append(row)
    activated = ", ".join(f"{o} {n} at {at:.2f} s" for o, (n, at) in row["activated"].items())
    print(f"t_min {row['t_min']:.2f} s: {row['valid']} valid; met {row['best_met']} at most, {row['mean_met']:.1f}"
          f" mean (world: {row['parent_met']}); {row['better']} better\n  gained {row['gained']}\n"
          f"  lost {row['lost']}\n  active {row['active_mean']:.1f} per child: {activated}", flush=True)
  if args.json:
    with open(args.json, "w") as f:
      json.dump({"bank": args.bank, "world": args.world, "objects": objects, "samples": args.samples,
                 "seed": args.seed, "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
