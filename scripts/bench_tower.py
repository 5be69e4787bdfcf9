"""The paper's tower on this machine: sampling with island sleep against
without, whether their outcomes agree, and a 64-child refinement against
the same refinement fitting every channel and testing every contact pair.

Sampling (``configs/trebuchet_tower.yaml``, native): the same N worlds
(seed 1) with ``sim.sleep: false`` and with ``sim.sleep: true``: wall time,
world-steps/s, physics, compression and contact events of each, the ratio,
and the time 1549 worlds take at that rate. Agreement: per outcome (blocks
knocked down, the rock's and each bystander's final place, the knocked-down
blocks' summed path length and collisions; the standing blocks' jitter is
reported apart), a Welch z of the means and a two-sample
Kolmogorov-Smirnov p, Bonferroni-corrected over the outcomes at a
family-wise 1 %, and, the worlds being the same draws (initial states and
perturbation draws), the paired view: per outcome the mean and largest
difference of a world with sleep on from itself with sleep off. Whether the
rock hits the tower at all (about one world in five) dominates every tower
outcome, so independent draws of 64 worlds differ by chance far more than
sleep moves them; the paired worlds show what sleep itself changes.

Refinement (``--objects rock --time 0.8 --samples 64`` of world 2 of the
sleep-on bank, whose rock misses the tower, and of the world whose rock
knocks down most blocks): wall, physics, compression and contact events, and the
bytes per refined world, against the same request (same key) in the same
process with inactive objects moved along the stored path every step
instead of held asleep, and against a baseline with that and every channel
fitted anew and every contact pair tested (the sleeping of inactive
objects, the parent-channel reuse, the events found at every step and the
active-pair filter patched off: events found on every stored frame).

The paper's 1549 worlds by the README's command: ``scripts/bench_scale.py``.

  .venv/bin/python scripts/bench_tower.py [--worlds 64] [--samples 64] [--out out/bench/tower.json]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import pathlib
import platform
import shutil
import time
from unittest import mock

import jax
import numpy as np
from scipy import stats

import mwbx
from mwbx.batch_sim import mujoco_c
from mwbx.codec import splice
from mwbx.refinement import plan

refine_lib = importlib.import_module("mwbx.refinement.refine")  # the package's ``refine`` is the function

REPO = pathlib.Path(__file__).resolve().parents[1]
CONFIG = REPO / "configs" / "trebuchet_tower.yaml"
FAMILY_ALPHA = 0.01
KNOCKED_DOWN = 0.05  # m a block's COM ends from where it started: knocked down


def sample(sleep: bool, n: int, seed: int):
  config = mwbx.load_config(CONFIG)
  config = config.model_copy(update={"sim": config.sim.model_copy(update={"sleep": sleep})})
  t0 = time.perf_counter()
  with mwbx.Sampler(config, "native") as sampler:
    bank, st = sampler.run(n, jax.random.key(seed))
  wall = time.perf_counter() - t0
  timing = {"wall_seconds": round(wall, 2), "compile_seconds": round(st.compile_seconds, 2),
            "physics_seconds": round(st.run_seconds, 2), "compression_seconds": round(st.codec_seconds, 2),
            "events_seconds": round(st.events_seconds, 2), "world_steps": int(st.world_steps),
            "world_steps_per_second": round(st.world_steps_per_second, 1),
            "at_rest": int(bank.summary()["at_rest_fraction"] * n + 0.5),
            "mean_perturbations": round(float(bank.perturbations.mean()), 1)}
  return bank, timing


def _knocked_down(bank) -> tuple[list[int], np.ndarray]:
  """(the blocks' body indices, bool[W, blocks] each block ending more than
  KNOCKED_DOWN from where it started)."""
  rows = np.arange(bank.n_worlds)
  blocks = [i for i, b in enumerate(bank.body_names) if b.startswith("block_")]
  moved = bank.com[rows, bank.com_count - 1][:, blocks] - bank.com[:, 0][:, blocks]
  return blocks, np.linalg.norm(moved, axis=-1) > KNOCKED_DOWN


def outcomes(bank) -> dict[str, np.ndarray]:
  """Per world: what a viewer of the tower would tell apart."""
  last = bank.com[np.arange(bank.n_worlds), bank.com_count - 1]  # f32[W, B, 3]
  names = list(bank.body_names)
  blocks, knocked = _knocked_down(bank)
  out = {"blocks_knocked_down": knocked.sum(axis=1).astype(float)}
  for body in ["rock"] + [b for b in names if b.startswith("bystander_")]:
    for axis, label in enumerate("xyz"):
      out[f"{body}_{label}"] = last[:, names.index(body), axis].astype(float)
  # Summed over the knocked-down blocks: a standing block's share is its
  # jitter (resting_jitter), which sleep removes from the blocks no hit wakes.
  metrics = list(bank.metric_names)
  for metric in ("path_length", "collisions"):
    out[f"knocked_{metric}"] = (bank.metrics[:, blocks, metrics.index(metric)] * knocked).sum(axis=1).astype(float)
  return out


def resting_jitter(bank) -> dict:
  """What the blocks that stay standing do meanwhile (per world, summed over
  them): awake, they creep and rattle on their contacts; asleep, only those a
  hit woke do."""
  blocks, knocked = _knocked_down(bank)
  metrics = list(bank.metric_names)
  return {f"mean_{metric}": round(float((bank.metrics[:, blocks, metrics.index(metric)] * ~knocked).sum(axis=1).mean()), 4)
          for metric in ("path_length", "collisions")}


def agreement(off: dict, on: dict) -> dict:
  z_crit = float(stats.norm.ppf(1 - FAMILY_ALPHA / 2 / len(off)))
  rows = {}
  for name in off:
    a, b = off[name], on[name]
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    z = 0.0 if se == 0 else float((b.mean() - a.mean()) / se)
    ks_p = float(stats.ks_2samp(a, b).pvalue)
    rows[name] = {"mean_off": round(float(a.mean()), 4), "mean_on": round(float(b.mean()), 4),
                  "z": round(z, 2), "ks_p": round(ks_p, 4),
                  "passes": bool(abs(z) < z_crit and ks_p > FAMILY_ALPHA / len(off))}
  for name in off:
    diff = np.abs(on[name] - off[name])
    rows[name]["paired_mean_abs_diff"] = round(float(diff.mean()), 4)
    rows[name]["paired_max_abs_diff"] = round(float(diff.max()), 4)
  return {"z_crit": round(z_crit, 3), "outcomes": rows, "max_abs_z": max(abs(r["z"]) for r in rows.values()),
          "all_pass": all(r["passes"] for r in rows.values()),
          "min_ks_p": min(r["ks_p"] for r in rows.values())}


def refine(bank, samples: int, baseline: bool, seed: int = 7, inactive_asleep: bool = True, world: int = 2) -> dict:
  request = refine_lib.RefineRequest(world, "rock", t_min=0.8, n_samples=samples, key=jax.random.key(seed))
  with contextlib.ExitStack() as stack:
    if baseline or not inactive_asleep:  # inactive objects moved along the stored path every step
      stack.enter_context(mock.patch.object(mujoco_c, "can_put_to_sleep", lambda: False))
    if baseline:  # every channel fitted anew, every contact pair tested on the stored frames
      find_events = plan.refined_events
      stack.enter_context(mock.patch.object(splice.ParentChannels, "of", staticmethod(_nothing_taken)))
      stack.enter_context(mock.patch.object(plan, "_stepped_episodes", lambda *args: None))
      stack.enter_context(mock.patch.object(
          plan, "refined_events", lambda *args, active=None, **kw: find_events(*args, **kw)))
    t0 = time.perf_counter()
    done = refine_lib.run_refinement(bank, request)
    wall = time.perf_counter() - t0
  st = done.stats
  active = [len(done.new.lineage[str(i)]["active"]) for i in done.new.world_ids]
  return {"wall_seconds": round(wall, 2), "physics_seconds": round(st.run_seconds, 2),
          "compile_seconds": round(st.compile_seconds, 2), "compression_seconds": round(st.codec_seconds, 2),
          "events_seconds": round(st.events_seconds, 2), "world_steps": int(st.world_steps),
          "asleep_object_frames_per_world": int(np.mean(st.asleep_object_frames)),
          "bytes_per_world": int(done.new.qpos_store.nbytes / done.new.n_worlds),
          "active_objects": {"min": min(active), "median": float(np.median(active)), "max": max(active)}}


def _nothing_taken(stream, keep, counts):
  code = splice.parse(stream)
  return splice.ParentChannels(code, np.zeros((len(keep), len(code.addresses())), bool))


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=64)
  parser.add_argument("--samples", type=int, default=64)
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "tower.json"))
  args = parser.parse_args()
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}",
            "worlds": args.worlds, "samples": args.samples}
  bank_off, result["sample_sleep_off"] = sample(False, args.worlds, 1)
  print("sleep off", result["sample_sleep_off"], flush=True)
  bank_on, result["sample_sleep_on"] = sample(True, args.worlds, 1)
  print("sleep on ", result["sample_sleep_on"], flush=True)
  for name, bank in (("off", bank_off), ("on", bank_on)):  # for a look at the worlds afterwards
    folder = REPO / "out" / "bench" / f"tower_sleep_{name}"  # never beside a JSON kept in docs/
    shutil.rmtree(folder, ignore_errors=True)
    bank.save(folder)
  off, on = result["sample_sleep_off"], result["sample_sleep_on"]
  result["sleep_speedup_physics"] = round(on["world_steps_per_second"] / off["world_steps_per_second"], 2)
  result["sleep_speedup_wall"] = round(off["wall_seconds"] / on["wall_seconds"], 2)
  result["projected_1549_worlds_minutes"] = {
      "sleep_off": round(off["wall_seconds"] / args.worlds * 1549 / 60, 1),
      "sleep_on": round(on["wall_seconds"] / args.worlds * 1549 / 60, 1)}
  result["agreement"] = agreement(outcomes(bank_off), outcomes(bank_on))
  result["resting_jitter"] = {"sleep_off": resting_jitter(bank_off), "sleep_on": resting_jitter(bank_on)}
  print("agreement", json.dumps(result["agreement"], indent=1), flush=True)
  # Once before timing, with other draws: compiles the refinement loop and the codec's fit for
  # these shapes, as an interactive session's first refinement does for the next ones.
  refine(bank_on, args.samples, baseline=False, seed=3)
  result["refine"] = refine(bank_on, args.samples, baseline=False)
  print("refine  ", result["refine"], flush=True)
  result["refine_inactive_awake"] = refine(bank_on, args.samples, baseline=False, inactive_asleep=False)
  print("awake   ", result["refine_inactive_awake"], flush=True)
  result["refine_baseline"] = refine(bank_on, args.samples, baseline=True)
  print("baseline", result["refine_baseline"], flush=True)
  # World 2's rock misses the tower; the world whose rock knocks down most blocks, refined alike.
  hit = int(np.argmax(outcomes(bank_on)["blocks_knocked_down"]))
  result["refine_hit"] = dict(refine(bank_on, args.samples, baseline=False, world=hit), world=hit)
  print("hit     ", result["refine_hit"], flush=True)
  result["refine_speedup_wall"] = round(result["refine_baseline"]["wall_seconds"] / result["refine"]["wall_seconds"], 2)
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(json.dumps(result, indent=2) + "\n")
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
