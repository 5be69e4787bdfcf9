"""The page's newer tools, in a real browser (Playwright driving Debian's
chromium) and in process: whole-geometry boxes, orientation queries and their
sorter metric, several bodies per query, worlds side by side, playing a world
without uploading meshes again, and adding and removing objects from the
page with the lineage shown."""

from __future__ import annotations

import json
import re
import shutil
import time

import jax
import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.browser import Browser, Session
from mwbx.browser.session import ORIENTATION_ERROR

from test_browse import QUERY_LINE, WAIT, Server, _arm, _camera, _drag
from mwbx.testing.headless import CHROMIUM_BINARY, WEBGL_ARGS


def _tick(checkbox) -> None:
  """Ticks a page checkbox and waits until it shows ticked. Playwright's
  ``check()`` reads the box right after its click, and the page's React
  renders the tick a frame later, late on a busy machine ("Clicking the
  checkbox did not change its state" with three test workers on 2 cores)."""
  from playwright.sync_api import expect
  checkbox.click()
  expect(checkbox).to_be_checked(timeout=WAIT * 1000)

ORIENTATION_LINE = re.compile(r"mwbx browse: query (\d+) orientation upright axis=(\S+) within_deg=(\S+) "
                              r"bodies=(.+) mode=(\w+) window=(\S+) -> (\d+) worlds, all queries (\d+) of (\d+)")


def _scenes_dir():
  import pathlib
  return pathlib.Path(__file__).resolve().parents[1] / "scenes"


def _tiny_with_block(tmp_path):
  """tiny.yaml copied into ``tmp_path`` and a later version of it with a
  block added (tiny_block.yaml, its MJCF including tiny.xml)."""
  scenes = _scenes_dir()
  shutil.copy(scenes / "tiny.xml", tmp_path / "tiny.xml")
  shutil.copy(scenes / "tiny.yaml", tmp_path / "tiny.yaml")
  (tmp_path / "tiny_block.xml").write_text(
      '<mujoco model="tiny_block">\n  <include file="tiny.xml"/>\n  <worldbody>\n'
      '    <body name="block" pos="0.1 0 0.5">\n      <freejoint/>\n'
      '      <geom type="box" size="0.03 0.03 0.03" mass="0.2" rgba="0.9 0.7 0.1 1"/>\n'
      '    </body>\n  </worldbody>\n</mujoco>\n')
  (tmp_path / "tiny_block.yaml").write_text(
      (tmp_path / "tiny.yaml").read_text().replace("tiny.xml", "tiny_block.xml"))
  return tmp_path / "tiny.yaml", tmp_path / "tiny_block.yaml"


def _field(page, label: str):
  """The input of a labelled viser text field (its input is not tied to its label)."""
  return page.locator(f"xpath=//label[text()='{label}']/ancestor::div[contains(@class, 'mantine-Flex-root')][1]"
                      "//input")


def _choose(page, label: str, option: str) -> None:
  """Picks ``option`` in the viser dropdown ``label``."""
  page.get_by_role("combobox", name=label).click()
  page.get_by_role("option", name=option, exact=True).click()


def _type_number(page, label: str, text: str) -> None:
  """Types into a viser number input key by key, as a person would, and leaves it.

  A programmatic ``fill`` of a controlled number input can be lost when the
  page re-renders it; keystrokes and a blur reach the server's value.
  """
  field = page.get_by_label(label)
  field.click()
  field.press("Control+A")
  field.press_sequentially(text)
  field.press("Tab")
  assert field.input_value() == text, field.input_value()
  time.sleep(1.0)  # (the value reaches the server before the next click)


def _fill(page, label: str, text: str) -> None:
  _field(page, label).fill(text)
  time.sleep(0.5)  # (the value reaches the server before the next click)


def test_page_geometry_orientation_several_bodies_side_by_side_add_remove(browser, tmp_path):
  from playwright.sync_api import sync_playwright
  config, later = _tiny_with_block(tmp_path)
  bank_dir = tmp_path / "bank"
  mwbx.sample(mwbx.load_config(config), n_worlds=6, key=jax.random.key(0)).save(bank_dir)
  shutil.copy(later, bank_dir / "tiny_block.yaml")  # scene files stay under the page's directory
  shutil.copy(tmp_path / "tiny_block.xml", bank_dir / "tiny_block.xml")
  shutil.copy(tmp_path / "tiny.xml", bank_dir / "tiny.xml")
  bank = mwbx.Bank.load(bank_dir)
  server = Server(bank_dir, tmp_path)
  try:
    with sync_playwright() as pw:
      chromium = pw.chromium.launch(executable_path=CHROMIUM_BINARY, args=list(WEBGL_ARGS))
      page = chromium.new_page(viewport={"width": 1200, "height": 800})
      page.goto(server.url, timeout=WAIT * 1000)
      page.get_by_text("Draw include box").wait_for(timeout=WAIT * 1000)
      # Several bodies at once, and whole geometry: the page's count is
      # mwbx.queries' for the same box, bodies and shape.
      page.get_by_text("Several bodies").click()
      _tick(page.get_by_label("cube", exact=True))
      _tick(page.get_by_label("ball", exact=True))
      _tick(page.get_by_label("Whole geometry"))
      time.sleep(0.5)
      _arm(page, "include")
      _drag(page, 420, 300, 700, 520)
      line = server.expect(QUERY_LINE.pattern + r" shape=(\w+)")
      assert line.group(16) == "geometry" and json.loads(line.group(4).replace("'", '"')) == ["cube", "ball"]
      box = mq.Query.screen(_camera(line), json.loads(line.group(3)), bodies=["cube", "ball"], shape="geometry")
      want = int((np.asarray(mq.evaluate(bank, [box])) & bank.valid).sum())
      assert int(line.group(13)) == want
      page.get_by_text(re.compile(rf"^{want} of 6 worlds")).wait_for(timeout=WAIT * 1000)
      # the query stack and the status line both name it
      page.get_by_text("q0 include cube,ball (geometry)", exact=False).first.wait_for(timeout=WAIT * 1000)
      # Upright at the end, within 30 degrees, for the same bodies.
      page.get_by_label("Within (deg)").fill("30")
      time.sleep(0.5)
      page.get_by_text("Upright at the end").click()
      line = server.expect(ORIENTATION_LINE.pattern)
      upright = mq.OrientationQuery(bodies=("cube", "ball"), axis="z", within_deg=30)
      assert float(line.group(3)) == 30.0
      assert int(line.group(7)) == int((np.asarray(mq.evaluate(bank, [upright])) & bank.valid).sum())
      assert int(line.group(8)) == int((np.asarray(mq.evaluate(bank, [box, upright])) & bank.valid).sum())
      # The sorter by orientation error lists what the session lists.
      _choose(page, "Metric", ORIENTATION_ERROR)
      page.get_by_text(re.compile(r"error of the orientation query:sum over the bodies of q1")).wait_for(timeout=WAIT * 1000)
      session = Session(bank)
      session.add(box)
      session.add(upright)
      rows = session.sorted_rows(ORIENTATION_ERROR, "sum")
      first = page.get_by_text(re.compile(r"^world \d+ · ")).first
      assert first.inner_text().startswith(f"world {rows[0].world} · {rows[0].satisfied} · {rows[0].value:.4g}")
      # Side by side: three worlds, each labelled, one shared time.
      ids = [int(w) for w in bank.world_ids[:3]]
      _fill(page, "Worlds to compare", ", ".join(map(str, ids)))
      page.get_by_text("Show side by side").click()
      server.expect("side by side: " + ", ".join(f"world {w}" for w in ids))
      page.get_by_text("playing " + ", ".join(f"world {w}" for w in ids)).wait_for(timeout=WAIT * 1000)
      # Remove the ball from a world from the page: the new worlds' lineage says so.
      world = ids[0]
      page.get_by_text(re.compile(rf"^world {world} · ")).click()
      server.expect(rf"playing world {world}$")
      _tick(page.get_by_label("Pause"))
      _type_number(page, "Samples", "2")
      _fill(page, "Remove objects", "ball")
      page.get_by_text("Refine playing world").click()
      said = server.expect(r"mwbx browse: (refining|error).*").group(0)
      assert re.search(rf"refining cube of world {world} from .* 2 samples, removing ball", said), said
      removed = server.expect(r"refined world (\d+): new worlds (\d+)\.\.(\d+)")
      child = int(removed.group(2))
      # Add the block of a later scene version: the page moves to it.
      _fill(page, "Remove objects", "")
      _fill(page, "Scene file", "tiny_block.yaml")
      _fill(page, "Add objects", "block")
      page.get_by_text("Refine playing world").click()
      added = server.expect(r"refined world (\d+): new worlds (\d+)\.\.(\d+)")
      grandchild = int(added.group(2))
      # The lineage of each, shown when it plays.
      _fill(page, "Worlds to compare", f"{child}, {grandchild}")
      page.get_by_text("Show side by side").click()
      server.expect(f"side by side: world {child}, world {grandchild}")
      page.get_by_text(re.compile(rf"world {grandchild}: cube refined from {world} at .*\+block at")).wait_for(
          timeout=WAIT * 1000)
      page.get_by_text(re.compile(rf"world {child}: cube refined from {world} at .*-ball at")).wait_for(
          state="detached", timeout=WAIT * 1000)  # (the last world played is the one whose lineage shows)
      page.get_by_text(re.compile(rf"^world {child} · ")).first.click()
      page.get_by_text(re.compile(rf"world {child}: cube refined from {world} at .*-ball at")).wait_for(
          timeout=WAIT * 1000)
      page.get_by_text(re.compile(r"absent: .*ball \d")).wait_for(timeout=WAIT * 1000)
      page.get_by_text("Save bank").click()
      server.expect(r"saved ")
      chromium.close()
  finally:
    if server.proc.poll() is None:
      server.stop()
  grown = mwbx.Bank.load(bank_dir)
  assert grown.n_worlds == 10 and "block" in grown.body_names
  assert grown.absent(child) == {"ball": pytest.approx(grown.absent(child)["ball"]), "block": (0.0, float("inf"))}
  assert grown.absent(grandchild).get("block", (0.0, 0.0))[1] < float("inf")  # absent only before its t_min


def test_replaying_uploads_no_meshes_and_side_by_side_cells(tmp_path):
  """A played world's meshes go to the page once per slot; playing other
  worlds (or the same again) sends poses only; side by side puts each slot in
  its own cell, with a copy of the static scene."""
  config, _ = _tiny_with_block(tmp_path)
  bank = mwbx.sample(mwbx.load_config(config), n_worlds=4, key=jax.random.key(0))
  page = Browser(Session(bank))
  try:
    page.play(0)
    first = page.stage.uploads
    per_set = sum(len(g) for g in page.stage.moving.values())
    assert first == 2 * per_set  # the scene as it starts (drawn while nothing plays), and one slot
    for w in (1, 2, 3, 0):
      page.play(w)
    assert page.stage.uploads == first
    page.play(1, add=True)
    page.play(2, add=True)
    assert list(page.player.played) == [0, 1, 2] and page.stage.uploads == 4 * per_set
    # The poses shown are the decoded world's at the shared frame.
    from mwbx.viewer.kinematics import body_trajectories
    pos, _ = body_trajectories(page.model, bank.qpos_frames(2).astype(np.float64), page.stage.body_ids)
    page.ui.paused.value = True
    page.player.seek(5)
    frames = page.stage.slot(page.player.played[2])
    np.testing.assert_allclose(frames[int(page.stage.body_ids[0])].position, pos[5, 0], atol=1e-6)
    page.ui.side_by_side.value = True
    page.stage.set_side_by_side(True)
    assert [page.stage._slots[k][3].text for k in range(3)] == ["world 0", "world 1", "world 2"]
    offsets = [tuple(page.stage.offset(k)) for k in range(3)]
    assert len(set(offsets)) == 3
    assert page.stage._copies and all(page.stage._copies[k].visible for k in (1, 2))
    page.stage.set_side_by_side(False)
    assert not any(f.visible for f in page.stage._copies.values())
  finally:
    page.close()


def test_session_view_orientation_sorter_and_lineage(tmp_path):
  config, _ = _tiny_with_block(tmp_path)
  bank = mwbx.sample(mwbx.load_config(config), n_worlds=8, key=jax.random.key(1))
  session = Session(bank)
  with pytest.raises(mwbx.MwbxError, match="needs an orientation query"):
    session.sorted_rows(ORIENTATION_ERROR)
  upright = mq.OrientationQuery(bodies=("cube",), axis="z", within_deg=180)
  session.add(upright)
  err = mq.orientation_error(bank, upright)
  rows = session.sorted_rows(ORIENTATION_ERROR, "max", top=8)
  want = np.asarray(bank.world_ids)[np.argsort(err, kind="stable")]
  assert [r.world for r in rows] == [int(w) for w in want if bank.valid[bank.row_of(int(w))]][:8]
  assert [r.value for r in rows] == sorted(r.value for r in rows)
  exclude = mq.Query.region([-5, -5, -5], [5, 5, 5], sign="exclude")  # every world rejected
  session.add(exclude)
  view = session.view()
  assert view.each.shape == (8, 2) and not view.match.any()
  assert (view.rejected == np.asarray(bank.valid, bool)).all()
  assert session.lineage(int(bank.world_ids[0])) == [f"world {int(bank.world_ids[0])}: sampled"]
