"""The page's threads (viser's GUI callbacks, the playback thread, a
refinement's watcher) share the played worlds, the frame and the drawn
handles under one lock."""

from __future__ import annotations

import threading
import time

from mwbx.browser import Browser, Session

from viewer_banks import quickstart_bank


def test_gui_callbacks_and_playback_hold_one_lock():
  bank = quickstart_bank()
  page = Browser(Session(bank))
  try:
    assert page.player.lock is page.lock
    world = int(bank.world_ids[0])
    done: list[str] = []
    threads = [threading.Thread(target=lambda: (page.refresh(), done.append("refresh"))),
               threading.Thread(target=lambda: (page.play(world), done.append("play"))),
               threading.Thread(target=lambda: (page.sorter(), done.append("sorter")))]
    with page.lock:  # as the playback thread holds it while it poses the played worlds
      for t in threads:
        t.start()
      time.sleep(1.0)
      assert done == [] and page.playing_world is None and not page.player.played
    for t in threads:
      t.join(timeout=300)
    assert sorted(done) == ["play", "refresh", "sorter"] and page.playing_world == world

    # Many callbacks at once while a world plays: no error, and what is
    # drawn stays one node per path class and query (nothing orphaned).
    errors: list[BaseException] = []

    def hammer(k: int) -> None:
      try:
        for i in range(4):
          if k % 2:
            page.play(int(bank.world_ids[(i + k) % bank.n_worlds]), add=bool(i % 2))
          else:
            page.refresh()
      except BaseException as err:  # noqa: BLE001 (reported below)
        errors.append(err)

    workers = [threading.Thread(target=hammer, args=(k,)) for k in range(4)]
    for t in workers:
      t.start()
    for t in workers:
      t.join(timeout=300)
    assert not errors, errors
    assert set(page._handles) <= {"paths/faint", "paths/match", "paths/exclude"}
    assert set(page.path_segments) <= {"faint", "match", "exclude"} and all(page.path_segments.values())
    assert len(page.player.played) >= 1 and page.playing_world in page.player.played
  finally:
    page.close()


def test_page_lighting_is_plain(monkeypatch):
  """No environment map and no shadows: in software WebGL they cost seconds a
  frame, and a sorter click's answer waited for the frame (scripts/bench_browse.py)."""
  import viser

  calls, meshes = [], []
  for name in ("configure_environment_map", "configure_default_lights"):
    real = getattr(viser.SceneApi, name)
    monkeypatch.setattr(viser.SceneApi, name, lambda self, *a, _n=name, _f=real, **k: (
        calls.append((_n, a, k)), _f(self, *a, **k))[1])
  real_mesh = viser.SceneApi.add_mesh_simple
  monkeypatch.setattr(viser.SceneApi, "add_mesh_simple", lambda self, *a, **k: (
      meshes.append((k.get("cast_shadow", True), k.get("receive_shadow", True))), real_mesh(self, *a, **k))[1])
  bank = quickstart_bank()
  page = Browser(Session(bank))
  try:
    page.play(int(bank.world_ids[0]))
    assert ("configure_environment_map", (None,), {}) in calls
    assert any(n == "configure_default_lights" and (a[1:] == (False,) or k.get("cast_shadow") is False)
               for n, a, k in calls)
    assert meshes and all(m == (False, False) for m in meshes)  # the scene and the played world's bodies
  finally:
    page.close()
