"""Contact events found frame to frame from what moved equal those found by
testing every pair at every frame: a scene of many actors (36 boxes dropped
in a heap, so most rest while a few still slide) sampled, and its stored
frames scanned both ways."""

from __future__ import annotations

import textwrap

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.events import detect
from mwbx.events.actors import actors_of, qpos_actors


def heap_mjcf(n: int = 36) -> str:
  bodies = "".join(
      f'<body name="box{i}" pos="{0.09 * (i % 6) - 0.22:.3f} {0.09 * (i // 6 % 3) - 0.09:.3f} '
      f'{0.05 + 0.09 * (i // 18):.3f}"><freejoint/><geom type="box" size="0.04 0.04 0.04" mass="0.1"/></body>'
      for i in range(n))
  return (f'<mujoco><option timestep="0.0020833333333333333"/><worldbody>'
          f'<geom name="floor" type="plane" size="3 3 0.1"/><geom name="wall" type="box" pos="0.35 0 0.1" '
          f'size="0.02 0.5 0.1"/>{bodies}</worldbody></mujoco>')


@pytest.fixture(scope="module")
def heap_bank(tmp_path_factory):
  folder = tmp_path_factory.mktemp("heap")
  (folder / "heap.xml").write_text(heap_mjcf())
  config = folder / "heap.yaml"
  config.write_text(textwrap.dedent("""\
      scene: {mjcf: heap.xml}
      randomize:
        box0: {linear_velocity: {dist: uniform, mean: [1.5, 0, 0], scale: [0.5, 0.3, 0]}}
      sim: {end_time: 1.0, sleep: off}
      """))
  return mwbx.sample(mwbx.load_config(config), n_worlds=4, key=jax.random.key(0), backend="native")


def test_frame_to_frame_events_equal_every_pair_at_every_frame(heap_bank, monkeypatch):
  model = heap_bank.model
  actors = actors_of(model, list(heap_bank.objects))
  assert len(actors.names) >= detect.INCREMENTAL_MIN_ACTORS  # the frame-to-frame path runs
  assert qpos_actors(model, actors) is not None
  frames = heap_bank.qpos_store.frames_of_rows(None)
  margin = detect.touch_margin(heap_bank.config["codec"]["e_pos"])
  incremental = detect.detect_events(model, actors, frames, margin)
  monkeypatch.setattr(detect, "qpos_actors", lambda *_: None)
  every_pair = detect.detect_events(model, actors, frames, margin)
  total = 0
  for w in range(heap_bank.n_worlds):
    np.testing.assert_array_equal(incremental.world(w), every_pair.world(w))
    total += len(every_pair.world(w))
  assert total > 4 * 36  # boxes on the floor and on each other: many episodes, all found alike


def test_a_frame_where_nothing_moves_keeps_the_frame_before(heap_bank):
  """Frames repeated (a world at rest held) change nothing; a moved actor's
  contacts are found again where it now is."""
  model = detect.margin_model(heap_bank.model, 0.002)
  actors = actors_of(model, list(heap_bank.objects))
  qpos_actor = qpos_actors(model, actors)
  frames = heap_bank.qpos_store.frames_of_rows([0])[0]
  held = np.concatenate([frames, np.repeat(frames[-1:], 5, axis=0), frames[:3]])
  data = mujoco.MjData(model)
  fast = detect.world_episodes(model, data, actors, held, 0.002, qpos_actor)
  full = detect.world_episodes(model, data, actors, held, 0.002)
  np.testing.assert_array_equal(fast, full)
