"""The scale benchmark: the paper's trebuchet and tower at its dataset size,
and a synthetic 100 k-world bank.

Phases (``--phases``, default all but ``million`` and ``hundred_k``; results merge into
out/bench/scale.json, so phases can run at different times):

- ``sample``: ``mwbx sample configs/trebuchet_tower.yaml --worlds 1549`` (the
  paper's dataset size) as a child process on the native backend: wall time,
  world-steps/s, peak memory (the child's max RSS), bank bytes per world.
  Baseline measured in the same run: plain ``mj_step`` of the same MJCF on
  one thread for 2 s of the scene (no mwbx), times the sampler's threads --
  the physics floor; the ratio says what the sampler's own work costs.
- ``tower``: opening that bank and answering its query file
  (configs/queries/trebuchet_tower.yaml), each in a fresh child process: wall
  time and peak memory, opened lazily (the default: indexed whole below
  ``paths.IN_MEMORY_COM_BYTES``), lazily and streamed a shard at a time, and
  -- the baseline -- eagerly (``Bank.load(path, lazy=False)``); the answers
  must be equal; whether the first evaluation started from the stored path
  boxes, and their bytes against the bank's; then ``mwbx info`` and ``mwbx
  query`` as a user runs them (fresh processes).
- ``synthetic``: a pachinko-size bank of 100 k worlds (sampled worlds of
  configs/pachinko.yaml written again under new ids, shard after shard), then
  opened and queried as above but for eagerly; baseline: its COM polylines
  as float32 (the least an eager bank holds).
- ``million``: ``--million-worlds`` (default 1,000,000) quickstart worlds of
  ``--million-end-time`` seconds (default 0.5), every one sampled by ``mwbx
  sample`` in a child process (wall, world-steps/s, peak memory, bytes); then
  ``mwbx info`` and ``mwbx query BANK configs/queries/quickstart.yaml`` as a
  user runs them (fresh processes: wall with Python's start and imports, peak
  memory), and opening and querying lazily and streamed as above.
- ``hundred_k``: as ``million``, ``--hundred-k-worlds`` (default 100,000)
  full-length quickstart worlds (4 s, the shipped config).

With ``--reuse``, ``million`` and ``hundred_k`` browse the bank their last run
sampled again (its sampling figures kept, with the commit that sampled it).

Usage:

  .venv/bin/python scripts/bench_scale.py [--phases sample,tower,synthetic]
      [--worlds 1549] [--synthetic-worlds 100000] [--million-worlds 1000000]
      [--hundred-k-worlds 100000]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import platform
import resource
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "bench"
BANKS = OUT / "scale"
TOWER = ROOT / "configs" / "trebuchet_tower.yaml"
TOWER_QUERIES = ROOT / "configs" / "queries" / "trebuchet_tower.yaml"
PACHINKO = ROOT / "configs" / "pachinko.yaml"
PACHINKO_QUERIES = ROOT / "configs" / "queries" / "pachinko.yaml"
QUICKSTART = ROOT / "configs" / "quickstart.yaml"
QUICKSTART_QUERIES = ROOT / "configs" / "queries" / "quickstart.yaml"


def _machine() -> dict:
  return {"machine": platform.machine(), "processor": platform.processor() or platform.machine(),
          "cpus": os.cpu_count(), "python": platform.python_version(),
          "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                   cwd=ROOT).stdout.strip()}


def _child(code: str) -> dict:
  """Runs python ``code`` in a fresh process; it prints one JSON line. Adds the
  child's peak RSS (MB): VmHWM, which starts afresh at exec (ru_maxrss keeps
  the forking parent's)."""
  wrapper = (code + "\nimport json as _j\n"
             "_hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]\n"
             "print(_j.dumps(dict(RESULT, peak_rss_mb=int(_hwm) / 1024)))")
  out = subprocess.run([sys.executable, "-c", wrapper], capture_output=True, text=True, cwd=ROOT)
  if out.returncode:
    raise SystemExit(f"child failed:\n{out.stderr[-3000:]}")
  return json.loads(out.stdout.strip().splitlines()[-1])


def _disk_bytes(path: pathlib.Path) -> int:
  return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def plain_physics_rate(config_path: pathlib.Path, seconds: float = 2.0) -> float:
  """Steps/s of plain mj_step on the scene's MJCF, one thread (the floor)."""
  return _child(f"""
import time, mujoco, mwbx
scene = mwbx.Scene(mwbx.load_config({str(config_path)!r}))
m = mujoco.MjModel.from_xml_string(scene.mjcf_text)  # the MJCF as written: no mwbx sensors
m.opt.timestep = scene.model.opt.timestep
d = mujoco.MjData(m)
n = int({seconds} / m.opt.timestep)
t0 = time.perf_counter()
for _ in range(n):
  mujoco.mj_step(m, d)
RESULT = dict(steps_per_second=n / (time.perf_counter() - t0), steps=n)
""")["steps_per_second"]


def _sample(config: pathlib.Path, n_worlds: int, out: pathlib.Path) -> dict:
  """``mwbx sample CONFIG --worlds N --backend native --out OUT`` in a child
  process: wall seconds, world-steps/s as it prints them, the peak memory of
  this process's children so far (MB) and its summary lines."""
  t0 = time.perf_counter()
  proc = subprocess.run([sys.executable, "-m", "mwbx.cli", "sample", str(config), "--worlds", str(n_worlds),
                         "--backend", "native", "--out", str(out)], capture_output=True, text=True, cwd=ROOT)
  wall = time.perf_counter() - t0
  if proc.returncode:
    raise SystemExit(proc.stderr[-3000:])
  summary = {line.split("  ")[0]: line for line in proc.stdout.splitlines()}
  return {"wall_seconds": wall, "world_steps_per_second": float(summary["world-steps/s"].split()[1].replace(",", "")),
          "peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
          "summary": proc.stdout.strip().splitlines()}


def phase_sample(n_worlds: int) -> dict:
  bank = BANKS / "trebuchet_tower"
  if bank.exists():
    import shutil
    shutil.rmtree(bank)
  floor = plain_physics_rate(TOWER)
  load_before = os.getloadavg()[0]
  run = _sample(TOWER, n_worlds, bank)
  wall, rate = run["wall_seconds"], run["world_steps_per_second"]
  threads = os.cpu_count()
  return {
      "worlds": n_worlds, "wall_seconds": wall, "wall_minutes": wall / 60, "world_steps_per_second": rate,
      "plain_mj_step_per_second_one_thread": floor, "threads": threads,
      "ratio_to_physics_floor": rate / (floor * threads), "peak_rss_mb": run["peak_rss_mb"],
      "bank_bytes": _disk_bytes(bank), "bank_bytes_per_world": _disk_bytes(bank) / n_worlds,
      "load_average_before": load_before, "load_average_after": os.getloadavg()[0],
      "summary": run["summary"]}


_OPEN = """
import time, mwbx
t0 = time.perf_counter(); bank = mwbx.Bank.load({path!r}{lazy}); t_open = time.perf_counter() - t0
RESULT = dict(open_seconds=t_open, worlds=bank.n_worlds)
"""

_QUERY = """
import time, hashlib, mwbx
from mwbx.queries import paths as query
if {streamed}:
  query.IN_MEMORY_COM_BYTES = 0  # a shard at a time, whatever the bank's size
t0 = time.perf_counter(); bank = mwbx.Bank.load({path!r}{lazy}); t_open = time.perf_counter() - t0
qs = mwbx.load_queries({queries!r}, bank)
from_boxes = query.answered_from_boxes(bank)
t0 = time.perf_counter(); each = mwbx.evaluate_each(bank, qs); t_first = time.perf_counter() - t0
t0 = time.perf_counter(); each = mwbx.evaluate_each(bank, qs); t_second = time.perf_counter() - t0
RESULT = dict(open_seconds=t_open, query_seconds=t_first, query_again_seconds=t_second,
              streamed=query.streams(bank), from_boxes=from_boxes,
              matches=[int(x) for x in each.sum(0)], all_match=int(each.all(1).sum()),
              answers_sha=hashlib.sha256(each.tobytes()).hexdigest()[:16], worlds=bank.n_worlds)
"""


def open_and_query(path: pathlib.Path, queries: pathlib.Path, eager_baseline: bool) -> dict:
  """Opening and querying in fresh processes: lazily (mwbx's default policy:
  indexed whole up to paths.IN_MEMORY_COM_BYTES), lazily and streamed a shard
  at a time, and (baseline) eagerly."""
  out = {}
  modes = [("lazy", "", False), ("streamed", "", True)]
  if eager_baseline:
    modes.append(("eager", ", lazy=False", False))
  for label, lazy, streamed in modes:
    out[label] = {"open": _child(_OPEN.format(path=str(path), lazy=lazy)),
                  "query": _child(_QUERY.format(path=str(path), lazy=lazy, queries=str(queries),
                                                streamed=streamed))}
  out["same_answers"] = len({out[label]["query"]["answers_sha"] for label, _, _ in modes}) == 1
  if eager_baseline:
    out["query_time_ratio_lazy_to_eager"] = (out["lazy"]["query"]["query_seconds"]
                                             / out["eager"]["query"]["query_seconds"])
    out["peak_memory_ratio_lazy_to_eager"] = (out["lazy"]["query"]["peak_rss_mb"]
                                              / out["eager"]["query"]["peak_rss_mb"])
    out["peak_memory_ratio_streamed_to_eager"] = (out["streamed"]["query"]["peak_rss_mb"]
                                                  / out["eager"]["query"]["peak_rss_mb"])
  out["bank_bytes"] = _disk_bytes(path)
  out["index_bytes"] = sum(f.stat().st_size for f in path.glob("shards/*/index_boxes.npy"))
  out["index_fraction_of_bank"] = out["index_bytes"] / out["bank_bytes"]
  return out


def phase_tower() -> dict:
  bank = BANKS / "trebuchet_tower"
  if not bank.exists():
    raise SystemExit(f"{bank}: run the sample phase first")
  result = open_and_query(bank, TOWER_QUERIES, eager_baseline=True)
  result["bank_bytes_per_world"] = result["bank_bytes"] / result["lazy"]["open"]["worlds"]
  result["info"] = _command(["info", str(bank)])
  result["query"] = _command(["query", str(bank), str(TOWER_QUERIES)])
  return result


def phase_synthetic(n_worlds: int, seed_worlds: int = 1024) -> dict:
  """A pachinko-size bank of ``n_worlds``: ``seed_worlds`` sampled ones, their
  shard written again under new ids until the bank holds ``n_worlds``."""
  import shutil

  import jax
  import numpy as np

  import mwbx
  from mwbx.bank import BankDirectory

  path = BANKS / "pachinko_100k"
  if path.exists():
    shutil.rmtree(path)
  t0 = time.perf_counter()
  part = mwbx.sample(mwbx.load_config(PACHINKO), seed_worlds, jax.random.key(0), backend="native")
  sample_seconds = time.perf_counter() - t0
  directory = BankDirectory(path)
  t0 = time.perf_counter()
  for start in range(0, n_worlds, seed_worlds):
    n = min(seed_worlds, n_worlds - start)
    chunk = dataclasses.replace(part._take(np.arange(n)), world_ids=np.arange(start, start + n, dtype=np.int64))
    directory.append(chunk)
  write_seconds = time.perf_counter() - t0
  result = open_and_query(path, PACHINKO_QUERIES, eager_baseline=False)
  result.update(worlds=n_worlds, seed_worlds=seed_worlds, sample_seconds=sample_seconds,
                write_seconds=write_seconds, bank_bytes_per_world=result["bank_bytes"] / n_worlds,
                com_float32_bytes=int(n_worlds * part.com[0].nbytes))
  # Baseline: the polylines alone as float32 in memory (what an eager bank holds at least).
  result["peak_memory_ratio_streamed_to_float32_com"] = (
      result["streamed"]["query"]["peak_rss_mb"] * 2**20 / result["com_float32_bytes"])
  return result


_COMMAND = """
import runpy, sys
sys.argv = ["mwbx"] + {args!r}
try:
  runpy.run_module("mwbx.cli", run_name="__main__")
except SystemExit as stop:
  assert not stop.code, stop.code
RESULT = {{}}
"""


def _command(args: list[str]) -> dict:
  """``mwbx ARGS`` as a user runs it, in a fresh process: wall seconds
  (Python's start and mwbx's imports included) and peak memory."""
  t0 = time.perf_counter()
  result = _child(_COMMAND.format(args=args))
  return dict(result, wall_seconds=time.perf_counter() - t0)


def phase_quickstart(name: str, n_worlds: int, end_time: float, before: dict | None = None) -> dict:
  """``n_worlds`` quickstart worlds of ``end_time`` s, each sampled by mwbx,
  then browsed from fresh processes (bank ``quickstart_<name>``). With
  ``before`` (this phase's last results, ``--reuse``), the bank that run
  sampled is browsed again and its sampling figures are kept."""
  import shutil

  path = BANKS / f"quickstart_{name}"
  if before is not None:
    if not path.exists() or before.get("worlds") != n_worlds:
      raise SystemExit(f"--reuse: no bank of {n_worlds} worlds from an earlier {name} phase at {path}")
    result = open_and_query(path, QUICKSTART_QUERIES, eager_baseline=False)
    kept = ("worlds", "end_time", "sample_wall_seconds", "sample_peak_rss_mb", "world_steps_per_second",
            "shards", "load_average_before", "load_average_after", "summary")
    result.update({k: before[k] for k in kept if k in before},
                  sampled_at_commit=before.get("sampled_at_commit", before["machine"]["commit"]),
                  bank_bytes_per_world=result["bank_bytes"] / n_worlds,
                  info=_command(["info", str(path)]),
                  query=_command(["query", str(path), str(QUICKSTART_QUERIES)]))
    return result
  if path.exists():
    shutil.rmtree(path)
  config = QUICKSTART
  text = QUICKSTART.read_text()
  if "end_time: 4.0" not in text:
    raise SystemExit(f"{QUICKSTART}: no 'end_time: 4.0' to change")
  if end_time != 4.0:
    config = BANKS / f"quickstart_{name}.yaml"
    config.write_text(text.replace("end_time: 4.0", f"end_time: {end_time}"))  # the packaged quickstart.xml
  load_before = os.getloadavg()[0]
  run = _sample(config, n_worlds, path)  # this phase's first child: its peak is the sampler's
  result = open_and_query(path, QUICKSTART_QUERIES, eager_baseline=False)
  result.update(
      worlds=n_worlds, end_time=end_time, sample_wall_seconds=run["wall_seconds"],
      sample_peak_rss_mb=run["peak_rss_mb"], world_steps_per_second=run["world_steps_per_second"],
      bank_bytes_per_world=result["bank_bytes"] / n_worlds,
      shards=sum(1 for _ in (path / "shards").iterdir()),
      info=_command(["info", str(path)]),
      query=_command(["query", str(path), str(QUICKSTART_QUERIES)]),
      load_average_before=load_before, load_average_after=os.getloadavg()[0], summary=run["summary"])
  return result


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--phases", default="sample,tower,synthetic")
  parser.add_argument("--worlds", type=int, default=1549)
  parser.add_argument("--synthetic-worlds", type=int, default=100_000)
  parser.add_argument("--million-worlds", type=int, default=1_000_000)
  parser.add_argument("--million-end-time", type=float, default=0.5)
  parser.add_argument("--hundred-k-worlds", type=int, default=100_000)
  parser.add_argument("--reuse", action="store_true",
                      help="million, hundred_k: browse the bank the last such phase sampled again, without sampling")
  args = parser.parse_args()
  OUT.mkdir(parents=True, exist_ok=True)
  BANKS.mkdir(parents=True, exist_ok=True)
  file = OUT / "scale.json"
  results = json.loads(file.read_text()) if file.exists() else {}
  for phase in args.phases.split(","):
    print(f"bench_scale: {phase} ...", flush=True)
    start = time.perf_counter()
    if phase == "sample":
      results["sample"] = phase_sample(args.worlds)
    elif phase == "tower":
      results["tower"] = phase_tower()
    elif phase == "synthetic":
      results["synthetic"] = phase_synthetic(args.synthetic_worlds)
    elif phase == "million":
      results["million"] = phase_quickstart("million", args.million_worlds, args.million_end_time,
                                            results.get("million") if args.reuse else None)
    elif phase == "hundred_k":
      results["hundred_k"] = phase_quickstart("hundred_k", args.hundred_k_worlds, 4.0,
                                              results.get("hundred_k") if args.reuse else None)
    else:
      raise SystemExit(f"--phases: unknown phase {phase!r}")
    results[phase]["machine"] = _machine()
    results[phase]["phase_seconds"] = time.perf_counter() - start
    file.write_text(json.dumps(results, indent=1))
    print(json.dumps(results[phase], indent=1)[:4000], flush=True)
  print(f"wrote {file}")


if __name__ == "__main__":
  main()
