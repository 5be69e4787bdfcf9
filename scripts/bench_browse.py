"""Browsing latency: from a drawn box to updated counts, paths and sorter.

A real pachinko bank (``--sample`` worlds) is repeated to ``--worlds`` worlds
(appended copies get new ids; the size is what matters here). For each of
``--boxes`` screen boxes through the scene's camera it times what the page
does when a rect-select event arrives (build the frustum, put the query on
the stack, re-evaluate every query, redraw the paths and frustums, rebuild
the sorter), and the same for a metric re-sort. Baseline, measured in the
same run: the CLI round trip the page replaces (``mwbx query BANK Q.yaml``
in a new process, the same queries). Then the same for ``--geometry-boxes``
whole-geometry boxes (``shape="geometry"``; the geometry index is built
before the timing, once per bank), and the play latency of a sorter click on
a 20-body scene (tests/scenes/twenty.yaml, ``--play-worlds`` worlds): decode,
forward kinematics and poses sent (in process), and with ``--browser`` from
the click in Chromium to the page saying the world plays.

With ``--bank PATH`` it browses that bank on disk instead, opened as ``mwbx
browse`` opens it (lazily): page ready, box -> counts (boxes that split the
bank apart), re-sort, click -> poses sent, and the ``mwbx query`` round trip.

Writes out/bench/browse.json (or ``--out``) and prints a table. Usage:

  .venv/bin/python scripts/bench_browse.py [--worlds 4096] [--sample 256] [--boxes 20]
  .venv/bin/python scripts/bench_browse.py --bank out/bench/scale/quickstart_hundred_k --out out/bench/browse_100k.json
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
from mwbx.viewer import display

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _in_browser(page, camera) -> dict:
  """Page load time (to the GUI shown, scene and paths sent) and websocket bytes
  the page receives for one box update, in headless Chromium."""
  from playwright.sync_api import sync_playwright
  from mwbx.testing.headless import CHROMIUM_BINARY, WEBGL_ARGS
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


PLAY_SCENE = ROOT / "tests" / "scenes" / "twenty.yaml"


def _play_latency(n_worlds: int, clicks: int, in_browser: bool, scene: pathlib.Path = PLAY_SCENE) -> dict:
  """Sorter click -> world playing, on the 20-body scene (or ``scene``, e.g.
  the tablecloth): per click, decode + FK (ms) and the whole play (decode, FK,
  poses and flex surfaces to the page, flushed), the first click of a slot
  (its meshes uploaded) apart from the others."""
  from mwbx.viewer.kinematics import body_trajectories
  bank = mwbx.sample(mwbx.load_config(scene), n_worlds, jax.random.key(0))
  page = Browser(Session(bank))
  decode_fk, play = [], []
  try:
    page.play(0)
    page.server.flush()
    first_uploads = page.stage.uploads
    for k in range(clicks):
      world = int(bank.world_ids[1 + k % (bank.n_worlds - 1)])
      page.player._poses.clear()  # every click decodes afresh (no kept worlds)
      start = time.perf_counter()
      body_trajectories(page.model, bank.qpos_frames(world).astype(np.float64), page.stage.body_ids)
      decode_fk.append(time.perf_counter() - start)
      page.player._poses.clear()
      start = time.perf_counter()
      page.play(world)
      page.server.flush()
      play.append(time.perf_counter() - start)
    assert page.stage.uploads == first_uploads  # no mesh sent again
    # What the page redraws each frame: the paths' segments as drawn (simplified) and as recorded.
    drawn_segments = sum(page.path_segments.values())
    recorded_segments = len(display.polyline_segments(np.asarray(bank.com), np.asarray(bank.com_count)))
    browser_ms = _play_in_browser(page, bank, clicks) if in_browser else None
  finally:
    page.close()
  return {"scene": os.path.relpath(scene, ROOT), "flexes": list(bank.scene().flex_objects),
          "bodies": len(bank.body_names), "meshes_per_slot": first_uploads, "clicks": clicks,
          "path_segments_drawn": int(drawn_segments), "path_segments_recorded": int(recorded_segments),
          "decode_fk_ms": float(1e3 * np.median(decode_fk)), "play_ms": float(1e3 * np.median(play)),
          "play_p95_ms": float(1e3 * np.percentile(play, 95)), "browser_click_to_playing_ms": browser_ms}


# The page's frame rate over two seconds (requestAnimationFrame callbacks per
# second): low while WebGL rendering keeps the main thread busy.
_FRAME_RATE_JS = """() => new Promise(done => { let n = 0; const t0 = performance.now();
  const tick = () => { n++; if (performance.now() - t0 < 2000) requestAnimationFrame(tick);
                       else done(n / ((performance.now() - t0) / 1000)); };
  requestAnimationFrame(tick); })"""


# In-page timing of a click's answer, on the page's own clock: the last
# pointer press, and the first time the page shows "playing world N" after
# it (a MutationObserver on the panel's text) and the animation frame that
# follows (the world drawn). Playwright's own waits check the page at
# intervals, from outside it, so a wall clock around them is coarse.
_CLICK_TIMING_JS = """() => {
  const t = window.__mwbxTiming = {press: 0, shown: []};
  document.addEventListener("pointerdown", () => { t.press = performance.now(); }, true);
  new MutationObserver(records => {
    const now = performance.now();
    for (const r of records) {
      const nodes = [r.target, ...r.addedNodes];
      for (let a = r.target.parentNode, up = 0; a && up < 4; a = a.parentNode, up++) nodes.push(a);
      for (const n of nodes) {
        const text = (n.textContent || "");
        if (text.length > 200) continue;
        const m = text.match(/playing world (\\d+)/);
        if (m) {
          const e = {world: Number(m[1]), press: t.press, shown: now, drawn: null};
          t.shown.push(e);
          requestAnimationFrame(() => { e.drawn = performance.now(); });
          return;
        }
      }
    }
  }).observe(document.body, {subtree: true, childList: true, characterData: true});
}"""


def _play_in_browser(page, bank, clicks: int) -> dict:
  """Median / p95 ms from a sorter-row click in headless Chromium to the page
  saying the world plays (the poses are sent before that line), for mouse
  clicks at the row and for Playwright's locator clicks, with what
  keeps the page busy: its frame rate idle and while a world plays, and the
  websocket messages per second it receives while playing. Mouse clicks are
  also timed in the page (:data:`_CLICK_TIMING_JS`): press → text shown, and
  → the next frame drawn."""
  from playwright.sync_api import sync_playwright
  from mwbx.testing.headless import CHROMIUM_BINARY, WEBGL_ARGS
  arrived = {}
  play = page.play

  def timed_play(world, add=False):  # when the click reaches the server
    arrived[int(world)] = time.perf_counter()
    play(world, add=add)

  page.play = timed_play
  messages = []
  with sync_playwright() as pw:
    chromium = pw.chromium.launch(executable_path=CHROMIUM_BINARY, args=list(WEBGL_ARGS))
    tab = chromium.new_page(viewport={"width": 1200, "height": 800})
    tab.on("websocket", lambda ws: ws.on("framereceived", lambda _: messages.append(time.perf_counter())))
    tab.goto(page.url)
    rows = tab.get_by_text(re.compile(r"^world \d+ · "))
    rows.first.wait_for(timeout=600_000)
    tab.wait_for_timeout(2000)  # the scene and paths arrive and are drawn
    idle_fps = tab.evaluate(_FRAME_RATE_JS)
    tab.evaluate(_CLICK_TIMING_JS)
    in_page = []
    # A person's click (mouse events at the row, sent at once) and
    # Playwright's locator click (which first waits for the row to be stable
    # over two animation frames: slow frames delay it).
    out, to_server = {"mouse": [], "locator": []}, {"mouse": [], "locator": []}
    for how in ("mouse", "locator"):
      for k in range(clicks + 1):
        row = rows.nth(k % min(4, rows.count()))
        world = int(re.match(r"world (\d+)", row.inner_text()).group(1))
        other = page.playing_world
        row.scroll_into_view_if_needed()  # (the sorter sits low in the panel)
        tab.wait_for_timeout(300)
        box = row.bounding_box()
        start = time.perf_counter()
        if how == "mouse":
          tab.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        else:
          row.click()
        if world == other:
          continue
        tab.get_by_text(f"playing world {world}", exact=True).wait_for(timeout=600_000)
        if k:  # (a slot's first click uploads its meshes)
          out[how].append(time.perf_counter() - start)
          to_server[how].append(arrived[world] - start)
          if how == "mouse":
            tab.wait_for_timeout(500)  # (the frame after the text)
            timing = tab.evaluate("() => window.__mwbxTiming")
            event = next(e for e in timing["shown"] if e["world"] == world and e["press"] == timing["press"])
            in_page.append((event["shown"] - event["press"], event["drawn"] - event["press"]))
    start = time.perf_counter()
    playing_fps = tab.evaluate(_FRAME_RATE_JS)
    per_s = sum(1 for t in messages if t >= start) / (time.perf_counter() - start)
    chromium.close()
  ms, server_ms = 1e3 * np.array(out["mouse"]), 1e3 * np.array(to_server["mouse"])
  locator_ms = 1e3 * np.array(out["locator"])
  shown_ms, drawn_ms = np.array(in_page).T
  return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "clicks": len(ms),
          "in_page_shown_median": float(np.median(shown_ms)), "in_page_shown_p95": float(np.percentile(shown_ms, 95)),
          "in_page_drawn_median": float(np.median(drawn_ms)), "in_page_drawn_p95": float(np.percentile(drawn_ms, 95)),
          "click_to_server_median": float(np.median(server_ms)),
          "locator_click_median": float(np.median(locator_ms)), "locator_click_p95": float(np.percentile(locator_ms, 95)),
          "locator_click_to_server_median": float(np.median(1e3 * np.array(to_server["locator"]))),
          "idle_frames_per_s": float(idle_fps),
          "playing_frames_per_s": float(playing_fps), "playing_messages_per_s": float(per_s)}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=4096)
  parser.add_argument("--sample", type=int, default=256)
  parser.add_argument("--boxes", type=int, default=20)
  parser.add_argument("--geometry-boxes", type=int, default=5)
  parser.add_argument("--play-worlds", type=int, default=8)
  parser.add_argument("--clicks", type=int, default=10)
  parser.add_argument("--browser", action="store_true",
                      help="also page load time and bytes sent per update, in headless Chromium")
  parser.add_argument("--only-play", action="store_true",
                      help="run only the play part and update its entry in --out (the other parts kept)")
  parser.add_argument("--play-scene", type=pathlib.Path, default=PLAY_SCENE,
                      help="the scene of the play part (e.g. configs/tablecloth.yaml)")
  parser.add_argument("--play-key", default="play",
                      help="with --only-play: the entry of --out it writes (e.g. play_cloth)")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "browse.json")
  parser.add_argument("--bank", type=pathlib.Path,
                      help="browse this bank on disk instead (boxes through --camera; writes only that part)")
  parser.add_argument("--camera", default="front", help="with --bank: the scene's camera the boxes are drawn in")
  args = parser.parse_args()
  if args.bank:
    _saved_bank(args)
    return
  if args.only_play:
    _only_play(args)
    return
  base = mwbx.sample(mwbx.load_config(ROOT / "configs" / "pachinko.yaml"), args.sample, jax.random.key(0))
  parts = [base] * max(1, args.worlds // base.n_worlds)
  bank = parts[0]
  for part in parts[1:]:
    bank = bank.append(part)
  page = Browser(Session(bank))
  camera = mq.Camera.from_model(bank.model, "front")
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
      page.ui.metric.value = bank.metric_names[k % len(bank.metric_names)]
      page.refresh()
      page.server.flush()
      sort_s.append(time.perf_counter() - start)
    geometry_s = []
    while page.session.entries:
      page.session.remove(0)
    page.ui.geometry.value = True
    for k in range(args.geometry_boxes + 1):
      u0, v0 = rng.uniform(0.1, 0.7, 2)
      box = mq.ScreenBox(u0, v0, u0 + rng.uniform(0.05, 0.25), v0 + rng.uniform(0.05, 0.25))
      start = time.perf_counter()
      page.session.add(mq.Query.screen(camera, box, sign="include" if k % 2 == 0 else "exclude", shape="geometry"))
      page.refresh()
      page.server.flush()
      if k:  # the first builds the bank's geometry index
        geometry_s.append(time.perf_counter() - start)
      else:
        index_s = time.perf_counter() - start
      if len(page.session.entries) > 3:
        page.session.remove(0)
    with tempfile.TemporaryDirectory() as tmp:
      bank_dir = pathlib.Path(tmp) / "bank"
      bank.save(bank_dir)
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
  add_ms, sort_ms, geo_ms = 1e3 * np.array(add_s), 1e3 * np.array(sort_s), 1e3 * np.array(geometry_s)
  play = _play_latency(args.play_worlds, args.clicks, args.browser, args.play_scene.resolve())
  result = {
      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "worlds": bank.n_worlds,
      "bodies": len(bank.body_names), "boxes": args.boxes,
      "box_to_update_ms": {"median": float(np.median(add_ms)), "p95": float(np.percentile(add_ms, 95))},
      "resort_ms": {"median": float(np.median(sort_ms)), "p95": float(np.percentile(sort_ms, 95))},
      "cli_query_round_trip_s": float(min(cli_s)),
      "cli_over_page": float(min(cli_s) / (np.median(add_ms) / 1e3)),
      "browser": in_browser,
      "geometry_box_to_update_ms": {"median": float(np.median(geo_ms)), "p95": float(np.percentile(geo_ms, 95)),
                                    "boxes": len(geometry_s), "first_with_index_build_s": float(index_s)},
      "play": play,
  }
  if in_browser:
    print(f"page load {in_browser['page_load_s']:.1f} s ({in_browser['initial_bytes'] / 1e6:.1f} MB);"
          f" one box update sends {in_browser['bytes_per_box_update'] / 1e6:.2f} MB")
  print(f"{bank.n_worlds} worlds x {len(bank.body_names)} bodies: box -> update median "
        f"{result['box_to_update_ms']['median']:.0f} ms, p95 {result['box_to_update_ms']['p95']:.0f} ms;"
        f" re-sort median {result['resort_ms']['median']:.0f} ms, p95 {result['resort_ms']['p95']:.0f} ms;"
        f" mwbx query round trip {result['cli_query_round_trip_s']:.2f} s"
        f" ({result['cli_over_page']:.0f}x the page update)")
  print(f"geometry box -> update median {result['geometry_box_to_update_ms']['median']:.0f} ms"
        f" (index built in {index_s:.1f} s); play on {play['bodies']} bodies: decode + FK {play['decode_fk_ms']:.1f} ms,"
        f" click -> poses sent {play['play_ms']:.1f} ms median (p95 {play['play_p95_ms']:.1f})"
        + (f", in Chromium {play['browser_click_to_playing_ms']['median']:.0f} ms median (of which click to"
           f" server {play['browser_click_to_playing_ms']['click_to_server_median']:.0f} ms)"
           if play["browser_click_to_playing_ms"] else ""))
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


def _saved_bank(args) -> None:
  """Browsing a bank on disk (``--bank``) as ``mwbx browse BANK`` opens it
  (lazily): the page ready (opened, first refresh sent), box -> counts for
  ``--boxes`` include boxes through the scene camera, those that split the bank
  (5-95 % of its worlds kept) apart, re-sorts, and a sorter click -> the
  world's poses sent (with ``--browser``, also in headless Chromium); baseline in the same run: ``mwbx query`` with the page's
  last queries, in a fresh process."""
  load = os.getloadavg()[0]
  start = time.perf_counter()
  bank = mwbx.Bank.load(args.bank)
  page = Browser(Session(bank))
  page.server.flush()
  ready_s = time.perf_counter() - start
  camera = mq.Camera.from_model(bank.model, args.camera)
  rng = np.random.default_rng(0)
  boxes, sort_s, play_s = [], [], []
  try:
    for k in range(args.boxes):
      u0, v0 = rng.uniform(0.05, 0.75, 2)
      box = mq.ScreenBox(u0, v0, u0 + rng.uniform(0.05, 0.3), v0 + rng.uniform(0.05, 0.3))
      start = time.perf_counter()
      page.session.add(mq.Query.screen(camera, box))
      page.refresh()
      page.server.flush()
      seconds = time.perf_counter() - start
      boxes.append((seconds, page.session.counts().per_query[-1] / bank.n_worlds))
      page.session.remove(len(page.session.entries) - 1)
      start = time.perf_counter()
      page.ui.metric.value = bank.metric_names[k % len(bank.metric_names)]
      page.refresh()
      page.server.flush()
      sort_s.append(time.perf_counter() - start)
    for k in range(args.clicks + 1):
      world = int(bank.world_ids[rng.integers(bank.n_worlds)])
      start = time.perf_counter()
      page.play(world)
      page.server.flush()
      if k:  # (the first uploads the slot's meshes)
        play_s.append(time.perf_counter() - start)
    browser_ms = _play_in_browser(page, bank, args.clicks) if args.browser else None
    with tempfile.TemporaryDirectory() as tmp:
      page.session.workdir = pathlib.Path(tmp)
      page.session.add(mq.Query.screen(camera, mq.ScreenBox(0.3, 0.3, 0.6, 0.6)))
      qfile = page.session.save_queries("q.yaml")
      start = time.perf_counter()
      subprocess.run([sys.executable, "-m", "mwbx.cli", "query", str(args.bank), qfile], check=True,
                     capture_output=True, timeout=1200)
      cli_s = time.perf_counter() - start
  finally:
    page.close()
  seconds = np.array([b[0] for b in boxes])
  kept = np.array([b[1] for b in boxes])
  split = (kept > 0.05) & (kept < 0.95)
  ms = lambda x: {"median": float(1e3 * np.median(x)), "p95": float(1e3 * np.percentile(x, 95)), "n": len(x)}
  result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "bank": str(args.bank),
            "worlds": bank.n_worlds, "bodies": len(bank.body_names), "load_average": load,
            "page_ready_s": ready_s, "box_to_counts_ms": ms(seconds),
            "splitting_box_to_counts_ms": ms(seconds[split]) if split.any() else None,
            "first_box_s": float(seconds[0]), "kept_fractions": [float(x) for x in kept],
            "resort_ms": ms(sort_s), "click_to_poses_sent_ms": ms(play_s), "cli_query_round_trip_s": cli_s,
            "browser_click_to_playing_ms": browser_ms}
  print(json.dumps(result, indent=1))
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


def _only_play(args) -> None:
  """The play part alone, written into --out's existing figures."""
  load = os.getloadavg()[0]
  play = _play_latency(args.play_worlds, args.clicks, args.browser, args.play_scene.resolve())
  commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
  play.update(load_average=load, commit=commit.stdout.strip() or None)
  result = json.loads(args.out.read_text()) if args.out.exists() else {}
  result[args.play_key] = play
  b = play["browser_click_to_playing_ms"]
  print(f"play on {play['bodies']} bodies: decode + FK {play['decode_fk_ms']:.1f} ms, click -> poses sent"
        f" {play['play_ms']:.1f} ms median (p95 {play['play_p95_ms']:.1f})"
        + (f"; in Chromium {b['median']:.0f} ms median, p95 {b['p95']:.0f}; in the page's clock press -> shown"
           f" {b['in_page_shown_median']:.0f} ms median (p95 {b['in_page_shown_p95']:.0f}), -> next frame drawn"
           f" {b['in_page_drawn_median']:.0f} (p95 {b['in_page_drawn_p95']:.0f}) (click to server"
           f" {b['click_to_server_median']:.0f} ms); locator clicks {b['locator_click_median']:.0f} ms median; page frames/s idle {b['idle_frames_per_s']:.1f},"
           f" playing {b['playing_frames_per_s']:.1f}; {b['playing_messages_per_s']:.0f} messages/s while playing"
           if b else ""))
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
