"""Who may use the browsing page and what it may touch: the URL's token
(HTTP 403 and a refused websocket without it), foreign Origins refused, the
port printed being the one bound, hosts checked, query files kept under the
session's directory and written only into folders that exist there (never
the bank's own), errors naming files but never showing what they hold, every
page handler answering bad values in one status line, refinement limits held
by the server, unsaved refinements named or saved on exit, and meshcat's
server on loopback."""

from __future__ import annotations

import math
import os
import pathlib
import socket
import time
import types
import urllib.error
import urllib.request

import jax
import numpy as np
import pytest

import mwbx
from mwbx.browser import Session, browse
from mwbx.browser import session as session_lib
from mwbx.browser.session import MAX_REFINE_SAMPLES

from viewer_banks import quickstart_bank

TIMEOUT = 300  # seconds: a loaded machine is slow, never wrong


@pytest.fixture(scope="module")
def bank_dir(tmp_path_factory):
  out = tmp_path_factory.mktemp("page") / "bank"
  quickstart_bank(4).save(out)
  return out


@pytest.fixture(scope="module")
def page(bank_dir):
  page = browse(mwbx.Bank.load(bank_dir), path=bank_dir, block=False)
  yield page
  page.close()


def _get(url: str, headers: dict | None = None):
  """(status, Set-Cookie header) of a GET."""
  try:
    with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=TIMEOUT) as r:
      return r.status, r.headers.get("Set-Cookie")
  except urllib.error.HTTPError as err:
    return err.code, err.headers.get("Set-Cookie")


def _websocket(port: int, headers: dict):
  """The status the websocket handshake got (101: open, and a first message came)."""
  import viser
  from websockets.exceptions import InvalidStatus
  from websockets.sync.client import connect
  try:
    with connect(f"ws://127.0.0.1:{port}/", subprotocols=[f"viser-v{viser.__version__}"],
                 additional_headers=headers, open_timeout=TIMEOUT) as ws:
      assert ws.recv(timeout=TIMEOUT)
      return 101
  except InvalidStatus as err:
    return err.response.status_code


def test_page_and_websocket_need_the_token_and_refuse_foreign_origins(page):
  base = f"http://127.0.0.1:{page.port}/"
  token = page.guard.token
  assert page.url == f"{base}?token={token}" and len(token) >= 40
  assert _get(base)[0] == 403
  assert _get(f"{base}?token={token[:-1]}x")[0] == 403
  assert _get(f"{base}?token={token}", {"Origin": "http://evil.example"})[0] == 403
  status, cookie = _get(page.url)
  assert status == 200 and cookie.startswith(f"{page.guard.cookie}={token};") and "HttpOnly" in cookie
  assert _get(base, {"Cookie": cookie.split(";")[0]})[0] == 200  # the page's other requests carry the cookie
  own = {"Cookie": cookie.split(";")[0]}
  assert _websocket(page.port, {}) == 403
  assert _websocket(page.port, {"Cookie": f"{page.guard.cookie}=guess"}) == 403
  assert _websocket(page.port, {**own, "Origin": "http://evil.example"}) == 403
  assert _websocket(page.port, {**own, "Origin": "null"}) == 403
  assert _websocket(page.port, {**own, "Origin": f"http://127.0.0.1:{page.port}"}) == 101
  assert _websocket(page.port, own) == 101


def test_the_printed_port_is_the_bound_one_when_the_asked_one_is_busy(bank_dir, capsys):
  with socket.socket() as busy:
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    asked = busy.getsockname()[1]
    page = browse(mwbx.Bank.load(bank_dir), path=bank_dir, port=asked, block=False)
    try:
      err = capsys.readouterr().err
      assert page.port != asked and page.requested_port == asked
      assert f"port {asked} is busy; serving on port {page.port}" in err
      assert f"at http://127.0.0.1:{page.port}/?token=" in err
      assert _get(page.url)[1] is not None  # this page answered (with its cookie), not the other listener
    finally:
      page.close()


def test_hosts_unresolvable_is_one_line_and_not_loopback_is_warned(bank_dir, capsys):
  from mwbx import cli
  assert cli.main(["browse", str(bank_dir), "--host", "no-such-host.invalid", "--no-browser"]) == 2
  err = capsys.readouterr().err
  assert "--host 'no-such-host.invalid': no such address" in err and err.count("\n") == 1
  with pytest.raises(mwbx.MwbxError) as raised:  # from Python: the parameter, not the flag
    browse(mwbx.Bank.load(bank_dir), path=bank_dir, host="no-such-host.invalid", block=False)
  assert str(raised.value).startswith("browse: host 'no-such-host.invalid': no such address")
  assert "--" not in str(raised.value)
  page = browse(mwbx.Bank.load(bank_dir), path=bank_dir, host="0.0.0.0", block=False)
  try:
    err = capsys.readouterr().err
    assert "warning: --host 0.0.0.0 is not a loopback address" in err
    assert _get(f"http://127.0.0.1:{page.port}/")[0] == 403  # still behind the token
  finally:
    page.close()
  page = browse(mwbx.Bank.load(bank_dir), path=bank_dir, host="localhost", block=False)
  page.close()
  assert "warning" not in capsys.readouterr().err


def test_query_files_stay_under_the_directory(bank_dir, tmp_path):
  bank = mwbx.Bank.load(bank_dir)
  work = tmp_path / "work"
  work.mkdir()
  session = Session(bank, bank_dir, work)
  session.add(mwbx.Query.region([0, 0, 0], [1, 1, 1]))
  (work / "sub").mkdir()  # a folder someone made there: written into
  saved = pathlib.Path(session.save_queries("sub/q.yaml"))
  assert saved == work / "sub" / "q.yaml" and saved.is_file()
  session.open_queries("sub/q.yaml")
  with pytest.raises(mwbx.MwbxError, match="no folder new under"):
    session.save_queries("new/q.yaml")  # none is made
  assert not (work / "new").exists()
  (tmp_path / "outside").mkdir()
  (work / "escape").symlink_to(tmp_path / "outside")
  for name in ("../escaped/dir/pwned.yaml", str(tmp_path / "abs" / "pwned.yaml"), "escape/pwned.yaml",
               "/etc/passwd.yaml"):
    with pytest.raises(mwbx.MwbxError, match="outside .*query files stay under that directory"):
      session.save_queries(name)
    with pytest.raises(mwbx.MwbxError, match="outside"):
      session.open_queries(name)
  assert not (tmp_path / "escaped").exists() and not (tmp_path / "abs").exists()
  assert not list((tmp_path / "outside").iterdir())
  # Not a query file: no bank file (manifest.json) overwritten, no name without .yaml.
  for name in ("manifest.json", "q", "."):
    with pytest.raises(mwbx.MwbxError):
      session.save_queries(name)
  # A file holding a secret: the error names the file, never what it holds.
  (work / "auth.yaml").write_text('{"auths": {"registry.example": {"auth": "c2VjcmV0LXRva2VuLTEyMzQ1"}}}\n')
  (work / "bad.yaml").write_text("queries: [c2VjcmV0LXRva2VuLTEyMzQ1\n")
  for name in ("auth.yaml", "bad.yaml"):
    with pytest.raises(mwbx.MwbxError) as err:
      session.open_queries(name)
    assert name in str(err.value) and "c2VjcmV0" not in str(err.value) and "registry" not in str(err.value)
  # The bank directory by default; no directory at all: no query files.
  assert pathlib.Path(Session(bank, bank_dir).save_queries("q.yaml")) == bank_dir / "q.yaml"
  with pytest.raises(mwbx.MwbxError, match="no directory"):
    Session(bank).save_queries("q.yaml")


def test_refinement_limits_hold_on_the_server(bank_dir, monkeypatch):
  session = Session(mwbx.Bank.load(bank_dir), bank_dir)
  world = int(session.bank.world_ids[0])
  for n in (MAX_REFINE_SAMPLES + 1, 50_000, 10**9, 0, -3, 2.5, True):
    with pytest.raises(mwbx.MwbxError, match=f"from 1 to {MAX_REFINE_SAMPLES}"):
      session.refine(world, "capsule", t_min=0.5, n_samples=n)
  assert session.job is None  # nothing started
  # One refinement at a time; the running one can be cancelled and adds nothing.
  big = session.refine(world, "capsule", t_min=0.5, n_samples=MAX_REFINE_SAMPLES)
  with pytest.raises(mwbx.MwbxError, match=f"world {world} is being refined"):
    session.refine(world, "capsule", t_min=0.5, n_samples=1)
  assert session.cancel() is big
  assert big.done.wait(TIMEOUT) and big.cancelled and big.new_ids is None and big.error is None
  assert session.bank.n_worlds == 4 and session.unsaved == [] and session.cancel() is None
  small = session.refine(world, "capsule", t_min=0.5, n_samples=2, key=jax.random.key(0), wait=True)
  assert small.error is None and small.new_ids.tolist() == [4, 5] and session.unsaved == [4, 5]
  # A job that fails in any way says why (it used to die silently in its thread).
  def out_of_memory(*args, **kwargs):
    raise MemoryError
  monkeypatch.setattr(session_lib, "run_refinement", out_of_memory)
  failed = session.refine(world, "capsule", t_min=0.5, n_samples=3, wait=True)
  assert failed.error.startswith("MemoryError") and failed.new_ids is None
  assert session.refine(world, "capsule", t_min=0.5, n_samples=3, wait=True).done.is_set()  # not stuck


def test_unsaved_refinements_are_named_or_autosaved_on_exit(bank_dir, tmp_path):
  import shutil
  for autosave in (False, True):
    copy = tmp_path / f"bank{autosave}"
    shutil.copytree(bank_dir, copy)
    page = browse(mwbx.Bank.load(copy), path=copy, block=False)
    try:
      job = page.session.refine(0, "capsule", t_min=0.5, n_samples=2, key=jax.random.key(1), wait=True)
      assert job.error is None
      lines = page.leave(autosave)
    finally:
      page.close()
    assert len(lines) == 1
    if autosave:
      assert lines[0].startswith("saved 2 refined worlds (ids 4..5) to")
      assert mwbx.Bank.load(copy).n_worlds == 6
    else:
      assert lines[0].startswith("2 refined worlds (ids 4..5) were not saved")
      assert mwbx.Bank.load(copy).n_worlds == 4


def test_a_save_that_renumbers_plays_on_under_the_ids_on_disk(bank_dir, tmp_path):
  # The page kept playing, and named, the ids its worlds had before the save.
  import shutil
  copy = tmp_path / "bank"
  shutil.copytree(bank_dir, copy)
  page = browse(mwbx.Bank.load(copy), path=copy, block=False)
  try:
    job = page.session.refine(0, "capsule", t_min=0.5, n_samples=2, key=jax.random.key(1), wait=True)
    assert job.error is None and job.new_ids.tolist() == [4, 5]
    page.play(5)
    page.play(4, add=True)
    decoded = page.player.poses(5)
    other = mwbx.Bank.load(copy)
    other.append(other._take(np.array([0, 1]))).save(copy)  # another writer takes ids 4 and 5 meanwhile
    said = page.save()
    assert said.startswith("saved 2 refined worlds (ids 6..7) to"), said
    assert page.playing_world == 6 and page.player.played == {7: 0, 6: 1}
    assert page.player.poses(7) is decoded  # the same world, under its id on disk
    np.testing.assert_array_equal(mwbx.Bank.load(copy).qpos_frames(7), page.session.bank.qpos_frames(7))
    assert page.session.bank.parent_world[page.session.bank.row_of(7)] == 0
  finally:
    page.close()


def _listening(pid: int) -> list[tuple[str, int]]:
  """(address, port) of the TCP sockets process ``pid`` listens on, from /proc."""
  inodes = set()
  for fd in os.listdir(f"/proc/{pid}/fd"):
    try:
      target = os.readlink(f"/proc/{pid}/fd/{fd}")
    except OSError:
      continue
    if target.startswith("socket:["):
      inodes.add(target[8:-1])
  out = []
  for table, width in (("tcp", 8), ("tcp6", 32)):
    for line in open(f"/proc/{pid}/net/{table}").read().splitlines()[1:]:
      fields = line.split()
      if fields[3] == "0A" and fields[9] in inodes:  # LISTEN
        addr, port = fields[1].split(":")
        raw = bytes.fromhex(addr)
        # /proc prints each 32-bit word in host (little-endian) order.
        raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
        out.append((socket.inet_ntop(socket.AF_INET if width == 8 else socket.AF_INET6, raw), int(port, 16)))
  return out


def test_meshcat_server_listens_on_loopback_only():
  from mwbx.viewer.server import _stop, start_server
  proc, zmq_url, web_url = start_server()
  try:
    listening = _listening(proc.pid)
    web_port = int(web_url.split(":")[2].split("/")[0])
    assert web_url.startswith("http://127.0.0.1:") and ("127.0.0.1", web_port) in listening
    assert all(addr == "127.0.0.1" for addr, _ in listening), listening
    assert len(listening) == 2  # the web page and the ZMQ socket
  finally:
    _stop(proc)
  assert proc.poll() is not None


# --- the page's handlers, driven as a client's clicks drive them -------------------------

SECRET = "sk-live-0a1b2c3d4e5f"


def _click(page, label: str) -> str:
  """Clicks the page's button ``label`` (its callbacks run at once, as for a
  client's click); returns the status line it left."""
  page.ui.status_md.content = "(stale)"
  page.ui.buttons[label].value = True
  return page.ui.status_md.content


def _refused(status: str, *needles: str) -> None:
  assert status.startswith("error: ") and "\n" not in status and len(status) < 500, status
  for needle in needles:
    assert needle in status, status


def _first_world(page) -> int:
  world = int(page.session.bank.world_ids[0])
  page.play(world)
  return world


def test_the_page_shows_file_names_never_their_content(page, bank_dir):
  # A file of secrets as Scene file: the status line, sent to every client,
  # printed `scene: Field required (got {'api_key': ...})`.
  (bank_dir / "secret.yaml").write_text(f"api_key: {SECRET}\ndb: {{user: admin, password: {SECRET}}}\n")
  _first_world(page)
  page.ui.scene_file.value = "secret.yaml"
  try:
    # The job starts; the watcher reports its error, which on a fast machine
    # may already be in the status line when the click returns.
    first = _click(page, "Refine playing world")
    assert first == "(stale)" or first.startswith("error: "), first
    assert page.session.job.done.wait(TIMEOUT)
    deadline = time.monotonic() + TIMEOUT
    while page.ui.status_md.content == "(stale)" and time.monotonic() < deadline:
      time.sleep(0.05)
    _refused(page.ui.status_md.content, "secret.yaml", "scene")
    assert SECRET not in page.ui.status_md.content and SECRET not in page.session.job.error
  finally:
    page.ui.scene_file.value = ""
    (bank_dir / "secret.yaml").unlink()


def test_every_file_field_refuses_a_nul_byte_in_one_line(page):
  # A NUL raised ValueError in the handler and left the status line stale.
  _first_world(page)
  job = page.session.job
  for field, name, button in (("query_file", "q\x00.yaml", "Save queries"),
                              ("query_file", "q\x00.yaml", "Open queries"),
                              ("export_file", "w\x00.npz", "Export playing world"),
                              ("scene_file", "s\x00.yaml", "Refine playing world")):
    widget = getattr(page.ui, field)
    before = widget.value
    widget.value = name
    try:
      _refused(_click(page, button), field.replace("_", " "), "control character")
    finally:
      widget.value = before
  assert page.session.job is job  # no refinement started


def test_a_dragged_box_of_bad_corners_is_refused_in_one_line(page, monkeypatch):
  # A NaN or huge box failed outside _add_box's try: the page said nothing.
  armed = []
  monkeypatch.setattr(page.server.scene, "on_rect_select", lambda **_: lambda f: armed.append(f) or f)
  monkeypatch.setattr(page.server.scene, "remove_rect_select_callback", lambda f: None)
  camera = types.SimpleNamespace(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 3.0), fov=0.8, aspect=1.5)
  bad_camera = types.SimpleNamespace(wxyz=(1.0, 0.0, 0.0, 0.0), position=(math.nan, 0.0, 3.0), fov=0.8, aspect=1.5)
  queries = len(page.session.entries)
  for cam, a, b, needle in ((camera, (math.nan, 0.2), (0.5, 0.6), "box"),
                            (camera, (0.1, 0.2), (1e300, 0.6), "box"),
                            (camera, (0.1,), (0.5, 0.6), "include box"),
                            (bad_camera, (0.1, 0.2), (0.5, 0.6), "camera")):
    _click(page, "Draw include box")
    page.ui.status_md.content = "(stale)"
    armed.pop()(types.SimpleNamespace(client=types.SimpleNamespace(camera=cam), screen_min=a, screen_max=b))
    _refused(page.ui.status_md.content, needle)
  assert len(page.session.entries) == queries


def test_every_handler_answers_bad_values_in_the_status_line(page):
  # Values a client can send that no widget offers: each is one error line.
  queries = len(page.session.entries)
  window = page.ui.window.value
  page.ui.window.value = (math.nan, 1.0)
  try:
    for button in ("Upright at the end", "Near its initial orientation", "Add: they touch"):
      _refused(_click(page, button), "window")
  finally:
    page.ui.window.value = window
  page.ui.query_pick.value = "qzz"
  _refused(_click(page, "Toggle query"), "qzz")
  page.ui.query_pick.value = "(none)"
  page.ui.status_md.content = "(stale)"
  page.ui.time_slider.value = math.nan
  _refused(page.ui.status_md.content, "time")
  page.ui.time_slider.value = 0.0
  assert len(page.session.entries) == queries


def test_the_page_writes_only_into_folders_it_owns(page, bank_dir):
  # A client made any folder in the bank (`sub/deep`, `~`) and wrote into shards/.
  _first_world(page)
  shards = sorted(p.name for p in (bank_dir / "shards").iterdir())
  before = sorted(p.name for p in bank_dir.iterdir())
  for name, needle in (("sub/deep/q.yaml", "no folder sub/deep"), ("~/q.yaml", "'~'"), ("~", "'~'"),
                       ("shards/q.yaml", "shards/"), ("shards/00000/q.yaml", "shards/"),
                       (".lock.yaml", "hidden"), ("manifest.json", "must end in")):
    page.ui.query_file.value = name
    _refused(_click(page, "Save queries"), name, needle)
  for name, needle in (("shards/w.npz", "shards/"), ("exports/w.npz", "no folder exports")):
    page.ui.export_file.value = name
    _refused(_click(page, "Export playing world"), needle)
  assert sorted(p.name for p in bank_dir.iterdir()) == before
  assert sorted(p.name for p in (bank_dir / "shards").iterdir()) == shards
  (bank_dir / "saved").mkdir()  # a folder someone made: written into
  try:
    page.ui.query_file.value = "saved/q.yaml"
    assert _click(page, "Save queries") == f"saved {bank_dir / 'saved' / 'q.yaml'}"
  finally:
    page.ui.query_file.value = "queries.yaml"
    (bank_dir / "saved" / "q.yaml").unlink(missing_ok=True)
    (bank_dir / "saved").rmdir()
