"""Bank bytes on disk per body-second: COM polylines as float32 against on the grid.

Samples each scene twice with the same seed, once with ``codec.e_com: null``
(float32 COM polylines, the baseline) and once with the default grid, saves
both banks and reports their bytes on disk per body-second (one tracked body
for one simulated second), what each part costs, and the whole bank against
its compressed qpos stream. Also times loading each bank (best of 3).

Writes out/bench/bank.json and prints a table. Usage:

  .venv/bin/python scripts/bench_bank.py [--worlds 128] [--scenes quickstart,pachinko]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import tempfile
import time

import jax

import mwbx

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _disk(path: pathlib.Path) -> dict:
  """Bytes on disk of a bank directory: total and per array kind."""
  parts = {"com": 0, "qpos": 0, "other": 0}
  for f in (path / "shards").rglob("*"):
    if f.is_file():
      kind = "com" if f.name.startswith("com_") or f.name == "com.npy" else \
          "qpos" if f.name.startswith("qpos_") else "other"
      parts[kind] += f.stat().st_size
  parts["manifest"] = (path / "manifest.json").stat().st_size
  parts["total"] = sum(parts.values())
  return parts


def _load_seconds(path: pathlib.Path) -> float:
  best = float("inf")
  for _ in range(3):
    start = time.perf_counter()
    mwbx.Bank.load(path)
    best = min(best, time.perf_counter() - start)
  return best


def bench_scene(name: str, n: int, tmp: pathlib.Path) -> dict:
  config = mwbx.load_config(ROOT / "configs" / f"{name}.yaml")
  out = {}
  for label, e_com in (("float32", None), ("grid", config.codec.e_com)):
    cfg = config.model_copy(update={"codec": config.codec.model_copy(update={"e_com": e_com})})
    bank = mwbx.sample(cfg, n, jax.random.key(0))
    path = tmp / f"{name}-{label}"
    bank.save(path)
    body_seconds = float(bank.frame_count.sum()) / bank.record_fps * len(bank.body_names)
    disk = _disk(path)
    out[label] = {"e_com_m": e_com, "body_seconds": body_seconds, "disk_bytes": disk,
                  "bytes_per_body_second": disk["total"] / body_seconds,
                  "qpos_stream_bytes": int(bank.qpos_store.stats()["stream_bytes"]),
                  "bank_over_qpos_stream": disk["total"] / bank.qpos_store.stats()["stream_bytes"],
                  "load_s": _load_seconds(path)}
  out["grid_over_float32"] = out["grid"]["disk_bytes"]["total"] / out["float32"]["disk_bytes"]["total"]
  return out


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=128)
  parser.add_argument("--scenes", default="quickstart,pachinko")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "bank.json")
  args = parser.parse_args()
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "worlds": args.worlds, "scenes": {}}
  with tempfile.TemporaryDirectory() as tmp:
    for name in args.scenes.split(","):
      r = result["scenes"][name] = bench_scene(name, args.worlds, pathlib.Path(tmp))
      for label in ("float32", "grid"):
        x = r[label]
        print(f"{name:<11} {label:<8} {x['bytes_per_body_second']:>9.0f} B/body-s  total {x['disk_bytes']['total']:>10,} B"
              f"  com {x['disk_bytes']['com']:>10,}  qpos {x['disk_bytes']['qpos']:>9,}"
              f"  bank/qpos stream {x['bank_over_qpos_stream']:.2f}  load {x['load_s'] * 1e3:.0f} ms")
      print(f"{name:<11} grid / float32 = {r['grid_over_float32']:.3f}")
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
