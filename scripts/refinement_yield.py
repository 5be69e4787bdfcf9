"""What the refinements of a solved (or unsolved) bank bought: per number of
queries the parent met, how many refinements started there and how many gave
a kept child meeting more; the same per number of refined objects and per
restart time; and how many objects each refinement made active (the others
kept their paths).

Reads the lineage the bank stores (``mwbx solve`` or ``scripts/bench_solve.py
--save-banks`` keep only each refinement's best children, so a refinement
that kept none is not counted).

  .venv/bin/python scripts/refinement_yield.py out/bench/solve_siggraph_seed0 configs/queries/siggraph.yaml
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

import mwbx


# Restart-time bins of the per-time table, s.
TIME_BINS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, float("inf"))


def refinement_yield(bank, queries) -> dict:
  """{"by_parent_met": {met: (refinements, improved)}, "by_objects": {n: (refinements,
  improved)}, "by_restart": {(t0, t1) s: (refinements, improved)} over :data:`TIME_BINS`,
  "active": i64[R] objects active per refinement}; a refinement is its
  (parent, restart time, objects), improved when a kept child meets more queries."""
  met = mwbx.evaluate_each(bank, queries).sum(axis=1)
  children = collections.defaultdict(list)  # (parent id, restart time, objects) -> child rows
  # Refined worlds whose parent the bank holds (sampled and guided worlds have none).
  for row in np.flatnonzero(np.isin(bank.parent_world, bank.world_ids)):
    objects = tuple(bank.lineage[str(int(bank.world_ids[row]))]["objects"])
    children[(int(bank.parent_world[row]), float(bank.refine_time[row]), objects)].append(row)
  by_met = collections.defaultdict(lambda: [0, 0])
  by_objects = collections.defaultdict(lambda: [0, 0])
  by_restart = collections.defaultdict(lambda: [0, 0])
  active = []
  for (parent, t_min, objects), kids in children.items():
    parent_met = int(met[bank.row_of(parent)])
    improved = int(met[kids].max() > parent_met)
    b = int(np.searchsorted(TIME_BINS, t_min, side="right")) - 1
    for table, key in ((by_met, parent_met), (by_objects, len(objects)), (by_restart, TIME_BINS[b:b + 2])):
      table[key][0] += 1
      table[key][1] += improved
    active.append(len(bank.lineage[str(int(bank.world_ids[kids[0]]))]["active"]))
  return {"by_parent_met": {k: tuple(v) for k, v in sorted(by_met.items())},
          "by_objects": {k: tuple(v) for k, v in sorted(by_objects.items())},
          "by_restart": {k: tuple(v) for k, v in sorted(by_restart.items())},
          "active": np.asarray(active, np.int64)}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("bank")
  parser.add_argument("queries")
  args = parser.parse_args()
  bank = mwbx.Bank.load(args.bank)
  queries = mwbx.load_queries(args.queries, bank=bank)
  result = refinement_yield(bank, queries)
  print(f"{args.bank}: {sum(n for n, _ in result['by_parent_met'].values())} refinements with kept children,"
        f" {len(queries.queries)} queries")
  print("parent met  refinements  improved")
  for met, (n, better) in result["by_parent_met"].items():
    print(f"{met:>10}  {n:>11}  {better:>8}")
  print("objects  refinements  improved")
  for k, (n, better) in result["by_objects"].items():
    print(f"{k:>7}  {n:>11}  {better:>8}")
  print("restart, s   refinements  improved")
  for (t0, t1), (n, better) in result["by_restart"].items():
    print(f"{f'{t0:g}-{t1:g}':>10}  {n:>11}  {better:>8}")
  if result["active"].size:
    print(f"active objects per refinement: mean {result['active'].mean():.1f}, at most {result['active'].max()}")


if __name__ == "__main__":
  main()
