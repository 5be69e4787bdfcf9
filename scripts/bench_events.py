"""Contact events: what they cost to find and to keep, how fast event queries
answer, and the tower's "rock hits the tower" as an event beside the box query.

1. Quickstart, N worlds sampled on the native backend twice in one process:
   with events found at every physics step inside the loop, and with them
   found afterwards on the stored frames (MuJoCo collision at every frame:
   the baseline, the contact reading patched off): wall, simulation and
   event seconds of each, the episodes, and the bytes events add to the
   bank's shards on disk.
2. Query latency on 4096 worlds (the sampled worlds' event records repeated
   to 4096 worlds; answers are per world, so repeating them changes no
   work per world): a touch query and a three-touch order query, median of
   repeats, against a COM screen-box query on the same bank (the baseline).
3. The trebuchet tower, M worlds: how many worlds meet the box query
   ``rock_hits_tower`` and the event query ``rock_touches_tower``, and both.
5. The simulation's own cost of events at every step: the quickstart (N
   worlds) and the tower (M worlds) sampled by two samplers in one process,
   one reading MuJoCo's contacts at every step and one with the contact
   reading patched off (events then found afterwards, not timed here),
   alternating for a few repeats, each keeping its best simulation seconds
   (the machine may be shared).
4. Fast impacts: a ball dropped from 12.5–13.5 m onto a stiff, bouncy floor
   (about 16 m/s, in contact for a few milliseconds), K worlds: the worlds
   whose stored path turns back up at the floor (the truth), against those
   whose events say the ball touched the floor, found at every step and on
   the stored frames; and the impulses found.

Prints tables and writes out/bench/events.json.

  .venv/bin/python scripts/bench_events.py [--worlds 256] [--tower 32] [--fast 128]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pathlib
import platform
import statistics
import tempfile
import time

import jax
import numpy as np

from unittest import mock

import mwbx
from mwbx.batch_sim import mujoco_c
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


def _sample(config, n_worlds: int, on_frames: bool = False, seed: int = 0):
  """(bank, stats, wall s) of n_worlds native worlds; ``on_frames``: the
  loop reads no contacts, so events are found on the stored frames."""
  patch = mock.patch.object(mujoco_c, "contact_layout", lambda: None) if on_frames else contextlib.nullcontext()
  with patch, mwbx.Sampler(config, backend="native") as sampler:
    sampler.run(n_worlds, jax.random.key(99))  # compiles the loop and the codec's fit for these shapes, untimed
    with reporter("sample") as report:
      start = time.perf_counter()
      bank, stats = sampler.run(n_worlds, jax.random.key(seed), progress=report)
      wall = time.perf_counter() - start
  return bank, stats, wall


def cost(n_worlds: int) -> tuple[dict, mwbx.Bank]:
  config = mwbx.load_config(ROOT / "configs" / "quickstart.yaml")
  rows = {}
  for how, on_frames in (("every physics step", False), ("stored frames (baseline)", True)):
    bank, stats, wall = _sample(config, n_worlds, on_frames)
    with tempfile.TemporaryDirectory() as tmp:
      bank.save(tmp)
      total = _dir_bytes(pathlib.Path(tmp) / "shards")
      bank_total = _dir_bytes(pathlib.Path(tmp))
      events = _dir_bytes(pathlib.Path(tmp) / "shards", "events_*.npy")
    rows[how] = {"wall_seconds": wall, "episodes": int(len(bank.events.rows)),
                 "events_seconds": stats.events_seconds, "simulation_seconds": stats.run_seconds,
                 "shard_bytes": total, "bank_bytes": bank_total, "event_bytes": events,
                 "event_fraction": events / total, "event_fraction_of_bank": events / bank_total}
    if not on_frames:
      stepped = bank
    print(f"quickstart {n_worlds} worlds, events at {how}: wall {wall:.2f} s, simulation {stats.run_seconds:.2f} s,"
          f" events afterwards {stats.events_seconds:.2f} s; {events:,} of {total:,} shard bytes"
          f" ({events / total:.1%}), {len(bank.events.rows):,} episodes")
  step, frames = rows["every physics step"], rows["stored frames (baseline)"]
  row = {"scene": "quickstart", "worlds": n_worlds, "how": rows,
         "wall_ratio": step["wall_seconds"] / frames["wall_seconds"]}
  print(f"wall with events at every step / with events on the stored frames: {row['wall_ratio']:.2f}")
  return row, stepped


FAST_XML = """<mujoco><option timestep="0.001"/><worldbody>
  <geom name="floor" type="plane" size="3 3 0.1" solref="-1e6 -10"/>
  <body name="ball" pos="0 0 13.05"><freejoint/><geom type="sphere" size="0.05" mass="0.2" solref="-1e6 -10"/></body>
</worldbody></mujoco>"""
FAST_YAML = """scene: {mjcf: fast.xml}
randomize: {ball: {position: {dist: uniform, scale: [0.0, 0.0, 0.5]}}}
sim: {end_time: 2.0}
"""


def fast_impacts(n_worlds: int) -> dict:
  """Section 4: the worlds whose ball turns back up at the floor, and those whose events say it touched."""
  with tempfile.TemporaryDirectory() as tmp:
    (pathlib.Path(tmp) / "fast.xml").write_text(FAST_XML)
    (pathlib.Path(tmp) / "fast.yaml").write_text(FAST_YAML)
    config = mwbx.load_config(pathlib.Path(tmp) / "fast.yaml")
    bank, _, _ = _sample(config, n_worlds)
    frames_bank, _, _ = _sample(config, n_worlds, on_frames=True)
  z = np.stack([f[:, 2] for f in bank.qpos_store.frames_of_rows(None)])  # the same length: end time
  bounced = np.array([(np.diff(w) > 0).any() and w.min() < 0.5 for w in z])  # falls, then rises near the floor
  ball, floor = ("ball",), ("floor",)
  hit = mwbx.queries.event.hardest_hit(bank, ball, floor)
  row = {"worlds": n_worlds, "bounced": int(bounced.sum()),
         "touch_every_step": int(np.isfinite(mwbx.queries.event.first_touch(bank, ball, floor)).sum()),
         "touch_stored_frames": int(np.isfinite(mwbx.queries.event.first_touch(frames_bank, ball, floor)).sum()),
         "impulse_median": float(np.median(hit)), "impulse_min": float(hit.min()), "impulse_max": float(hit.max()),
         "impact_speed": float(np.sqrt(2 * 9.81 * 13.0))}
  print(f"fast impacts, {n_worlds} worlds: the ball turns back at the floor in {row['bounced']}; touch found in"
        f" {row['touch_every_step']} at every step, {row['touch_stored_frames']} on the stored frames;"
        f" impulse median {row['impulse_median']:.2f} N·s ({row['impulse_min']:.2f}–{row['impulse_max']:.2f})")
  return row


def latency(bank: mwbx.Bank, n_worlds: int = 4096) -> dict:
  copies = -(-n_worlds // bank.n_worlds)
  # Ids must stay distinct: each copy starts after the previous one's.
  parts = [bank]
  for _ in range(copies - 1):
    parts.append(bank._renumbered_after(parts[-1]))
  big = mwbx.Bank.concatenate(parts)._take(np.arange(n_worlds))
  camera = mwbx.Camera.from_model(big.model, "front")
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


def _best_simulation(samplers: dict, n_worlds: int, repeats: int) -> dict:
  """{how: best simulation seconds} of n_worlds run by each sampler, the
  samplers alternating (each compiled by an untimed run first)."""
  for sampler in samplers.values():
    sampler.run(n_worlds, jax.random.key(99))  # compiles, untimed
  best = {how: np.inf for how in samplers}
  for _ in range(repeats):
    for how, sampler in samplers.items():
      _, stats = sampler.run(n_worlds, jax.random.key(0))
      best[how] = min(best[how], stats.run_seconds)
  return best


def loop_cost(name: str, n_worlds: int, repeats: int = 3) -> dict:
  """Best simulation seconds of n_worlds with events read at every step and without."""
  config = mwbx.load_config(ROOT / "configs" / f"{name}.yaml")
  with contextlib.ExitStack() as stack:
    stepping = stack.enter_context(mwbx.Sampler(config, backend="native"))
    with mock.patch.object(mujoco_c, "contact_layout", lambda: None):
      plain = stack.enter_context(mwbx.Sampler(config, backend="native"))
    best = _best_simulation({"every physics step": stepping, "none in the loop": plain}, n_worlds, repeats)
  row = {"scene": name, "worlds": n_worlds, "repeats": repeats, "simulation_seconds": best,
         "ratio": best["every physics step"] / best["none in the loop"]}
  print(f"{name} {n_worlds} worlds: simulation with events read at every step {best['every physics step']:.2f} s,"
        f" without {best['none in the loop']:.2f} s: {row['ratio']:.3f}x (best of {repeats})")
  return row


def mjx_loop_cost(name: str, n_worlds: int, repeats: int = 2) -> dict:
  """Best simulation seconds of n_worlds on MJX (impl jax) with contact
  episodes tracked inside the scan at every step and without (the scan then
  tracks nothing; their events would be found on the stored frames)."""
  config = mwbx.load_config(ROOT / "configs" / f"{name}.yaml")
  with contextlib.ExitStack() as stack:
    stepping = stack.enter_context(mwbx.Sampler(config, backend="mjx"))
    plain = stack.enter_context(mwbx.Sampler(config, backend="mjx"))
    plain.backend.event_gap = None  # MjxBackend: no trackers in its scan
    best = _best_simulation({"every physics step": stepping, "none in the scan": plain}, n_worlds, repeats)
  row = {"scene": name, "worlds": n_worlds, "repeats": repeats, "backend": "mjx:jax", "simulation_seconds": best,
         "ratio": best["every physics step"] / best["none in the scan"]}
  print(f"{name} {n_worlds} worlds on MJX: simulation with episodes tracked in the scan"
        f" {best['every physics step']:.2f} s, without {best['none in the scan']:.2f} s: {row['ratio']:.3f}x"
        f" (best of {repeats})")
  return row


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=256, help="quickstart worlds sampled (default 256)")
  parser.add_argument("--tower", type=int, default=32, help="tower worlds sampled (default 32; 0: skip)")
  parser.add_argument("--fast", type=int, default=128, help="fast-impact worlds (default 128; 0: skip)")
  parser.add_argument("--mjx", type=int, default=64, help="quickstart worlds on MJX, tracked or not (0: skip)")
  parser.add_argument("--only-mjx", action="store_true", help="run the MJX part alone, into the existing --out")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "events.json")
  args = parser.parse_args()
  if args.only_mjx:
    result = json.loads(args.out.read_text())
    result["mjx_loop_cost"] = mjx_loop_cost("quickstart", args.mjx) | {"machine": machine()}
    args.out.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.out}")
    return
  result = {"machine": machine(), "mujoco": __import__("mujoco").__version__}
  result["cost"], bank = cost(args.worlds)
  result["latency"] = latency(bank)
  result["loop_cost"] = [loop_cost("quickstart", args.worlds)]
  if args.tower:
    result["loop_cost"].append(loop_cost("trebuchet_tower", args.tower))
  if args.mjx:
    result["mjx_loop_cost"] = mjx_loop_cost("quickstart", args.mjx) | {"machine": machine()}
  if args.fast:
    result["fast"] = fast_impacts(args.fast)
  if args.tower:
    result["tower"] = tower(args.tower)
  elif args.out.exists() and "tower" in json.loads(args.out.read_text()):  # --tower 0: keep the last tower row
    result["tower"] = json.loads(args.out.read_text())["tower"]
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=1))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
