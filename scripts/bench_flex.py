"""Flexes (cloth, soft solids): sampling speed and storage, measured in one run.

For configs/tablecloth.yaml (and configs/soft_steps.yaml):

  speed    the mwbx sampler on the native backend against bare
           ``mujoco.rollout`` of the same model (no sensors, no perturbations)
           from the same initial states, a thread per core (the baseline);
  storage  the flex's stored coordinates (its vertex bodies' slide joints,
           coded under the codec's ``e_scalar`` bound): bytes per
           vertex-second against float32 vertex positions (3 floats a vertex
           a recorded frame) and against SZ3 (``pysz``, if installed) at the
           same absolute bound on the same coordinates, per world; the
           largest decoding error found.

Prints a table and writes out/bench/flex.json.

  .venv/bin/python scripts/bench_flex.py [--worlds 8] [--scenes tablecloth,soft_steps]
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


def _rollout_rate(sampler, n_worlds: int) -> float:
  """World-steps/s of bare mujoco.rollout from the sampler's initial states."""
  scene = sampler.scene
  model = build_model(scene.mjcf_text, (), scene.mjcf_dir)
  model.opt.timestep = scene.model.opt.timestep
  _, init_keys, _ = world_keys(jax.random.key(0), np.arange(n_worlds))
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
    return n_worlds * n_steps / (time.perf_counter() - start)


def _flex_columns(bank, flex: str) -> np.ndarray:
  """The qpos columns of a flex's vertex bodies' joints."""
  model = bank.model()
  bodies = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in bank.objects[flex]}
  cols = []
  for j in range(model.njnt):
    if int(model.jnt_bodyid[j]) in bodies:
      cols.append(int(model.jnt_qposadr[j]))
  return np.asarray(sorted(cols), np.int64)


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


def bench(name: str, n_worlds: int) -> dict:
  config = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  with mwbx.Sampler(config, backend="native", chunk_size=n_worlds) as sampler:
    flexes = sampler.scene.flex_objects
    with reporter(f"{name}: warm-up") as report:
      sampler.run(min(2, n_worlds), jax.random.key(1), progress=report)  # compile
    with reporter(f"{name}: sample") as report:
      bank, stats = sampler.run(n_worlds, jax.random.key(0), progress=report)
    rollout = _rollout_rate(sampler, n_worlds)
  row = {"scene": name, "worlds": n_worlds, "valid": int(bank.valid.sum()), "flexes": list(flexes),
         "mwbx_world_steps_per_s": stats.world_steps_per_second, "rollout_world_steps_per_s": rollout,
         "ratio_vs_rollout": stats.world_steps_per_second / rollout,
         "events_seconds": stats.events_seconds, "simulation_seconds": stats.run_seconds}
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
  parser.add_argument("--scenes", default="tablecloth,soft_steps")
  parser.add_argument("--out", type=pathlib.Path, default=REPO / "out" / "bench" / "flex.json")
  args = parser.parse_args()
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, no GPU", "mujoco": mujoco.__version__,
            "scenes": [bench(name, args.worlds) for name in args.scenes.split(",")]}
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=1))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
