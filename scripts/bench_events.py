"""Contact events: what they cost to find and to keep, how fast event queries
answer, and the tower's "rock hits the tower" as an event beside the box query.

1. Quickstart, N worlds sampled on the native backend: seconds finding the
   events (MuJoCo collision on every stored frame) against the sampler's own
   simulation seconds in the same run (the baseline), and the bytes the events
   add to the bank's shards on disk.
2. Query latency on 4096 worlds (the sampled worlds' event records repeated
   to 4096 worlds; answers are per world, so repeating them changes no
   work per world): a touch query and a three-touch order query, median of
   repeats, against a COM screen-box query on the same bank (the baseline).
3. The trebuchet tower, M worlds: how many worlds meet the box query
   ``rock_hits_tower`` and the event query ``rock_touches_tower``, and both.

Prints tables and writes out/bench/events.json.

  .venv/bin/python scripts/bench_events.py [--worlds 256] [--tower 32]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import statistics
import tempfile
import time

import jax
import numpy as np

import mwbx
from mwbx.progress import reporter

ROOT = pathlib.Path(__file__).resolve().parents[1]


def machine() -> str:
  return f"{platform.machine()}, {os.cpu_count()} cores, {platform.processor() or 'cpu'}, no GPU used"


def _median_ms(fn, repeats: int = 15) -> float:
  fn()  # warm (numpy first-call costs)
  times = []
  for _ in range(repeats):
    t = time.perf_counter()
    fn()
    times.append(time.perf_counter() - t)
  return 1e3 * statistics.median(times)


def _dir_bytes(path: pathlib.Path, pattern: str = "*") -> int:
  return sum(f.stat().st_size for f in path.rglob(pattern) if f.is_file())


def cost(n_worlds: int) -> tuple[dict, mwbx.Bank]:
  config = mwbx.load_config(ROOT / "configs" / "quickstart.yaml")
  with mwbx.Sampler(config, backend="native") as sampler:
    with reporter("sample") as report:
      bank, stats = sampler.run(n_worlds, jax.random.key(0), progress=report)
  with tempfile.TemporaryDirectory() as tmp:
    bank.save(tmp)
    total = _dir_bytes(pathlib.Path(tmp) / "shards")
    events = _dir_bytes(pathlib.Path(tmp) / "shards", "events_*.npy")
  row = {"scene": "quickstart", "worlds": n_worlds, "episodes": int(len(bank.events.rows)),
         "events_seconds": stats.events_seconds, "simulation_seconds": stats.run_seconds,
         "events_over_simulation": stats.events_seconds / stats.run_seconds,
         "shard_bytes": total, "event_bytes": events, "event_fraction": events / total}
  print(f"quickstart {n_worlds} worlds: events {stats.events_seconds:.2f} s against simulation "
        f"{stats.run_seconds:.2f} s ({row['events_over_simulation']:.2f}x); {events:,} of {total:,} shard bytes "
        f"({row['event_fraction']:.1%}), {row['episodes']:,} episodes")
  return row, bank


def latency(bank: mwbx.Bank, n_worlds: int = 4096) -> dict:
  copies = -(-n_worlds // bank.n_worlds)
  # Ids must stay distinct: each copy starts after the previous one's.
  parts = [bank]
  for _ in range(copies - 1):
    parts.append(bank._renumbered_after(parts[-1]))
  big = mwbx.Bank.concatenate(parts)._take(np.arange(n_worlds))
  camera = mwbx.Camera.from_model(big.model(), "front")
  box = mwbx.Query.screen(camera, [0.3, 0.4, 0.5, 0.6], bodies="ball")
  touch = mwbx.TouchQuery("ball", "floor", window=(1.0, 3.0))
  order = mwbx.OrderQuery([("box_a", "ramp_upper"), ("box_a", "ramp_lower"), ("box_a", "floor")])
  rows = {}
  for name, query in (("com box (baseline)", box), ("touch", touch), ("order of 3", order)):
    ms = _median_ms(lambda q=query: mwbx.evaluate(big, [q]))
    rows[name] = {"ms": ms, "matches": int(mwbx.evaluate(big, [query]).sum())}
  base = rows["com box (baseline)"]["ms"]
  for name, r in rows.items():
    r["vs_baseline"] = r["ms"] / base
    print(f"{n_worlds} worlds, {name}: {r['ms']:.2f} ms median ({r['vs_baseline']:.2f}x the COM box), "
          f"{r['matches']} worlds")
  return {"worlds": n_worlds, "distinct_worlds": bank.n_worlds, "queries": rows}


def tower(n_worlds: int) -> dict:
  config = mwbx.load_config(ROOT / "configs" / "trebuchet_tower.yaml")
  with mwbx.Sampler(config, backend="native") as sampler:
    with reporter("sample") as report:
      bank, stats = sampler.run(n_worlds, jax.random.key(0), progress=report)
  queries = mwbx.load_queries(ROOT / "configs" / "queries" / "trebuchet_tower.yaml", bank=bank)
  names = [q.name for q in queries.queries]
  each = mwbx.evaluate_each(bank, queries)
  box, event = each[:, names.index("rock_hits_tower")], each[:, names.index("rock_touches_tower")]
  chain = each[:, names.index("rock_then_blocks_hit_bystander_0")]
  row = {"worlds": n_worlds, "valid": int(bank.valid.sum()), "box": int(box.sum()), "event": int(event.sum()),
         "both": int((box & event).sum()), "order_rock_then_bystander_0": int(chain.sum()),
         "events_seconds": stats.events_seconds, "simulation_seconds": stats.run_seconds}
  print(f"tower {n_worlds} worlds: rock_hits_tower (box) {row['box']}, rock_touches_tower (event) "
        f"{row['event']}, both {row['both']}; rock then blocks hit bystander_0: {row['order_rock_then_bystander_0']};"
        f" events {stats.events_seconds:.1f} s against simulation {stats.run_seconds:.1f} s")
  return row


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=256, help="quickstart worlds sampled (default 256)")
  parser.add_argument("--tower", type=int, default=32, help="tower worlds sampled (default 32; 0: skip)")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "events.json")
  args = parser.parse_args()
  result = {"machine": machine(), "mujoco": __import__("mujoco").__version__}
  result["cost"], bank = cost(args.worlds)
  result["latency"] = latency(bank)
  if args.tower:
    result["tower"] = tower(args.tower)
  elif args.out.exists() and "tower" in json.loads(args.out.read_text()):  # --tower 0: keep the last tower row
    result["tower"] = json.loads(args.out.read_text())["tower"]
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=1))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
