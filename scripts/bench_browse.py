"""Browsing latency: from a drawn box to updated counts, paths and sorter.

A real pachinko bank (``--sample`` worlds) is repeated to ``--worlds`` worlds
(appended copies get new ids; the size is what matters here). For each of
``--boxes`` screen boxes through the scene's camera it times what the page
does when a rect-select event arrives (build the frustum, put the query on
the stack, re-evaluate every query, redraw the paths and frustums, rebuild
the sorter), and the same for a metric re-sort. Baseline, measured in the
same run: the CLI round trip the page replaces (``mwbx query BANK Q.yaml``
in a new process, the same queries).

Writes out/bench/browse.json and prints a table. Usage:

  .venv/bin/python scripts/bench_browse.py [--worlds 4096] [--sample 256] [--boxes 20]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import re
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

import mwbx
from mwbx import queries as mq
from mwbx.browser import Browser, Session

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _in_browser(page, camera) -> dict:
  """Page load time (to the GUI shown, scene and paths sent) and websocket bytes
  the page receives for one box update, in headless Chromium."""
  sys.path.insert(0, str(ROOT / "tests"))
  from playwright.sync_api import sync_playwright
  from viewer_render import CHROMIUM_BINARY, WEBGL_ARGS
  received = []
  with sync_playwright() as pw:
    chromium = pw.chromium.launch(executable_path=CHROMIUM_BINARY, args=list(WEBGL_ARGS))
    tab = chromium.new_page(viewport={"width": 1200, "height": 800})
    tab.on("websocket", lambda ws: ws.on("framereceived", lambda payload: received.append(len(payload))))
    start = time.perf_counter()
    tab.goto(page.url)
    tab.get_by_text("Draw include box").wait_for(timeout=600_000)
    tab.get_by_text(re.compile(r"^world \d+ · ")).first.wait_for(timeout=600_000)
    load_s = time.perf_counter() - start
    tab.wait_for_timeout(2000)  # (the sync API delivers websocket events only while it waits)
    before = sum(received)
    page.session.add(mq.Query.screen(camera, mq.ScreenBox(0.3, 0.4, 0.5, 0.6)))
    page.refresh()
    page.server.flush()
    tab.wait_for_timeout(2000)
    update_bytes = sum(received) - before
    chromium.close()
  return {"page_load_s": load_s, "initial_bytes": before, "bytes_per_box_update": update_bytes}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=4096)
  parser.add_argument("--sample", type=int, default=256)
  parser.add_argument("--boxes", type=int, default=20)
  parser.add_argument("--browser", action="store_true",
                      help="also page load time and bytes sent per update, in headless Chromium")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "browse.json")
  args = parser.parse_args()
  base = mwbx.sample(mwbx.load_config(ROOT / "configs" / "pachinko.yaml"), args.sample, jax.random.key(0))
  parts = [base] * max(1, args.worlds // base.n_worlds)
  bank = parts[0]
  for part in parts[1:]:
    bank = bank.append(part)
  page = Browser(Session(bank))
  camera = mq.Camera.from_model(bank.model(), "front")
  in_browser = _in_browser(page, camera) if args.browser else None
  rng = np.random.default_rng(0)
  add_s, sort_s = [], []
  try:
    page.refresh()  # compiles the query kernels and builds the path index once
    for k in range(args.boxes):
      u0, v0 = rng.uniform(0.1, 0.7, 2)
      box = mq.ScreenBox(u0, v0, u0 + rng.uniform(0.05, 0.25), v0 + rng.uniform(0.05, 0.25))
      sign = "include" if k % 2 == 0 else "exclude"
      start = time.perf_counter()
      page.session.add(mq.Query.screen(camera, box, sign=sign))
      page.refresh()
      page.server.flush()
      add_s.append(time.perf_counter() - start)
      if len(page.session.entries) > 3:  # keep a stack of a few queries, as a person would
        page.session.remove(0)
      start = time.perf_counter()
      page.metric.value = bank.metric_names[k % len(bank.metric_names)]
      page.refresh()
      page.server.flush()
      sort_s.append(time.perf_counter() - start)
    with tempfile.TemporaryDirectory() as tmp:
      bank_dir = bank.save(pathlib.Path(tmp) / "bank")
      page.session.workdir = pathlib.Path(tmp)  # the page's query files stay under its directory
      qfile = page.session.save_queries("q.yaml")
      cli_s = []
      for _ in range(3):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "mwbx.cli", "query", str(bank_dir), qfile], check=True,
                       capture_output=True, timeout=600)
        cli_s.append(time.perf_counter() - start)
  finally:
    page.close()
  add_ms, sort_ms = 1e3 * np.array(add_s), 1e3 * np.array(sort_s)
  result = {
      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "worlds": bank.n_worlds,
      "bodies": len(bank.body_names), "boxes": args.boxes,
      "box_to_update_ms": {"median": float(np.median(add_ms)), "p95": float(np.percentile(add_ms, 95))},
      "resort_ms": {"median": float(np.median(sort_ms)), "p95": float(np.percentile(sort_ms, 95))},
      "cli_query_round_trip_s": float(min(cli_s)),
      "cli_over_page": float(min(cli_s) / (np.median(add_ms) / 1e3)),
      "browser": in_browser,
  }
  if in_browser:
    print(f"page load {in_browser['page_load_s']:.1f} s ({in_browser['initial_bytes'] / 1e6:.1f} MB);"
          f" one box update sends {in_browser['bytes_per_box_update'] / 1e6:.2f} MB")
  print(f"{bank.n_worlds} worlds x {len(bank.body_names)} bodies: box -> update median "
        f"{result['box_to_update_ms']['median']:.0f} ms, p95 {result['box_to_update_ms']['p95']:.0f} ms;"
        f" re-sort median {result['resort_ms']['median']:.0f} ms, p95 {result['resort_ms']['p95']:.0f} ms;"
        f" mwbx query round trip {result['cli_query_round_trip_s']:.2f} s"
        f" ({result['cli_over_page']:.0f}x the page update)")
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
