"""Exported viewer pages and the browse page in headless Chromium: screenshots
and colour measurements.

What the browser tests, the viewer and browse benchmarks and
``scripts/paper_scenes.py`` (the README's pictures) share. Chromium is
Debian's package (``scripts/ensure_chromium.sh`` installs it); WebGL runs on
the CPU through SwiftShader. Playwright comes with the ``dev`` extra, so it is
imported only when a page is opened.
"""

from __future__ import annotations

import io
import os
from typing import NamedTuple, Sequence

import numpy as np

CHROMIUM_BINARY = "/usr/lib/chromium/chromium"
CHROMIUM_LAUNCHER = "/usr/bin/chromium"
WEBGL_ARGS = ("--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader")
NO_WEBGL_ARGS = ("--no-sandbox", "--disable-webgl", "--disable-3d-apis")


def chromium_unavailable_reason() -> str | None:
  """None when the browser test can run, else why not."""
  if not os.path.exists(CHROMIUM_BINARY):
    return (f"{CHROMIUM_BINARY} not found (Debian package 'chromium'; "
            "scripts/ensure_chromium.sh installs it when run as root)")
  try:
    import playwright.sync_api  # noqa: F401  (lazy: the dev extra)
  except ImportError as err:
    return f"playwright is not importable: {err}"
  return None


class PageShots(NamedTuple):
  """Screenshots u8[H, W, 3] per requested time, and the animation duration
  the page reports (seconds; 0 without WebGL or animation)."""

  images: list
  duration_s: float


def screenshots(url: str, seeks_s: Sequence[float | None] = (None,), *, webgl: bool = True,
                size: tuple[int, int] = (800, 600), timeout_ms: int = 60_000) -> PageShots:
  """Screenshots of `url` once the scene has loaded, one per entry of seeks_s.

  A number pauses the animation and shows the frame at that time (seconds),
  so the picture does not depend on how fast the page rendered; None takes
  the page as it is.
  """
  from PIL import Image
  from playwright.sync_api import sync_playwright  # lazy: the dev extra

  images, duration = [], 0.0
  with sync_playwright() as pw:
    browser = pw.chromium.launch(executable_path=CHROMIUM_BINARY,
                                 args=list(WEBGL_ARGS if webgl else NO_WEBGL_ARGS))
    try:
      page = browser.new_page(viewport={"width": size[0], "height": size[1]})
      page.goto(url)
      if webgl:
        page.wait_for_function("window.mwbx_loaded === true", timeout=timeout_ms)
        duration = float(page.evaluate("viewer.animator.duration"))
      else:
        page.wait_for_timeout(1000)
      for seek in seeks_s:
        if webgl and seek is not None:
          # Actions only pose their targets once started: start, stop the clock, seek.
          page.evaluate("viewer.animator.play(); viewer.animator.pause();"
                        f"viewer.animator.seek({float(seek)});")
        if webgl:
          # Two animation frames: the render loop draws dirty scenes once per frame.
          page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        images.append(np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")))
    finally:
      browser.close()
  return PageShots(images, duration)


def screenshot(url: str, *, seek_s: float | None = None, webgl: bool = True,
               size: tuple[int, int] = (800, 600)) -> np.ndarray:
  """u8[H, W, 3]: one screenshot (see `screenshots`)."""
  return screenshots(url, (seek_s,), webgl=webgl, size=size).images[0]


def colour_fraction(image: np.ndarray, rgb: Sequence[float], tol: float) -> float:
  """Fraction of pixels within `tol` (max abs difference, 0-255 scale) of rgb (0-1)."""
  target = np.asarray(rgb, np.float64) * 255.0
  diff = np.abs(image.astype(np.float64) - target[None, None, :]).max(axis=-1)
  return float(np.mean(diff <= tol))


def hue_fraction(image: np.ndarray, rgb: Sequence[float], min_chroma: float = 60.0,
                 hue_tol_deg: float = 12.0) -> float:
  """Fraction of saturated pixels whose hue is within hue_tol_deg of rgb's hue.

  Shading of lit surfaces changes brightness, not hue, so this finds a
  coloured object however it is lit; grey/white/black pixels never count.
  """
  img = image.astype(np.float64)
  mx, mn = img.max(axis=-1), img.min(axis=-1)
  chroma = mx - mn
  hue = _hue(img)
  t = np.asarray(rgb, np.float64)[None, None, :] * 255.0
  target = _hue(t)[0, 0]
  dh = np.abs((hue - target + 180.0) % 360.0 - 180.0)
  return float(np.mean((chroma >= min_chroma) & (dh <= hue_tol_deg)))


def hue_of(rgb: Sequence[float]) -> float:
  """Hue in degrees of one colour (components 0-1)."""
  return float(_hue(np.asarray(rgb, np.float64).reshape(1, 1, 3) * 255.0)[0, 0])


def _hue(img: np.ndarray) -> np.ndarray:
  r, g, b = img[..., 0], img[..., 1], img[..., 2]
  return np.degrees(np.arctan2(np.sqrt(3.0) * (g - b), 2.0 * r - g - b)) % 360.0
