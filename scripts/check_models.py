"""Models written by others, end to end: each MJCF given is sampled from a
config naming only it (``scene: {mjcf: …}`` and ``end_time``), drawn in the
meshcat viewer (offline) and opened in the browsing page, whose first view is
checked to be outside every body's paths.

Prints one JSON line per model: the rates chosen, unstable worlds, whether
both views opened, whether the page's eye is outside the paths' box (widened
by the largest moving geom), and the geoms drawn (geom groups 3+ and
transparent geoms are hidden, as in MuJoCo's viewer). A model that fails
prints its one-line error, or the traceback's tail.

Usage (e.g. on dm_control's suite and MuJoCo's humanoid and shadow-hand test models):

  .venv/bin/python scripts/check_models.py path/to/suite/*.xml [--worlds 4] [--end-time 1.0]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time
import traceback

import jax
import meshcat
import numpy as np

import mwbx
from mwbx import viewer
from mwbx.browser import app


def check(mjcf: pathlib.Path, folder: pathlib.Path, worlds: int, end_time: float) -> dict:
  """One model's row (see the module docstring)."""
  row = {"model": str(mjcf)}
  config = folder / f"{mjcf.stem}.yaml"
  config.write_text(f"scene: {{mjcf: {json.dumps(str(mjcf.resolve()))}}}\nsim: {{end_time: {end_time}}}\n")
  try:
    start = time.perf_counter()
    scene = mwbx.Scene(mwbx.load_config(config))
    row["rates"] = scene.rates.describe()
    bank = mwbx.sample(scene, n_worlds=worlds, key=jax.random.key(0), backend="native")
    row["unstable"] = int((~np.asarray(bank.valid)).sum())
    row["sample_s"] = round(time.perf_counter() - start, 1)
    vis = meshcat.Visualizer(window=viewer.SceneRecorder())
    viewer.draw(vis, bank, worlds=[int(bank.world_ids[0])])
    row["viewer"] = "ok"
    page = app.browse(bank, block=False)
    try:
      eye = np.asarray(page.server.initial_camera.position, np.float64)
      com = np.asarray(bank.com)[np.asarray(bank.valid, bool)].reshape(-1, 3)
      model = page.model
      margin = float(model.geom_rbound[model.body_weldid[model.geom_bodyid] != 0].max())
      lo, hi = com.min(axis=0) - margin, com.max(axis=0) + margin
      row["page"] = "ok"
      row["eye_outside_paths"] = bool(not np.all((eye > lo) & (eye < hi)))
      row["geoms_drawn"] = f"{len(page.visuals)}/{model.ngeom}"
    finally:
      page.close()
  except mwbx.MwbxError as err:
    row["error"] = str(err)
  except Exception:  # a traceback is what this script is looking for
    row["error"] = "traceback: " + traceback.format_exc()[-800:]
  return row


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("mjcf", nargs="+", type=pathlib.Path)
  parser.add_argument("--worlds", type=int, default=4)
  parser.add_argument("--end-time", type=float, default=1.0)
  args = parser.parse_args()
  with tempfile.TemporaryDirectory() as folder:
    for mjcf in args.mjcf:
      print(json.dumps(check(mjcf, pathlib.Path(folder), args.worlds, args.end_time)), flush=True)


if __name__ == "__main__":
  main()
