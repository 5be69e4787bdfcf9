"""`mwbx browse` in a real browser (Playwright driving Debian's chromium):
the page needs its token, drawn boxes give the counts mwbx.queries gives for
the same frustum, undo, saved query files (and none outside the bank
directory), the sorter plays worlds, refinement from the page (one at a time,
cancellable), and the server stops on SIGINT and SIGTERM, naming the
refinements not saved."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.browser.app import free_port

from viewer_banks import quickstart_bank
from mwbx.testing.headless import CHROMIUM_BINARY, WEBGL_ARGS

QUERY_LINE = re.compile(r"mwbx browse: query (\d+) (\w+) box=(\[[^\]]*\]) bodies=(\S+) mode=(\w+) "
                        r"window=(\S+) camera eye=(\[[^\]]*\]) right=(\[[^\]]*\]) up=(\[[^\]]*\]) "
                        r"forward=(\[[^\]]*\]) fovy=(\S+) aspect=(\S+) -> (\d+) worlds, all queries (\d+) of (\d+)")
WAIT = 300  # seconds: a loaded machine is slow, never wrong


def _default_sigint():  # the suite may run with SIGINT ignored (nohup, background jobs)
  signal.signal(signal.SIGINT, signal.SIG_DFL)


class Server:
  """`mwbx browse BANK` in a subprocess, its stdout lines in a queue; ``url``
  the address it printed (with its token)."""

  def __init__(self, bank_dir, cwd):
    self.port = free_port()
    self.proc = subprocess.Popen([sys.executable, "-m", "mwbx.cli", "browse", str(bank_dir), "--no-browser",
                                  "--port", str(self.port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True, cwd=cwd, preexec_fn=_default_sigint)
    self.lines: queue.Queue = queue.Queue()
    self.stderr: list = []
    threading.Thread(target=self._read, args=(self.proc.stdout, self.lines.put), daemon=True).start()
    threading.Thread(target=self._read, args=(self.proc.stderr, self.stderr.append), daemon=True).start()
    deadline = time.monotonic() + WAIT
    while not any("browsing" in line for line in self.stderr):
      assert self.proc.poll() is None and time.monotonic() < deadline, self.stderr
      time.sleep(0.1)
    self.url = re.search(r"browsing \d+ worlds at (\S+)", "\n".join(self.stderr)).group(1)
    assert self.url == f"http://127.0.0.1:{self.port}/?token={self.url.split('=', 1)[1]}"

  @staticmethod
  def _read(stream, put):
    for line in stream:
      put(line.rstrip("\n"))

  def expect(self, pattern: str) -> re.Match:
    """The next stdout line matching ``pattern`` (other lines are skipped)."""
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
      try:
        line = self.lines.get(timeout=1)
      except queue.Empty:
        assert self.proc.poll() is None, self.stderr
        continue
      match = re.search(pattern, line)
      if match:
        return match
    raise AssertionError(f"no line matching {pattern!r}; stderr: {self.stderr}")

  def stop(self, sig=signal.SIGINT) -> float:
    start = time.monotonic()
    self.proc.send_signal(sig)
    try:
      code = self.proc.wait(timeout=WAIT)
    finally:  # a server that did not stop is not left behind
      if self.proc.poll() is None:
        self.proc.kill()
        self.proc.wait()
    assert code == 0, self.stderr
    return time.monotonic() - start


def _camera(m: re.Match) -> mq.Camera:
  eye, right, up, forward = (np.array(json.loads(m.group(i))) for i in (7, 8, 9, 10))
  return mq.Camera(eye=eye, right=right, up=up, forward=forward, fovy=float(m.group(11)),
                   aspect=float(m.group(12)))


def _arm(page, sign: str) -> None:
  """Presses the draw button and waits until the server has armed the box
  (its answer comes after the rect-select registration on the same socket)."""
  page.get_by_text(f"Draw {sign} box").click()
  page.get_by_text(f"drag a box in the view for an {sign} query").wait_for(timeout=WAIT * 1000)


def _drag(page, x0, y0, x1, y1):
  page.mouse.move(x0, y0)
  page.mouse.down()
  page.mouse.move(x1, y1, steps=8)
  page.mouse.up()


def test_browse_page_draw_undo_save_sort_refine(browser, tmp_path):
  from playwright.sync_api import sync_playwright
  bank_dir = tmp_path / "bank"
  quickstart_bank(16).save(bank_dir)
  bank = mwbx.Bank.load(bank_dir)
  server = Server(bank_dir, tmp_path)
  try:
    with sync_playwright() as pw:
      chromium = pw.chromium.launch(executable_path=CHROMIUM_BINARY, args=list(WEBGL_ARGS))
      page = chromium.new_page(viewport={"width": 1200, "height": 800})
      assert page.goto(f"http://127.0.0.1:{server.port}/", timeout=WAIT * 1000).status == 403  # no token
      page.goto(server.url, timeout=WAIT * 1000)
      page.get_by_text("Draw include box").wait_for(timeout=WAIT * 1000)
      # A first box tells the camera the page looks through; undone.
      _arm(page, "include")
      _drag(page, 330, 280, 560, 520)
      camera = _camera(server.expect(QUERY_LINE.pattern))
      page.get_by_text("Undo", exact=True).click()
      page.get_by_text(re.compile(r"^16 of 16 worlds")).wait_for(timeout=WAIT * 1000)
      # Boxes around where the ball ends in the left and in the right half of the worlds.
      ball = bank.select_bodies("ball")[0]
      ends = bank.com[np.arange(bank.n_worlds), bank.com_count - 1, ball]
      uv, _ = camera.project(ends)
      order = np.argsort(uv[:, 0])
      left, right = uv[order[:6]], uv[order[-6:]]
      pixels = lambda pts: (*(pts.min(0) * [1200, 800] - 6), *(pts.max(0) * [1200, 800] + 6))  # noqa: E731
      # An include box: the page's count is what mwbx.queries gives for the
      # frustum of the same box and camera.
      _arm(page, "include")
      _drag(page, *pixels(left))
      first = server.expect(QUERY_LINE.pattern)
      assert first.group(2) == "include"
      box = json.loads(first.group(3))
      query = mq.Query.screen(_camera(first), box)
      want = int(np.asarray(mq.evaluate(bank, [query])).sum())
      assert int(first.group(13)) == want and 0 < want < bank.n_worlds
      page.get_by_text(re.compile(rf"^{want} of 16 worlds")).wait_for(timeout=WAIT * 1000)
      # An exclude box: the conjunction.
      _arm(page, "exclude")
      _drag(page, *pixels(right))
      second = server.expect(QUERY_LINE.pattern)
      both = [query, mq.Query.screen(_camera(second), json.loads(second.group(3)), sign="exclude")]
      want_both = int(np.asarray(mq.evaluate(bank, both)).sum())
      assert int(second.group(14)) == want_both
      page.get_by_text(re.compile(rf"^{want_both} of 16 worlds")).wait_for(timeout=WAIT * 1000)
      # Undo takes the exclude box back.
      page.get_by_text("Undo", exact=True).click()
      page.get_by_text(re.compile(rf"^{want} of 16 worlds")).wait_for(timeout=WAIT * 1000)
      page.get_by_text("Redo", exact=True).click()
      page.get_by_text(re.compile(rf"^{want_both} of 16 worlds")).wait_for(timeout=WAIT * 1000)
      # Saved as a query file, `mwbx query` gives the same counts.
      page.get_by_text("Save queries").click()
      server.expect(r"saved .*queries\.yaml")
      report = subprocess.run([sys.executable, "-m", "mwbx.cli", "query", str(bank_dir),
                               str(bank_dir / "queries.yaml"), "--json"],
                              capture_output=True, text=True, timeout=WAIT)
      assert report.returncode == 0, report.stderr
      counts = json.loads(report.stdout)
      assert counts["count"] == want_both
      assert [q["matches"] for q in counts["queries"]] == [int(first.group(13)), int(second.group(13))]
      # No query file outside the bank directory, and no file's content on the page.
      secret = "c2VjcmV0LXRva2VuLTEyMzQ1"
      (tmp_path / "creds.yaml").write_text(f'{{"auths": {{"registry.example": {{"auth": "{secret}"}}}}}}\n')
      (bank_dir / "creds.yaml").write_text(f'{{"auths": {{"registry.example": {{"auth": "{secret}"}}}}}}\n')
      for name, button, why in (("../escaped/dir/pwned.yaml", "Save queries", "outside"),
                                (str(tmp_path / "pwned.yaml"), "Save queries", "outside"),
                                (str(tmp_path / "creds.yaml"), "Open queries", "outside"),
                                ("creds.yaml", "Open queries", "not a query file")):
        # (viser's text input is not tied to its label: found through the label's row)
        page.locator("xpath=//label[text()='Query file']/ancestor::div[contains(@class, 'mantine-Flex-root')][1]"
                     "//input").fill(name)
        time.sleep(0.5)
        page.get_by_text(button).click()
        line = server.expect(rf"error: query file .*{why}").group(0)
        assert secret not in line
        page.get_by_text(re.compile(rf"error: query file .*{why}")).wait_for(timeout=WAIT * 1000)
      assert not (tmp_path / "escaped").exists() and not (tmp_path / "pwned.yaml").exists()
      assert secret not in page.content()
      # A sorter row plays its world.
      row = page.get_by_text(re.compile(r"^world \d+ · ")).first
      world = int(re.match(r"world (\d+)", row.inner_text()).group(1))
      row.click()
      server.expect(rf"playing world {world}$")
      page.get_by_text(f"playing world {world}").wait_for(timeout=WAIT * 1000)
      # A second world overlaid on the first, both named on the page.
      page.get_by_text("Add to the playing worlds").click()
      other = page.get_by_text(re.compile(r"^world \d+ · ")).nth(1)
      second_world = int(re.match(r"world (\d+)", other.inner_text()).group(1))
      other.click()
      server.expect(rf"playing world {second_world} \(added\)")
      page.get_by_text(f"playing world {world}, world {second_world}").wait_for(timeout=WAIT * 1000)
      page.get_by_text("Add to the playing worlds").click()
      # Refine the last one played: 4 samples from the page, then save the bank.
      world = second_world
      page.get_by_label("Samples").fill("4")
      time.sleep(0.5)
      page.get_by_text("Refine playing world").click()
      done = server.expect(r"refined world (\d+): new worlds (\d+)\.\.(\d+) \(parent (\d+)\)")
      assert int(done.group(1)) == world and int(done.group(4)) == world
      assert int(done.group(3)) - int(done.group(2)) == 3
      page.get_by_text("Save bank").click()
      server.expect(r"saved ")
      # One refinement at a time, and a cancelled one adds nothing.
      page.get_by_label("Samples").fill("4096")
      time.sleep(0.5)
      page.get_by_text("Refine playing world").click()
      server.expect(rf"refining \S+ of world {world} from .* 4096 samples")
      page.get_by_text("Refine playing world").click()
      server.expect(rf"error: refine: world {world} is being refined \(4096 samples\)")
      page.get_by_text("Cancel refinement").click()
      server.expect(rf"refinement of world {world} cancelled; nothing added")
      # A refinement not saved is named when the server stops.
      page.get_by_label("Samples").fill("2")
      time.sleep(0.5)
      page.get_by_text("Refine playing world").click()
      lost = server.expect(r"refined world (\d+): new worlds (\d+)\.\.(\d+)")
      chromium.close()
  finally:
    if server.proc.poll() is None:
      server.stop()
  assert any(f"2 refined worlds (ids {lost.group(2)}..{lost.group(3)}) were not saved" in line
             for line in server.stderr), server.stderr
  grown = mwbx.Bank.load(bank_dir)
  assert grown.n_worlds == bank.n_worlds + 4
  assert grown.children(world).tolist() == list(range(int(done.group(2)), int(done.group(3)) + 1))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_browse_stops_on_signals_and_leaves_no_child(tmp_path, sig):
  bank_dir = tmp_path / "bank"
  quickstart_bank(4).save(bank_dir)
  server = Server(bank_dir, tmp_path)
  children = [int(c) for c in open(f"/proc/{server.proc.pid}/task/{server.proc.pid}/children").read().split()]
  seconds = server.stop(sig)
  print(f"mwbx browse stopped {seconds:.2f} s after {sig.name}")
  for child in children:
    assert not os.path.exists(f"/proc/{child}") or "Z" in open(f"/proc/{child}/stat").read().split()[2]
