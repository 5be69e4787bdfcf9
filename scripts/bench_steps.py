"""Larger physics steps with speculative contacts: do a scene's outcomes
still agree with its own step, and is it faster?

MuJoCo 4's speculative contacts (``mjENBL_SPECULATIVE``) add a contact before
an impact from a conservative time of impact, so fast convex geoms do not
tunnel at larger steps; its docs suggest raising the step with them. Per
scene (``--scenes``, shipped config names) and step factor (``--factors``),
this samples the same N worlds (seed 1) with the scene as shipped and with a
copy of its MJCF whose ``<option>`` has ``timestep`` times the factor and the
speculative flag on, and reports wall, physics, world-steps, perturbations
per world (drawn per colliding step, so the step changes the perturbation
process too) and the agreement of outcomes: per outcome a Welch z of the
means and a Kolmogorov-Smirnov p, Bonferroni-corrected over the outcomes at
a family-wise 1 % (the tower's outcomes are ``bench_tower.outcomes``; other
scenes': each metric summed over bodies and the final COM of the bodies that
move most). Tunnelling shows as bodies lower than the shipped step ever puts
them: the lowest COM height of each body over every world and frame is
compared with the shipped step's.

A factor is safe on a seed where every outcome agrees, nothing goes lower
and its physics is faster (the wall of the first run of a process includes
its warm-up), and a candidate for a scene's default only where it is safe
on every seed (``--seeds``; each seed's worlds are a run of their own); the
tables in docs/benchmarks.md say which.

  .venv/bin/python scripts/bench_steps.py [--scenes trebuchet_tower] [--factors 2] [--worlds 64] [--seeds 1]
      [--append]

Writes out/bench/steps.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import re
import sys
import tempfile
import time

import jax
import numpy as np

import mwbx

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import bench_tower  # noqa: E402  (the tower's outcomes and the agreement test)

MOST_MOVING = 5  # bodies whose final COM counts as an outcome (scenes other than the tower)
LOWER_TOLERANCE = 0.005  # m a body may go below the shipped step's lowest COM before it counts as tunnelling


def speculative_copy(config_path: pathlib.Path, factor: float, folder: pathlib.Path) -> pathlib.Path:
  """A config whose scene is a copy of the MJCF with the step times ``factor``
  and speculative contacts on (in ``folder``, an empty one, beside links to
  the MJCF's sibling files)."""
  config = mwbx.load_config(config_path)
  model = mwbx.Scene(config).model
  mjcf = pathlib.Path(config.scene.mjcf)
  if not mjcf.is_absolute():
    mjcf = (REPO / "mwbx" / "assets" / mjcf) if (REPO / "mwbx" / "assets" / mjcf).exists() else config_path.parent / mjcf
  text = mjcf.read_text()
  step = repr(float(model.opt.timestep) * factor)
  flag = '<flag speculative="enable"/>'
  if re.search(r"<option\b[^>]*/>", text):
    text = re.sub(r"<option\b([^>]*?)\s*/>", lambda m: f"<option{_with_step(m.group(1), step)}>{flag}</option>", text,
                  count=1)
  elif re.search(r"<option\b", text):
    text = re.sub(r"<option\b([^>]*)>", lambda m: f"<option{_with_step(m.group(1), step)}>{flag}", text, count=1)
  else:
    text = re.sub(r"(<mujoco\b[^>]*>)", rf'\1<option timestep="{step}">{flag}</option>', text, count=1)
  # Both files are written before the MJCF's siblings are linked in, and only
  # as new files: a write never goes through a link into the shipped assets.
  copy = folder / mjcf.name
  out = folder / f"{config_path.stem}.steps.yaml"
  _write_new(copy, text)
  _write_new(out, re.sub(r"(mjcf:\s*)\S+", rf"\g<1>{copy}", config_path.read_text(), count=1))
  for sibling in mjcf.parent.iterdir():  # includes, meshes
    if sibling.is_file() and not (folder / sibling.name).exists():
      (folder / sibling.name).symlink_to(sibling)
  return out


def _write_new(path: pathlib.Path, text: str) -> None:
  with open(path, "x") as f:  # fails if anything (a link included) is there
    f.write(text)


def _with_step(attributes: str, step: str) -> str:
  attributes = re.sub(r'\s*timestep="[^"]*"', "", attributes)
  return f'{attributes} timestep="{step}"'


def sample(config_path: pathlib.Path, n: int, seed: int):
  config = mwbx.load_config(config_path)
  t0 = time.perf_counter()
  with mwbx.Sampler(config, "native") as sampler:
    bank, st = sampler.run(n, jax.random.key(seed))
  return bank, {"wall_seconds": round(time.perf_counter() - t0, 2), "physics_seconds": round(st.run_seconds, 2),
                "world_steps": int(st.world_steps), "timestep": float(bank.model.opt.timestep),
                "mean_perturbations": round(float(bank.perturbations.mean()), 1), "valid": int(bank.valid.sum())}


def outcomes(name: str, bank, moving=None) -> dict[str, np.ndarray]:
  if name == "trebuchet_tower":
    return bench_tower.outcomes(bank)
  rows = np.arange(bank.n_worlds)
  last = bank.com[rows, bank.com_count - 1]
  out = {f"sum_{m}": bank.metrics[:, :, i].sum(axis=1).astype(float) for i, m in enumerate(bank.metric_names)}
  for b in moving:
    for axis, label in enumerate("xyz"):
      out[f"{bank.body_names[b]}_{label}"] = last[:, b, axis].astype(float)
  return out


def lowest(bank) -> np.ndarray:
  """f64[B] each body's lowest COM height over every world and frame."""
  return np.array([min(float(np.nanmin(bank.com[w, :bank.com_count[w], b, 2])) for w in range(bank.n_worlds))
                   for b in range(len(bank.body_names))])


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--scenes", default="trebuchet_tower")
  parser.add_argument("--factors", default="2")
  parser.add_argument("--worlds", type=int, default=64)
  parser.add_argument("--seeds", default="1", help="the run keys; each seed is a run of its own")
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "steps.json"))
  parser.add_argument("--append", action="store_true", help="keep the runs already in --out (a scene and seed"
                      " measured again replaces its run)")
  args = parser.parse_args()
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}", "worlds": args.worlds,
            "runs": []}
  if args.append and pathlib.Path(args.out).exists():
    result["runs"] = json.loads(pathlib.Path(args.out).read_text())["runs"]
  for name in args.scenes.split(","):
    for seed in (int(s) for s in args.seeds.split(",")):
      result["runs"] = [r for r in result["runs"] if (r["scene"], r["seed"]) != (name, seed)]
      result["runs"].append(run_scene(name, seed, args))
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(json.dumps(result, indent=2) + "\n")
  print(f"wrote {out}")


def run_scene(name: str, seed: int, args) -> dict:
  """The shipped step and each factor of one scene on the worlds of one seed."""
  config_path = REPO / "configs" / f"{name}.yaml"
  base, base_t = sample(config_path, args.worlds, seed)
  print(name, f"seed {seed}", "shipped", base_t, flush=True)
  moving = None
  if name != "trebuchet_tower":
    path = np.array(base.metrics[:, :, list(base.metric_names).index("path_length")].mean(axis=0))
    moving = list(np.argsort(path)[::-1][:MOST_MOVING])
  base_low = lowest(base)
  rows = {"scene": name, "seed": seed, "shipped": base_t, "factors": {}}
  for factor in (float(f) for f in args.factors.split(",")):
    with tempfile.TemporaryDirectory() as folder:
      other, t = sample(speculative_copy(config_path, factor, pathlib.Path(folder)), args.worlds, seed)
    agree = bench_tower.agreement(outcomes(name, base, moving), outcomes(name, other, moving))
    deeper = base_low - lowest(other)
    t.update(agreement=agree, speedup_wall=round(base_t["wall_seconds"] / t["wall_seconds"], 2),
             speedup_physics=round(base_t["physics_seconds"] / t["physics_seconds"], 2),
             deepest_below_shipped_m=round(float(deeper.max()), 4),
             deepest_body=base.body_names[int(np.argmax(deeper))],
             ks_fails=[k for k, r in agree["outcomes"].items() if r["ks_p"] < 0.01 / len(agree["outcomes"])])
    t["safe"] = bool(agree["all_pass"] and not t["ks_fails"] and t["deepest_below_shipped_m"] <= LOWER_TOLERANCE
                     and t["speedup_physics"] > 1.0)
    rows["factors"][str(factor)] = t
    print(name, f"seed {seed}", f"x{factor}", {k: v for k, v in t.items() if k != "agreement"}, flush=True)
  return rows


if __name__ == "__main__":
  main()
