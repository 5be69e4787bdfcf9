"""Refining a tower world as a user first does it: from the browsing page,
and as the README's `mwbx refine` command.

A fresh process opens the tower bank that ``scripts/bench_tower.py`` saved
(``out/bench/tower_sleep_on``, 64 worlds sampled with sleep) in the page
(``mwbx.browse``, no browser needed: the page's handlers are called as a
client's clicks call them), plays world 2, seeks to 0.8 s, picks the rock and
the page's default sample count, and presses *Refine playing world*. Timed
from the press to the page listing the new worlds (its status line says
"refined world ..."): the first refinement of the session, so the loop's and
the codec's compiles (or cache loads) are in it, as they are for a user; then
a second press, compiles done. Also the time for the first new world to play.
Then the README's command, ``mwbx refine BANK --world 2 --objects rock
--time 0.8 --samples 64``, on a copy of the bank in a fresh process (imports,
loading, compiles and saving included), timed as a whole.

  .venv/bin/python scripts/bench_page_refine.py [--bank out/bench/tower_sleep_on] [--world 2]

Writes out/bench/page_refine.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import shutil
import subprocess
import sys
import tempfile
import time

import mwbx
from mwbx.browser import browse

REPO = pathlib.Path(__file__).resolve().parents[1]
TIMEOUT = 600  # s: a stuck refinement ends the bench, never hangs it


def press_refine(page) -> dict:
  """Presses *Refine playing world*; seconds until the new worlds are listed
  and until the first of them plays."""
  before = page.session.job
  page.ui.status_md.content = ""
  t0 = time.perf_counter()
  page.ui.buttons["Refine playing world"].value = True
  job = page.session.job
  if job is None or job is before:
    raise SystemExit(f"the page did not start a refinement: {page.ui.status_md.content}")
  deadline = t0 + TIMEOUT
  while not page.ui.status_md.content.startswith(("refined world", "error")) and time.perf_counter() < deadline:
    time.sleep(0.02)
  listed = time.perf_counter() - t0
  if not page.ui.status_md.content.startswith("refined world"):
    raise SystemExit(f"refinement failed: {page.ui.status_md.content}")
  page.play(int(job.new_ids[0]))
  playing = time.perf_counter() - t0
  return {"listed_seconds": round(listed, 2), "first_plays_seconds": round(playing, 2),
          "new_worlds": int(len(job.new_ids))}


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--bank", default=str(REPO / "out" / "bench" / "tower_sleep_on"))
  parser.add_argument("--world", type=int, default=2)
  parser.add_argument("--time", type=float, default=0.8)
  parser.add_argument("--out", default=str(REPO / "out" / "bench" / "page_refine.json"))
  args = parser.parse_args()
  t0 = time.perf_counter()
  page = browse(mwbx.Bank.load(args.bank), path=args.bank, block=False)
  opened = time.perf_counter() - t0
  try:
    page.play(args.world)
    page.player.seek(int(round(args.time * page.session.bank.record_fps)))
    page.ui.objects.value = "rock"
    result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}",
              "bank_worlds": int(page.session.bank.n_worlds), "world": args.world, "t_min": args.time,
              "samples": int(page.ui.samples.value), "page_open_seconds": round(opened, 2)}
    result["first"] = press_refine(page)
    print("first ", result["first"], flush=True)
    page.play(args.world)
    page.player.seek(int(round(args.time * page.session.bank.record_fps)))
    result["second"] = press_refine(page)
    print("second", result["second"], flush=True)
  finally:
    page.close()
  with tempfile.TemporaryDirectory() as folder:
    copy = pathlib.Path(folder) / "bank"
    shutil.copytree(args.bank, copy)
    command = [str(pathlib.Path(sys.executable).with_name("mwbx")), "refine", str(copy), "--world", str(args.world),
               "--objects", "rock", "--time", str(args.time), "--samples", "64"]
    t0 = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT)
    result["command"] = {"argv": " ".join(["mwbx"] + command[1:2] + ["BANK"] + command[3:]),
                         "wall_seconds": round(time.perf_counter() - t0, 2), "exit": done.returncode,
                         "report": [line for line in done.stdout.splitlines() if line.startswith("world-steps/s")]}
    print("command", result["command"], flush=True)
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(json.dumps(result, indent=2) + "\n")
  print(f"wrote {out}")


if __name__ == "__main__":
  main()
