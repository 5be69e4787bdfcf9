"""Do mjx:jax's per-query match rates agree with native's on SIGGRAPH, with
enough worlds to tell a bias from chance?

tests/batch_sim/test_backend_agreement.py samples 48 SIGGRAPH worlds per
engine (native seed 1, mjx seed 2), runs 1 s, and compares, per query
"letter X left of its native median x in the last 0.05 s", the two engines'
match rates with a two-proportion z-test, Bonferroni-corrected over the 8
queries at a family-wise 1 % (|z| < 3.23). This bench does the same with N
worlds per engine (default 256) and reports, per query and engine, the match
rate, z against native and whether it passes that critical value; also the
rates with the worlds flagged over the contact budget put back in (their
trajectories are kept; only ``bank.valid`` drops them), each world's x of the
query bodies at the end, and a two-sample Kolmogorov-Smirnov test of those x
against native (a finer check than the median split).

Engines (``--engines``, comma-separated):
  native  MuJoCo C (the reference), seed 1
  jax     mjx:jax as the test runs it (pilot budget, 20 / 4 solver caps,
          each world's solve over its rows in use), seed 2
  every   mjx:jax with ``sim.mjx.pack_rows: false`` (MJX's own solve over
          every budget row), seed 3: separates the packed solve from MJX
  wide    mjx:jax with a contact budget 3x the pilot's (headroom 4.5), seed 4:
          separates the budget caps (and the flagged worlds they drop)
  native_noperturb, jax_noperturb  both without the collision perturbations
          (``perturb.enabled: false``; randomized initial states only), seeds 5
          and 6, compared with each other: the physics without the impulses
  iters   mjx:jax with the model's solver limits (100 / 50) instead of mwbx's
          20 / 4 caps (module constants patched in this process), seed 7
  warp    mjx:warp (MuJoCo Warp's collision and solver; on the CPU here), seed 8
Seeds differ per engine, as in the test, so the worlds are independent draws;
world i of a run depends only on its seed and i, so the first 48 worlds of
``native`` and ``jax`` are the test's own.

The test module's definitions (SIGGRAPH's end time, medians, config and
queries) are copied here, not imported: tests/ is not a package. Keep them in
step with SCENES["siggraph"], _config and _queries there.

  .venv/bin/python scripts/bench_agreement.py [--worlds 256] [--engines native,jax,every]

Writes out/bench/agreement.json (rates, z, timings) and, beside it,
agreement_worlds.json (each world's answers and end x), after each engine, so
a killed run keeps what it finished.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import platform
import time

import jax
import numpy as np
from scipy import stats

import mwbx
from mwbx.bank import FLAG_CONTACT_OVERFLOW
from mwbx.queries import Query
from mwbx.queries.query import evaluate_each

REPO = pathlib.Path(__file__).resolve().parents[1]

# Copied from tests/batch_sim/test_backend_agreement.py (SCENES["siggraph"],
# FAMILY_ALPHA, _config, _queries).
END_TIME = 1.0
MEDIANS = {"letter_S": -0.458, "letter_I": -0.346, "letter_G1": -0.029, "letter_G2": -0.186,
           "letter_R": 0.106, "letter_A": 0.098, "letter_P": 0.141, "letter_H": 0.252}
FAMILY_ALPHA = 0.01

ENGINES = {  # name: (backend, impl, seed, sim.mjx overrides, perturb overrides)
    "native": ("native", "jax", 1, {}, {}),
    "jax": ("mjx", "jax", 2, {}, {}),
    "every": ("mjx", "jax", 3, {"pack_rows": False}, {}),
    "wide": ("mjx", "jax", 4, {"headroom": 4.5}, {}),
    # Without the collision perturbations (randomized initial states only): compared
    # with native_noperturb, separates the physics from where the impulses land.
    "native_noperturb": ("native", "jax", 5, {}, {"enabled": False}),
    # mjx:jax with the model's own solver limits (100 iterations / 50 line-search
    # steps) instead of mwbx's caps (mjx_backend.SOLVER_ITERATIONS / LS_ITERATIONS,
    # patched for this run only): separates the solver caps.
    "iters": ("mjx", "jax", 7, {}, {}),
    "warp": ("mjx", "warp", 8, {}, {}),  # MuJoCo Warp (its own collision), pools from the same pilot
    "jax_noperturb": ("mjx", "jax", 6, {}, {"enabled": False}),
}


def _config(impl: str, mjx_update: dict, perturb_update: dict):
  config = mwbx.load_config(REPO / "configs" / "siggraph.yaml")
  sim = config.sim.model_copy(update={"end_time": END_TIME, "mjx_impl": impl, "chunk_size": 64,
                                      "mjx": config.sim.mjx.model_copy(update=mjx_update)})
  return config.model_copy(update={"sim": sim, "perturb": config.perturb.model_copy(update=perturb_update)})


def _queries():
  return [Query.region((-10.0, -10.0, -10.0), (x, 10.0, 10.0), bodies=(body,), window=(END_TIME - 0.05, None),
                       name=f"{body}_left_of_{x}") for body, x in MEDIANS.items()]


def z_test(ka, na, kb, nb):
  """The test's two-proportion z (pooled variance), a minus b."""
  ka, kb = np.asarray(ka, float), np.asarray(kb, float)
  pooled = (ka + kb) / (na + nb)
  se = np.sqrt(np.maximum(pooled * (1 - pooled), 1e-12) * (1 / na + 1 / nb))
  return (ka / na - kb / nb) / se


def run_engine(name: str, n: int) -> dict:
  backend, impl, seed, update, perturb_update = ENGINES[name]
  config = _config(impl, update, perturb_update)
  from mwbx.batch_sim import mjx_backend  # lazy: imports mujoco.mjx
  caps = mjx_backend.SOLVER_ITERATIONS, mjx_backend.LS_ITERATIONS
  if name == "iters":
    mjx_backend.SOLVER_ITERATIONS, mjx_backend.LS_ITERATIONS = 100, 50
  try:
    t0 = time.perf_counter()
    with mwbx.Sampler(config, backend) as sampler:
      bank, st = sampler.run(n, jax.random.key(seed))
    wall = time.perf_counter() - t0
  finally:
    mjx_backend.SOLVER_ITERATIONS, mjx_backend.LS_ITERATIONS = caps
  queries = _queries()
  answers = evaluate_each(bank, queries)  # bool[W, Q], False for invalid worlds
  overflow = (bank.flags & FLAG_CONTACT_OVERFLOW) != 0
  # The same queries with the over-budget flag cleared: the worlds the test drops put back.
  unflagged = dataclasses.replace(bank, flags=bank.flags & ~np.uint8(FLAG_CONTACT_OVERFLOW))
  answers_all = evaluate_each(unflagged, queries)
  rows = np.arange(bank.n_worlds)
  last = np.minimum(round(END_TIME * bank.query_fps), bank.com_count - 1)
  x = bank.com[rows, last][:, [bank.body_names.index(b) for b in MEDIANS], 0]  # f32[W, Q]
  valid = np.asarray(bank.valid, bool)
  budget = bank.run.get("contact_budget")
  return {
      "backend": f"{backend}:{impl}" if backend == "mjx" else backend, "seed": seed, "mjx_overrides": update,
      "perturb_overrides": perturb_update,
      "solver_caps": [100, 50] if name == "iters" else list(caps) if backend == "mjx" else None, "mean_perturbations": round(float(bank.perturbations.mean()), 2),
      "worlds": n, "valid": int(valid.sum()), "contact_overflow": int(overflow.sum()),
      "unstable": int(bank.summary()["unstable"]),
      "matches": answers.sum(axis=0).tolist(), "matches_with_flagged": answers_all.sum(axis=0).tolist(),
      "stable": int(((bank.flags & (mwbx.bank.FLAG_UNSTABLE | mwbx.bank.FLAG_SIM_ERROR)) == 0).sum()),
      "answers": answers.astype(int).tolist(), "answers_with_flagged": answers_all.astype(int).tolist(),
      "x_end": np.round(x, 4).tolist(), "valid_mask": valid.astype(int).tolist(),
      "overflow_mask": overflow.astype(int).tolist(),
      "contact_budget": {k: v for k, v in (budget or {}).items() if not isinstance(v, (list, dict))} or None,
      "wall_seconds": round(wall, 1), "run_seconds": round(st.run_seconds, 1),
      "compile_seconds": round(st.compile_seconds, 1), "world_steps": int(st.world_steps),
  }


def compare(ref: dict, other: dict, names: list[str]) -> dict:
  q = len(names)
  z_crit = float(stats.norm.ppf(1 - FAMILY_ALPHA / 2 / q))
  out = {"z_crit": round(z_crit, 3), "queries": {}}
  for key, n_key in (("matches", "valid"), ("matches_with_flagged", "stable")):
    ka, na, kb, nb = ref[key], ref[n_key], other[key], other[n_key]
    z = z_test(ka, na, kb, nb)
    for i, name in enumerate(names):
      row = out["queries"].setdefault(name, {})
      suffix = "" if key == "matches" else "_with_flagged"
      row[f"rate_ref{suffix}"] = round(ka[i] / na, 3)
      row[f"rate{suffix}"] = round(kb[i] / nb, 3)
      row[f"z{suffix}"] = round(float(z[i]), 2)
      row[f"passes{suffix}"] = bool(abs(z[i]) < z_crit)
    out[f"all_pass{suffix}"] = bool((np.abs(z) < z_crit).all())
    out[f"max_abs_z{suffix}"] = round(float(np.abs(z).max()), 2)
  xa = np.asarray(ref["x_end"])[np.asarray(ref["valid_mask"], bool)]
  xb = np.asarray(other["x_end"])[np.asarray(other["valid_mask"], bool)]
  for i, name in enumerate(names):
    ks = stats.ks_2samp(xa[:, i], xb[:, i])
    out["queries"][name]["ks_p"] = round(float(ks.pvalue), 4)
    out["queries"][name]["median_x_ref"] = round(float(np.median(xa[:, i])), 4)
    out["queries"][name]["median_x"] = round(float(np.median(xb[:, i])), 4)
  # The test's own worlds: the first 48 of each run (native and jax have the test's seeds 1 and 2).
  n48 = 48
  if ref["worlds"] >= n48 and other["worlds"] >= n48:
    va, vb = (np.asarray(e["valid_mask"][:n48], bool) for e in (ref, other))
    ka, kb = (np.asarray(e["answers"][:n48]).sum(axis=0) for e in (ref, other))
    z = z_test(ka, int(va.sum()), kb, int(vb.sum()))
    out["first_48"] = {"z": np.round(z, 2).tolist(), "all_pass": bool((np.abs(z) < z_crit).all())}
  return out


PER_WORLD = ("answers", "answers_with_flagged", "x_end", "valid_mask", "overflow_mask")


def worlds_path(out_path: pathlib.Path) -> pathlib.Path:
  return out_path.with_name(out_path.stem + "_worlds.json")


def write(result: dict, out_path: pathlib.Path) -> None:
  """The summary to out_path (small, copied to docs/bench), each engine's
  per-world arrays to <stem>_worlds.json beside it (compact)."""
  summary = {**result, "engines": {k: {f: v for f, v in e.items() if f not in PER_WORLD}
                                   for k, e in result["engines"].items()}}
  summary["per_world"] = worlds_path(out_path).name
  out_path.write_text(json.dumps(summary, indent=1))
  worlds_path(out_path).write_text(json.dumps(
      {k: {f: e[f] for f in PER_WORLD if f in e} for k, e in result["engines"].items()}, separators=(",", ":")))


def read(out_path: pathlib.Path) -> dict:
  result = json.loads(out_path.read_text())
  if worlds_path(out_path).exists():
    for k, per in json.loads(worlds_path(out_path).read_text()).items():
      result["engines"].setdefault(k, {}).update(per)
  result.pop("per_world", None)
  return result


def main():
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--worlds", type=int, default=256)
  ap.add_argument("--engines", default="native,jax,every")
  ap.add_argument("--out", default=str(REPO / "out" / "bench" / "agreement.json"))
  ap.add_argument("--merge", action="store_true", help="add to the engines already in --out (same --worlds)")
  args = ap.parse_args()
  out_path = pathlib.Path(args.out)
  out_path.parent.mkdir(parents=True, exist_ok=True)
  names = [q.name for q in _queries()]
  result = {"scene": "siggraph", "end_time": END_TIME, "queries": names, "medians": MEDIANS,
            "family_alpha": FAMILY_ALPHA, "worlds_per_engine": args.worlds,
            "machine": f"{platform.machine()} {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f} at start",
            "jax": jax.__version__, "engines": {}, "vs_native": {}}
  if args.merge and out_path.exists():
    result = read(out_path)
    result.setdefault("worlds_per_engine_extra", {})
  engines = args.engines.split(",")
  for name in engines:
    print(f"[{time.strftime('%H:%M:%S')}] {name}: {args.worlds} worlds", flush=True)
    result["engines"][name] = run_engine(name, args.worlds)
    if args.worlds != result["worlds_per_engine"]:
      result.setdefault("worlds_per_engine_extra", {})[name] = args.worlds
    e = result["engines"][name]
    print(f"  {e['wall_seconds']} s wall, compile {e['compile_seconds']} s, valid {e['valid']}/{e['worlds']}, "
          f"over budget {e['contact_overflow']}", flush=True)
    ref = "native_noperturb" if name.endswith("_noperturb") else "native"
    if name != ref and ref in result["engines"]:
      result["vs_native"][name] = compare(result["engines"][ref], e, names)
    if name in ("every", "wide", "iters") and "jax" in result["engines"]:
      result.setdefault("vs_jax", {})[name] = compare(result["engines"]["jax"], e, names)
    result["load_at_end"] = round(os.getloadavg()[0], 1)
    write(result, out_path)
  for name, cmp in result["vs_native"].items():
    print(f"\n{name} vs native (z_crit {cmp['z_crit']}): all pass {cmp['all_pass']}, "
          f"with flagged worlds {cmp['all_pass_with_flagged']}")
    for q, row in cmp["queries"].items():
      print(f"  {q:28s} native {row['rate_ref']:.3f}  {name} {row['rate']:.3f}  z {row['z']:+.2f}"
            f"  (with flagged {row['rate_with_flagged']:.3f}, z {row['z_with_flagged']:+.2f})  KS p {row['ks_p']:.3f}")
  print(f"wrote {out_path}")


if __name__ == "__main__":
  main()
