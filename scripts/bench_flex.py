"""Flexes (cloth, soft solids): sampling speed and storage, measured in one run.

For configs/tablecloth.yaml (and configs/soft_steps.yaml):

  speed    the mwbx sampler on the native backend against bare
           ``mujoco.rollout`` of the same model (no sensors, no perturbations)
           from the same initial states, a thread per core (the baseline),
           in blocks of ``--block`` worlds taken in turn (mwbx, then rollout
           of the same worlds), so that load on a shared machine falls on
           both alike;
  storage  the flex's stored coordinates (its vertex bodies' slide joints,
           coded under the codec's ``e_scalar`` bound): bytes per
           vertex-second against float32 vertex positions (3 floats a vertex
           a recorded frame) and against SZ3 (``pysz``, if installed) at the
           same absolute bound on the same coordinates, per world; the
           largest decoding error found.

Prints a table and writes out/bench/flex.json.

  .venv/bin/python scripts/bench_flex.py [--worlds 8] [--block 8] [--scenes tablecloth,soft_steps]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import time

import jax
import mujoco
from mujoco import rollout as mj_rollout
import numpy as np

import mwbx
from mwbx.batch_sim.sampler import world_keys
from mwbx.progress import reporter
from mwbx.scene import build_model

REPO = pathlib.Path(__file__).resolve().parents[1]


def _rollout(sampler, ids: np.ndarray) -> tuple[int, float]:
  """(world-steps, seconds) of bare mujoco.rollout from the initial states
  of worlds ``ids`` (run key 0), each for the sampler's whole duration."""
  scene = sampler.scene
  n_worlds = len(ids)
  model = build_model(scene.mjcf_text, (), scene.mjcf_dir)
  model.opt.timestep = scene.model.opt.timestep
  _, init_keys, _ = world_keys(jax.random.key(0), ids)
  qpos0, qvel0 = (np.asarray(x, np.float64) for x in sampler._init(init_keys))
  data = mujoco.MjData(model)
  spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
  states = np.zeros((n_worlds, mujoco.mj_stateSize(model, spec)))
  for w in range(n_worlds):
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:] = qpos0[w], qvel0[w]
    mujoco.mj_getState(model, data, states[w], spec)
  n_steps = sampler.n_frames * sampler.params.steps_per_frame
  threads = sampler.backend.threads
  datas = [mujoco.MjData(model) for _ in range(threads)]
  with mj_rollout.Rollout(nthread=threads) as pool:
    start = time.perf_counter()
    pool.rollout(model, datas, states, nstep=n_steps)
    return n_worlds * n_steps, time.perf_counter() - start


def _flex_columns(bank, flex: str) -> np.ndarray:
  """The qpos columns of a flex's vertex bodies' joints."""
  model = bank.model
  bodies = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in bank.objects[flex]}
  cols = []
  for j in range(model.njnt):
    if int(model.jnt_bodyid[j]) in bodies:
      cols.append(int(model.jnt_qposadr[j]))
  return np.asarray(sorted(cols), np.int64)


def _shape_jitter(bank, flex: str, n_worlds: int) -> float:
  """RMS second difference (m per frame²) of the flex's vertices about their
  mean, over the first ``n_worlds`` worlds: how much its shape shakes from one
  recorded frame to the next (a uniform kick of the whole flex adds none)."""
  cols = _flex_columns(bank, flex)
  total, count = 0.0, 0
  for w in bank.world_ids[:n_worlds]:
    q = bank.qpos_frames(int(w))[:, cols].astype(np.float64).reshape(-1, len(cols) // 3, 3)
    shape = q - q.mean(axis=1, keepdims=True)
    second = np.diff(shape, n=2, axis=0)
    total += float((second ** 2).sum())
    count += second.shape[0] * second.shape[1]
  return float(np.sqrt(total / max(count, 1)))


def _sz3_bytes(block: np.ndarray, bound: float):
  try:
    from pysz import sz, szConfig, szErrorBoundMode  # optional: the bench's comparison only
  except ImportError:
    return None, None
  data = np.ascontiguousarray(block.T, np.float32)
  conf = szConfig()
  conf.errorBoundMode = szErrorBoundMode.ABS
  conf.absErrorBound = float(bound)
  conf.setDims(*data.shape)
  comp, _ = sz.compress(data, conf)
  out, _ = sz.decompress(comp, np.float32, data.shape)
  return int(comp.nbytes), float(np.abs(out.astype(np.float64) - data).max())


def bench(name: str, n_worlds: int, block: int) -> dict:
  config = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  block = max(1, min(block, n_worlds))
  with mwbx.Sampler(config, backend="native", chunk_size=block) as sampler:
    flexes = sampler.scene.flex_objects
    with reporter(f"{name}: warm-up") as report:
      sampler.run(min(2, n_worlds), jax.random.key(1), progress=report)  # compile
    banks, steps, seconds, events = [], [0, 0], [0.0, 0.0], 0.0
    for first in range(0, n_worlds, block):
      n = min(block, n_worlds - first)
      with reporter(f"{name}: sample worlds {first}-{first + n - 1}") as report:
        part, stats = sampler.run(n, jax.random.key(0), first_world=first, progress=report)
      banks.append(part)
      steps[0] += stats.world_steps
      seconds[0] += stats.run_seconds
      events += stats.events_seconds
      done, took = _rollout(sampler, np.arange(first, first + n))
      steps[1] += done
      seconds[1] += took
      print(f"{name}: worlds {first}-{first + n - 1}: mwbx {stats.world_steps_per_second:,.0f} world-steps/s,"
            f" rollout {done / took:,.0f}")
  bank = banks[0]
  for part in banks[1:]:
    bank = bank.append(part)
  mwbx_rate, rollout = steps[0] / seconds[0], steps[1] / seconds[1]
  # The flex's shape shaking with its perturbations against without them
  # (the flexes excluded), on the same first worlds.
  n_jitter = min(8, n_worlds)
  quiet_config = config.model_copy(update={"perturb": config.perturb.model_copy(
      update={"exclude": tuple(config.perturb.exclude) + tuple(flexes)})})
  with mwbx.Sampler(quiet_config, backend="native", chunk_size=n_jitter) as quiet_sampler:
    with reporter(f"{name}: {n_jitter} worlds, flexes not perturbed") as report:
      quiet, _ = quiet_sampler.run(n_jitter, jax.random.key(0), progress=report)
  jitter = {f: {"perturbed": _shape_jitter(bank, f, n_jitter), "not_perturbed": _shape_jitter(quiet, f, n_jitter)}
            for f in flexes}
  for f, j in jitter.items():
    j["ratio"] = j["perturbed"] / j["not_perturbed"]
    print(f"{name} {f}: shape jitter {j['perturbed'] * 1e3:.3f} mm/frame² perturbed, "
          f"{j['not_perturbed'] * 1e3:.3f} not ({j['ratio']:.2f}x), {n_jitter} worlds")
  row = {"scene": name, "worlds": n_worlds, "block": block, "shape_jitter": jitter, "valid": int(bank.valid.sum()), "flexes": list(flexes),
         "perturbations_per_world": float(np.mean(bank.perturbations)),
         "mwbx_world_steps_per_s": mwbx_rate, "rollout_world_steps_per_s": rollout,
         "ratio_vs_rollout": mwbx_rate / rollout,
         "events_seconds": events, "simulation_seconds": seconds[0]}
  e_scalar = float(bank.config["codec"]["e_scalar"])
  frames_all = bank.qpos_store.frames_of_rows(None)
  for flex in flexes:
    cols = _flex_columns(bank, flex)
    n_vertices = len(cols) // 3
    seconds = sum(len(f) for f in frames_all) / bank.record_fps
    float32 = sum(len(f) for f in frames_all) * len(cols) * 4
    sz3_total, sz3_worst = 0, 0.0
    for frames in frames_all:
      block = frames[:, cols].astype(np.float64)
      nbytes, err = _sz3_bytes(block, e_scalar)
      if nbytes is not None:
        sz3_total += nbytes
        sz3_worst = max(sz3_worst, err)
    mwbx_bytes = int(bank.qpos_store.nbytes)
    row[flex] = {
        "vertices": n_vertices, "vertex_seconds": n_vertices * seconds,
        "float32_bytes_per_vertex_second": float32 / (n_vertices * seconds),
        "mwbx_qpos_bytes_per_vertex_second": mwbx_bytes / (n_vertices * seconds),
        "mwbx_vs_float32": mwbx_bytes / float32,
        "sz3_bytes_per_vertex_second": sz3_total / (n_vertices * seconds) if sz3_total else None,
        "sz3_over_mwbx": sz3_total / mwbx_bytes if sz3_total else None,
        "e_scalar": e_scalar, "sz3_max_error": sz3_worst if sz3_total else None,
        "note": "mwbx bytes are the whole stored qpos (the flex and the rigid objects), an upper bound "
                "for the flex's share",
    }
    print(f"{name} {flex}: {n_vertices} vertices; mwbx {row[flex]['mwbx_qpos_bytes_per_vertex_second']:.1f}"
          f" B per vertex-second ({row[flex]['mwbx_vs_float32']:.3f}x float32)"
          + (f", SZ3 {row[flex]['sz3_bytes_per_vertex_second']:.1f} ({row[flex]['sz3_over_mwbx']:.2f}x mwbx)"
             if sz3_total else ", SZ3 not installed"))
  print(f"{name}: mwbx {row['mwbx_world_steps_per_s']:,.0f} world-steps/s, bare mujoco.rollout "
        f"{rollout:,.0f} ({row['ratio_vs_rollout']:.2f}x), {n_worlds} worlds")
  return row


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=8)
  parser.add_argument("--block", type=int, default=8, help="worlds per block, mwbx and rollout in turn")
  parser.add_argument("--scenes", default="tablecloth,soft_steps")
  parser.add_argument("--out", type=pathlib.Path, default=REPO / "out" / "bench" / "flex.json")
  args = parser.parse_args()
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, no GPU", "mujoco": mujoco.__version__,
            "scenes": [bench(name, args.worlds, args.block) for name in args.scenes.split(",")]}
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=1))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
