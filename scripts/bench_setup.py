"""How long a new user waits: `make run` on a fresh clone, twice, and optionally `make test`.

Clones this repository's HEAD into a temporary folder and runs, with a fresh
``HOME`` (no pip, numba, JAX or Warp caches: a machine that never ran mwbx)
unless ``--keep-home``:
  1. ``make run``: creates ``.venv``, installs what running needs, samples
     256 quickstart worlds (compiling the native loop and the codec);
  2. ``make run`` again: appends 256 more worlds (the baseline: nothing to
     install or compile);
  3. with ``--test``: ``make test`` (installs the test extras, then the whole
     suite).
Prints each wall time and the first run over the second, and writes
out/bench/setup.json. Usage:

  .venv/bin/python scripts/bench_setup.py [--keep-home] [--test]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _timed(cmd: list[str], cwd: pathlib.Path, env: dict, label: str) -> float:
  print(f"{label}: {' '.join(cmd)} ...", flush=True)
  start = time.perf_counter()
  out = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
  seconds = time.perf_counter() - start
  if out.returncode != 0:
    raise SystemExit(f"{label} failed ({out.returncode}):\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
  print(f"{label}: {seconds:.1f} s; {out.stdout.strip().splitlines()[-1] if out.stdout.strip() else ''}", flush=True)
  return seconds


def _versions(clone: pathlib.Path, env: dict) -> dict:
  """The versions the clone's ``.venv`` resolved for the packages its figures depend on most."""
  names = ["jax", "jaxlib", "mujoco", "mujoco-mjx", "numba", "numpy"]
  code = ("import importlib.metadata as m, json; "
          f"print(json.dumps({{n: m.version(n) for n in {names!r}}}))")
  out = subprocess.run([str(clone / ".venv" / "bin" / "python"), "-c", code], cwd=clone, env=env,
                       capture_output=True, text=True, check=True)
  return json.loads(out.stdout)


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--keep-home", action="store_true", help="use this HOME (its caches) instead of a fresh one")
  parser.add_argument("--test", action="store_true", help="also time `make test`")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "setup.json")
  args = parser.parse_args()
  commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
  with tempfile.TemporaryDirectory(prefix="mwbx-setup-") as tmp:
    clone, home = pathlib.Path(tmp) / "mwbx", pathlib.Path(tmp) / "home"
    home.mkdir()
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    env = dict(os.environ)
    if not args.keep_home:
      env["HOME"] = str(home)
    env.pop("NUMBA_CACHE_DIR", None)
    result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "commit": commit,
              "fresh_home": not args.keep_home}
    result["first_make_run_s"] = _timed(["make", "run"], clone, env, "first make run")
    result["second_make_run_s"] = _timed(["make", "run"], clone, env, "second make run")
    result["versions"] = _versions(clone, env)
    if args.test:
      result["make_test_s"] = _timed(["make", "test"], clone, env, "make test")
    result["load_average"] = os.getloadavg()[0]
  result["first_over_second"] = result["first_make_run_s"] / result["second_make_run_s"]
  print(f"make run on a fresh clone ({'fresh' if not args.keep_home else 'this'} HOME): first"
        f" {result['first_make_run_s']:.0f} s, second {result['second_make_run_s']:.0f} s"
        f" ({result['first_over_second']:.1f}x)"
        + (f"; make test {result['make_test_s'] / 60:.1f} min" if args.test else ""))
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
