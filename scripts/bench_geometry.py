"""Whole-geometry queries against COM queries on the browse bench's bank.

The bank of `scripts/bench_browse.py` (a real pachinko bank repeated to
``--worlds`` worlds). For each of ``--boxes`` screen boxes through the
scene's camera (the browse bench's boxes, include and exclude in turn) it
times the same query with ``shape="com"`` (the baseline, measured in the same
run) and ``shape="geometry"``, after one untimed warm-up that compiles the
COM kernels and builds both indexes (that build is timed separately), and
counts the worlds each answers (kept answers are cleared before each timed
geometry query, so each is computed afresh). Then the page's part, as in
`scripts/bench_browse.py`: for ``--page-boxes`` boxes drawn in turn on a
stack of at most 3 queries, the time from the box to the updated page
(evaluate the stack, redraw paths and sorter), COM and geometry boxes in
alternating rounds of 5. Orientation queries (upright at the end, and over a window) are timed
on the same bank.

Writes out/bench/geometry.json. Usage:

  .venv/bin/python scripts/bench_geometry.py [--worlds 4096] [--sample 256] [--boxes 20] [--page-boxes 20]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import time

import jax
import numpy as np

import mwbx
from mwbx import queries as mq
from mwbx.queries import geometry as geometry_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGE_ROUND = 5  # page boxes of one kind drawn in a row


def _commit() -> str:
  try:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()
  except (OSError, subprocess.CalledProcessError):
    return "unknown"


def _page_updates(bank, camera, rng, n_boxes: int) -> dict:
  """Box drawn -> page updated (ms), COM and geometry boxes in alternating rounds, on a
  stack of at most 3 queries (the page of scripts/bench_browse.py)."""
  from mwbx.browser import Browser, Session
  page = Browser(Session(bank))
  out = {}
  times = {"com": [], "geometry": []}
  try:
    page.refresh()
    # In rounds of a few boxes, COM then geometry, so that a change in the
    # machine's load falls on both.
    for start_box in range(0, n_boxes, PAGE_ROUND):
      for shape in ("com", "geometry"):
        while page.session.entries:
          page.session.remove(0)
        page.ui.geometry.value = shape == "geometry"
        _page_round(page, camera, rng, shape, min(PAGE_ROUND, n_boxes - start_box), times[shape])
  finally:
    page.close()
  for shape, ms in times.items():
    out[f"{shape}_box_to_update_ms"] = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)),
                                        "boxes": len(ms)}
  out["geometry_over_com"] = out["geometry_box_to_update_ms"]["median"] / out["com_box_to_update_ms"]["median"]
  return out


def _page_round(page, camera, rng, shape: str, n_boxes: int, times: list) -> None:
  """Draws n_boxes boxes in turn on the page's stack (at most 3 kept)."""
  for k in range(n_boxes):
    u0, v0 = rng.uniform(0.1, 0.7, 2)
    box = mq.ScreenBox(u0, v0, u0 + rng.uniform(0.05, 0.25), v0 + rng.uniform(0.05, 0.25))
    start = time.perf_counter()
    page.session.add(mq.Query.screen(camera, box, sign="include" if k % 2 == 0 else "exclude", shape=shape))
    page.refresh()
    page.server.flush()
    times.append(1e3 * (time.perf_counter() - start))
    if len(page.session.entries) > 3:
      page.session.remove(0)


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=4096)
  parser.add_argument("--sample", type=int, default=256)
  parser.add_argument("--boxes", type=int, default=20)
  parser.add_argument("--page-boxes", type=int, default=20)
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "geometry.json")
  args = parser.parse_args()
  start = time.perf_counter()
  base = mwbx.sample(mwbx.load_config(ROOT / "configs" / "pachinko.yaml"), args.sample, jax.random.key(0))
  sample_s = time.perf_counter() - start
  bank = base
  for _ in range(max(1, args.worlds // base.n_worlds) - 1):
    bank = bank.append(base)
  camera = mq.Camera.from_model(bank.model, "front")
  rng = np.random.default_rng(0)
  boxes = []
  for k in range(args.boxes):  # as scripts/bench_browse.py draws them
    u0, v0 = rng.uniform(0.1, 0.7, 2)
    boxes.append((mq.ScreenBox(u0, v0, u0 + rng.uniform(0.05, 0.25), v0 + rng.uniform(0.05, 0.25)),
                  "include" if k % 2 == 0 else "exclude"))
  warm = mq.Query.screen(camera, boxes[0][0])
  mq.evaluate_each(bank, [warm])  # compiles the COM kernels, builds the path index
  start = time.perf_counter()
  index = geometry_lib.geometry_index(bank)
  build_s = time.perf_counter() - start
  start = time.perf_counter()  # the first settle also builds the stored frames' poses (once per bank)
  mq.evaluate_each(bank, [mq.Query.screen(camera, boxes[0][0], shape="geometry")])
  first_s = time.perf_counter() - start
  com_ms, geo_ms, com_n, geo_n = [], [], [], []
  for box, sign in boxes:
    for shape, times, counts in (("com", com_ms, com_n), ("geometry", geo_ms, geo_n)):
      q = mq.Query.screen(camera, box, sign=sign, shape=shape)
      index.answers.clear()
      t = time.perf_counter()
      each = mq.evaluate_each(bank, [q])
      times.append(1e3 * (time.perf_counter() - t))
      counts.append(int(each.sum()))
  orient = {}
  for label, q in (("upright_at_end", mwbx.OrientationQuery(axis="z", within_deg=20)),
                   ("upright_over_window", mwbx.OrientationQuery(axis="z", within_deg=20, window=(1.0, 3.0)))):
    mq.evaluate_each(bank, [q])  # decodes and caches the bodies' orientations
    t = time.perf_counter()
    n = int(mq.evaluate_each(bank, [q]).sum())
    orient[label] = {"ms": 1e3 * (time.perf_counter() - t), "worlds": n}
  page = _page_updates(bank, camera, rng, args.page_boxes)
  com_ms, geo_ms = np.array(com_ms), np.array(geo_ms)
  include = np.array([s == "include" for _, s in boxes])
  result = {
      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "commit": _commit(),
      "load_average": os.getloadavg()[0], "worlds": bank.n_worlds, "bodies": len(bank.body_names),
      "boxes": args.boxes, "sample_s": sample_s, "geometry_index_build_s": build_s,
      "first_geometry_query_s": first_s,
      "com_query_ms": {"median": float(np.median(com_ms)), "p95": float(np.percentile(com_ms, 95))},
      "geometry_query_ms": {"median": float(np.median(geo_ms)), "p95": float(np.percentile(geo_ms, 95))},
      "geometry_over_com": float(np.median(geo_ms) / np.median(com_ms)),
      "include_matches": {"com": int(np.array(com_n)[include].sum()), "geometry": int(np.array(geo_n)[include].sum())},
      "exclude_matches": {"com": int(np.array(com_n)[~include].sum()),
                          "geometry": int(np.array(geo_n)[~include].sum())},
      "orientation": orient,
      "page": page,
  }
  print(f"{bank.n_worlds} worlds x {len(bank.body_names)} bodies: COM query median {np.median(com_ms):.1f} ms,"
        f" geometry query median {np.median(geo_ms):.1f} ms ({result['geometry_over_com']:.1f}x);"
        f" geometry index built in {build_s:.1f} s, first geometry query {first_s:.1f} s; include matches com/geometry "
        f"{result['include_matches']['com']}/{result['include_matches']['geometry']}, exclude "
        f"{result['exclude_matches']['com']}/{result['exclude_matches']['geometry']};"
        f" orientation " + ", ".join(f"{k} {v['ms']:.1f} ms" for k, v in orient.items())
        + f"; page box -> update median COM {page['com_box_to_update_ms']['median']:.0f} ms, geometry"
        f" {page['geometry_box_to_update_ms']['median']:.0f} ms ({page['geometry_over_com']:.1f}x)")
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
