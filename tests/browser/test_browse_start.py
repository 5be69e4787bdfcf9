"""The page opens on the scene as it starts (every moving body where the
first valid world starts, dimmed, until a world plays) and, in a scene of
many bodies, on the paths of the bodies that move most in every world."""

from __future__ import annotations

import types

import numpy as np

from mwbx.browser import Browser, Session
from mwbx.browser import drawing
from mwbx.viewer.kinematics import body_trajectories

from viewer_banks import quickstart_bank


def test_the_page_opens_on_the_scene_as_it_starts():
  bank = quickstart_bank()
  page = Browser(Session(bank))
  try:
    start = page.stage._start
    assert start is not None and start[0].visible  # drawn before anything plays
    first = int(bank.world_ids[np.flatnonzero(np.asarray(bank.valid, bool))[0]])
    pos, quat = body_trajectories(page.model, bank.qpos_frames(first)[:1].astype(np.float64), page.stage.pose_ids)
    for i, b in enumerate(page.stage.body_ids):
      np.testing.assert_allclose(start[1][int(b)].position, pos[0, i], atol=1e-6)
      np.testing.assert_allclose(start[1][int(b)].wxyz, quat[0, i], atol=1e-6)
    assert all(mesh.opacity is not None and mesh.opacity < 1 for mesh in start[2])
    page.play(first)
    assert not start[0].visible  # a playing world replaces it
  finally:
    page.close()


def test_many_bodies_draw_the_paths_of_those_that_move_most():
  w, b, t = 10, 50, 21
  lengths = np.zeros((w, b, 1), np.float32)
  lengths[:, 7] = 5.0  # the "rock"
  lengths[:, 30] = 2.0
  lengths[:, 12] = 1.0
  bank = types.SimpleNamespace(valid=np.ones(w, bool), com_count=np.full(w, t), metrics=lengths,
                               metric_names=("path_length",))
  bodies = np.arange(b)
  assert list(drawing.most_moving(bank, bodies, budget=w * (t - 1) * 2)) == [7, 30]
  assert list(drawing.most_moving(bank, bodies, budget=1)) == [7]  # at least the one that moves most
  assert len(drawing.most_moving(bank, bodies, budget=w * (t - 1) * b)) == b  # all fit: all drawn
