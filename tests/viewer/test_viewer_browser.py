"""The exported viewer page, rendered in a real browser (headless Chromium with
software WebGL), must show the scene: checked from the screenshot's pixels.

Negative controls run through the same check and must fail it: the same page
with WebGL disabled, and an empty meshcat page.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

import mwbx.viewer as mv
from mwbx.viewer import display
from viewer_banks import quickstart_bank
from mwbx.testing.headless import colour_fraction, hue_fraction, hue_of, screenshot, screenshots

# Thresholds as fractions of an 800 x 600 screenshot.
MIN_OBJECT_FRACTION = 0.0008  # ~380 px of one object colour
MIN_PATH_FRACTION = 0.0004  # ~190 px of exact (unlit) path colour
MIN_FRUSTUM_FRACTION = 0.02  # translucent green volume covers a large area
PATH_TOLERANCE = 40  # 0-255 scale; antialiased line pixels blend with the floor


@pytest.fixture(scope="module")
def bank():
  """A real sampled quickstart bank of 4 worlds."""
  return quickstart_bank(4)


def object_colours(bank) -> list[tuple[float, float, float]]:
  """MJCF colours of moving, saturated geoms whose hue is far from the sky
  background (blue) and from the path colour (green)."""
  model = bank.model
  out = []
  for v in mv.geometry.scene_visuals(model):
    rgb = np.asarray(v.rgba[:3])
    if v.static or rgb.max() - rgb.min() < 0.4:
      continue
    hue = hue_of(rgb)
    if hue < 70 or hue > 300:  # reds, oranges, yellows, magentas
      out.append(tuple(rgb))
  assert out, "the scene needs a red/orange/yellow object for this test"
  return out


def scene_drawn(image: np.ndarray, colours, path_rgb) -> tuple[bool, dict]:
  """The check: some object colour and the path colour cover enough pixels."""
  objects = max(hue_fraction(image, c) for c in colours)
  path = colour_fraction(image, path_rgb, PATH_TOLERANCE)
  ok = objects >= MIN_OBJECT_FRACTION and path >= MIN_PATH_FRACTION
  return ok, {"objects": objects, "path": path}


@pytest.fixture(scope="module")
def page(bank, browser, tmp_path_factory):
  """One played-back world with every world's paths drawn green."""
  out = tmp_path_factory.mktemp("viewer") / "world.html"
  match = np.asarray(bank.valid, bool)
  mv.export_html(bank, out, worlds=[int(np.flatnonzero(match)[0])], paths=True, match=match)
  return out


def test_exported_page_shows_geometry_paths_and_motion(bank, page):
  shots = screenshots(page.as_uri(), (0.0, 0.5, 3.0))
  save = pathlib.Path("out/viewer")
  save.mkdir(parents=True, exist_ok=True)
  from PIL import Image

  Image.fromarray(shots.images[1]).save(save / "browser_test.png")
  for image in shots.images:
    ok, fractions = scene_drawn(image, object_colours(bank), display.PATH_RGBA["match"][:3])
    assert ok, f"scene not visible in the screenshot: {fractions}"
  # Played back at the recorded rate: the clip lasts as long as the recording.
  world = int(np.flatnonzero(np.asarray(bank.valid))[0])
  assert shots.duration_s == pytest.approx((bank.frame_count[world] - 1) / bank.record_fps, abs=1e-3)
  # The bodies move: pictures at different times differ, beyond rendering noise.
  changed = lambda a, b: float(np.mean(np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > 30))  # noqa: E731
  assert changed(shots.images[0], shots.images[2]) > 0.002
  assert changed(shots.images[0], screenshots(page.as_uri(), (0.0,)).images[0]) < 0.0005


def test_check_fails_without_webgl_and_on_an_empty_page(bank, page, tmp_path):
  colours = object_colours(bank)
  no_webgl = screenshot(page.as_uri(), webgl=False)
  ok, fractions = scene_drawn(no_webgl, colours, display.PATH_RGBA["match"][:3])
  assert not ok, f"WebGL disabled yet the check passed: {fractions}"
  empty = tmp_path / "empty.html"
  empty.write_text(mv.SceneRecorder().get_scene())
  ok, fractions = scene_drawn(screenshot(empty.as_uri()), colours, display.PATH_RGBA["match"][:3])
  assert not ok, f"an empty meshcat page passed the check: {fractions}"


def test_grid_page_shows_query_frustum(bank, browser, tmp_path):
  """Grid layout of all valid worlds with one include frustum in front of
  the scene: the translucent green volume must be visible."""
  worlds = np.flatnonzero(np.asarray(bank.valid))[:4]
  com = np.asarray(bank.com)[worlds].reshape(-1, 3)
  lo, hi = np.nanmin(com, axis=0), np.nanmax(com, axis=0)
  mid = (lo + hi) / 2
  half = np.maximum((hi - lo) / 2, 0.1)
  near = [mid + [sx * half[0], -half[1], sz * half[2]] for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
  far = [mid + [1.5 * sx * half[0], half[1], 1.5 * sz * half[2]] for sx, sz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
  out = mv.export_html(bank, tmp_path / "grid.html", worlds=worlds.tolist(), layout="grid",
                       queries=[(np.asarray(near + far), True)])
  image = screenshot(out.as_uri(), seek_s=0.0)
  frustum = hue_fraction(image, mv.frustums.INCLUDE[:3], min_chroma=40, hue_tol_deg=25)
  # The frustum sits in front of every tile's scene: the objects are checked on the same page without it.
  plain = mv.export_html(bank, tmp_path / "plain.html", worlds=worlds.tolist(), layout="grid")
  objects = max(hue_fraction(screenshot(plain.as_uri(), seek_s=0.0), c) for c in object_colours(bank))
  assert frustum >= MIN_FRUSTUM_FRACTION and objects >= MIN_OBJECT_FRACTION / 4, (frustum, objects)


@pytest.mark.parametrize("camera", [None, "front"])
def test_query_camera_marker_never_covers_the_view(bank, browser, tmp_path, camera):
  """Screen queries drawn with their camera: seen from that same camera
  (``--camera front``) or from the fitted default view, the camera's eye
  marker stays a dot and the scene is visible (it used to fill the screen)."""
  from mwbx import queries as mq
  cam = mq.Camera.from_model(bank.model, "front")
  qs = [mq.Query.screen(cam, [0.3, 0.5, 0.42, 0.6], near=2, far=5, bodies="ball"),
        mq.Query.screen(cam, [0.1, 0.45, 0.2, 0.55], near=2, far=5, bodies="ball", sign="exclude")]
  world = int(bank.world_ids[np.flatnonzero(np.asarray(bank.valid))[0]])
  out = mv.export_html(bank, tmp_path / "q.html", worlds=[world], paths=True, queries=qs, camera=camera)
  image = screenshot(out.as_uri(), seek_s=0.5)
  marker = colour_fraction(image, mv.frustums.CAMERA_RGBA[:3], 12)
  objects = max(hue_fraction(image, c) for c in object_colours(bank))
  assert marker < 0.01 and objects >= MIN_OBJECT_FRACTION, (marker, objects)
