"""Viewer benchmark: building animations and many-path scenes, and rendering
them in headless Chromium.

Each measurement prints the mwbx way against a named baseline measured in
the same run:
  animation  tracks filled directly (mwbx.viewer.playback.add_clip)
             vs meshcat's per-frame `anim.at_frame(vis, t)[path].set_transform`
  paths      one LineSegments buffer per colour class (mwbx.viewer.paths)
             vs one meshcat Line object per polyline
  browser    (--browser) ms per rendered frame and draw calls of both path
             scenes in headless Chromium (SwiftShader WebGL)
  export     end-to-end export_html of a bank (quickstart when the foundation
             is installed, else the test stand-in)

Writes out/bench/viewer.json. Usage:
  .venv/bin/python scripts/bench_viewer.py [--paths 2000] [--browser] [--screenshot docs/viewer_screenshot.png]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import sys
import tempfile
import time
import warnings

import numpy as np

with warnings.catch_warnings():
  warnings.simplefilter("ignore", DeprecationWarning)
  import meshcat
  import meshcat.animation as manim
  import meshcat.geometry as mg

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mwbx.viewer as mv  # noqa: E402
from mwbx.viewer import display, geometry, paths, playback  # noqa: E402


def best_of_interleaved(ours, baseline, repeats: int = 3) -> tuple[float, float]:
  """Best wall time of each over `repeats` alternating runs, so load from
  other processes on a shared machine hits both alike."""
  times = {ours: [], baseline: []}
  for _ in range(repeats):
    for fn in (ours, baseline):
      t0 = time.perf_counter()
      fn()
      times[fn].append(time.perf_counter() - t0)
  return min(times[ours]), min(times[baseline])


def random_poses(n_frames: int, n_bodies: int, seed: int = 0):
  rng = np.random.default_rng(seed)
  pos = np.cumsum(rng.normal(0, 0.01, (n_frames, n_bodies, 3)), axis=0)
  quat = rng.normal(size=(n_frames, n_bodies, 4))
  quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
  return pos, quat


def bench_animation(n_worlds: int, n_bodies: int, n_frames: int, fps: float) -> dict:
  pos, quat = random_poses(n_frames, n_worlds * n_bodies)

  def ours():
    vis = meshcat.Visualizer(window=mv.SceneRecorder())
    anim = manim.Animation(default_framerate=fps)
    for k in range(pos.shape[1]):
      playback.add_clip(anim, vis[f"b{k}"], pos[:, k], quat[:, k], fps)
    vis.set_animation(anim)

  def baseline():
    vis = meshcat.Visualizer(window=mv.SceneRecorder())
    anim = manim.Animation(default_framerate=fps)
    mats = np.zeros((n_frames, pos.shape[1], 4, 4))
    for t in range(n_frames):
      for k in range(pos.shape[1]):
        mats[t, k] = geometry.pose_matrix(pos[t, k], quat[t, k])
    for t in range(n_frames):
      with anim.at_frame(vis, t) as frame:
        for k in range(pos.shape[1]):
          frame[f"b{k}"].set_transform(mats[t, k])
    vis.set_animation(anim)

  t_ours, t_base = best_of_interleaved(ours, baseline)
  return {"case": f"{n_worlds} worlds x {n_bodies} bodies x {n_frames} frames",
          "mwbx_s": t_ours, "baseline": "meshcat at_frame().set_transform per frame",
          "baseline_s": t_base, "speedup": t_base / t_ours}


def random_paths(n_worlds: int, n_bodies: int, n_points: int, seed: int = 1):
  rng = np.random.default_rng(seed)
  steps = rng.normal(0, 0.03, (n_worlds, n_points, n_bodies, 3)).astype(np.float32)
  steps[:, 0] = rng.uniform(-0.5, 0.5, (n_worlds, n_bodies, 3))
  com = np.cumsum(steps, axis=1)
  count = rng.integers(n_points // 2, n_points + 1, n_worlds).astype(np.int32)
  match = rng.random(n_worlds) < 0.1
  exclude = (rng.random(n_worlds) < 0.1) & ~match
  return com, count, match, exclude


def path_scene_ours(com, count, match, exclude):
  vis = meshcat.Visualizer(window=mv.SceneRecorder())
  classes = display.classify_worlds(np.ones(com.shape[0], bool), None, match, exclude)
  paths.draw_paths(vis["paths"], com, count, np.arange(com.shape[2]), classes)
  return vis


def path_scene_baseline(com, count, match, exclude):
  vis = meshcat.Visualizer(window=mv.SceneRecorder())
  for w in range(com.shape[0]):
    rgba = display.PATH_RGBA['exclude' if exclude[w] else 'match' if match[w] else 'faint']
    mat = mg.LineBasicMaterial(color=rgba.hex(), opacity=rgba.a, transparent=rgba.a < 1)
    for b in range(com.shape[2]):
      pts = np.ascontiguousarray(com[w, :count[w], b].T, np.float32)
      vis[f"paths/w{w}/b{b}"].set_object(mg.Line(mg.PointsGeometry(pts), mat))
  return vis


def bench_paths(n_worlds: int, n_bodies: int, n_points: int) -> tuple[dict, tuple]:
  data = random_paths(n_worlds, n_bodies, n_points)
  t_ours, t_base = best_of_interleaved(lambda: path_scene_ours(*data).static_html(),
                                       lambda: path_scene_baseline(*data).static_html())
  size_ours = len(path_scene_ours(*data).static_html())
  size_base = len(path_scene_baseline(*data).static_html())
  return ({"case": f"{n_worlds} worlds x {n_bodies} bodies x {n_points} points",
           "mwbx_s": t_ours, "baseline": "one meshcat Line per polyline", "baseline_s": t_base,
           "speedup": t_base / t_ours, "html_mb": size_ours / 1e6, "baseline_html_mb": size_base / 1e6},
          data)


FRAME_JS = """() => {
  const n = 10;
  viewer.render();
  const t0 = performance.now();
  for (let i = 0; i < n; i++) viewer.render();
  return {ms: (performance.now() - t0) / n, calls: viewer.renderer.info.render.calls};
}"""


def browser_frame(html: str, workdir: pathlib.Path, name: str) -> dict:
  from playwright.sync_api import sync_playwright
  from mwbx.testing.headless import CHROMIUM_BINARY, WEBGL_ARGS

  page_file = workdir / f"{name}.html"
  page_file.write_text(html)
  with sync_playwright() as pw:
    browser = pw.chromium.launch(executable_path=CHROMIUM_BINARY, args=list(WEBGL_ARGS))
    try:
      page = browser.new_page(viewport={"width": 800, "height": 600})
      t0 = time.perf_counter()
      page.goto(page_file.as_uri())
      page.wait_for_function("window.mwbx_loaded === true", timeout=600_000)
      load_s = time.perf_counter() - t0
      result = page.evaluate(FRAME_JS)
    finally:
      browser.close()
  return {"load_s": load_s, "ms_per_frame": result["ms"], "draw_calls": result["calls"]}


def load_bank():
  import mwbx

  if hasattr(mwbx, "sample") and (ROOT / "configs/quickstart.yaml").exists():
    import jax

    cfg = mwbx.load_config(str(ROOT / "configs/quickstart.yaml"))
    return "quickstart", mwbx.sample(cfg, n_worlds=128, key=jax.random.key(0))
  from mwbx.testing.standin import make_standin_bank

  return "viewer stand-in", make_standin_bank(n_worlds=128)


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--paths", type=int, default=2000, help="worlds in the path benchmark")
  parser.add_argument("--browser", action="store_true", help="also render in headless Chromium")
  parser.add_argument("--screenshot", type=pathlib.Path, help="write a screenshot of the export here")
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out/bench/viewer.json")
  args = parser.parse_args()

  results = {"machine": f"{platform.machine()}, {platform.processor() or 'cpu'}, "
                        f"python {platform.python_version()}"}
  results["animation"] = bench_animation(n_worlds=8, n_bodies=4, n_frames=600, fps=120.0)
  results["paths"], path_data = bench_paths(args.paths, 2, 100)

  bank_name, bank = load_bank()
  valid = np.asarray(bank.valid)
  match = valid & (np.arange(bank.n_worlds) % 4 == 0)
  exclude = valid & (np.arange(bank.n_worlds) % 4 == 1)
  worlds = np.asarray(bank.world_ids)[np.flatnonzero(valid)[:4]].tolist()
  queries, view_dir, path_bodies = None, None, True
  if bank_name == "quickstart":
    # Fig. 5 of the paper: an include box where paths land, an exclude box.
    from mwbx import queries as mq

    camera = mq.Camera.from_model(bank.model, "front")
    queries = [mq.Query.screen(camera, [0.3, 0.5, 0.42, 0.6], near=2.0, far=5.0, bodies="ball"),
               mq.Query.screen(camera, [0.1, 0.45, 0.2, 0.55], near=2.0, far=5.0, bodies="ball",
                               sign="exclude")]
    path_bodies = "ball"
    match = exclude = None
    matching = np.flatnonzero(np.asarray(mq.evaluate(bank, queries)))[:3]
    worlds = np.asarray(bank.world_ids)[matching].tolist() or worlds
    view_dir = (1.0, -1.6, 1.1)
  with tempfile.TemporaryDirectory() as tmp:
    tmp = pathlib.Path(tmp)
    t0 = time.perf_counter()
    out = mv.export_html(bank, tmp / "bank.html", worlds=worlds, paths=path_bodies, match=match, exclude=exclude,
                         queries=queries, view_dir=view_dir)
    results["export"] = {"case": f"{bank_name}: {bank.n_worlds} worlds of paths, {len(worlds)} played back",
                         "export_html_s": time.perf_counter() - t0, "html_mb": out.stat().st_size / 1e6}
    if args.browser:
      results["browser"] = {
          "case": results["paths"]["case"],
          "mwbx": browser_frame(path_scene_ours(*path_data).static_html(), tmp, "ours"),
          "baseline": browser_frame(path_scene_baseline(*path_data).static_html(), tmp, "baseline"),
      }
      results["browser"]["speedup"] = (results["browser"]["baseline"]["ms_per_frame"]
                                       / results["browser"]["mwbx"]["ms_per_frame"])
    if args.screenshot:
      from PIL import Image
      from mwbx.testing.headless import screenshot

      Image.fromarray(screenshot(out.as_uri(), seek_s=0.6)).save(args.screenshot)

  print(f"machine: {results['machine']}")
  print(f"{'measurement':<12} {'case':<42} {'mwbx':>10} {'baseline':>10} {'ratio':>7}")
  for key in ("animation", "paths"):
    r = results[key]
    print(f"{key:<12} {r['case']:<42} {r['mwbx_s']:>9.3f}s {r['baseline_s']:>9.3f}s {r['speedup']:>6.1f}x"
          f"   baseline: {r['baseline']}")
  print(f"{'':<12} html size: mwbx {results['paths']['html_mb']:.1f} MB, "
        f"baseline {results['paths']['baseline_html_mb']:.1f} MB")
  if "browser" in results:
    b = results["browser"]
    print(f"{'browser':<12} {b['case']:<42} {b['mwbx']['ms_per_frame']:>8.1f}ms "
          f"{b['baseline']['ms_per_frame']:>8.1f}ms {b['speedup']:>6.1f}x   per frame; draw calls "
          f"{b['mwbx']['draw_calls']} vs {b['baseline']['draw_calls']}; load "
          f"{b['mwbx']['load_s']:.1f}s vs {b['baseline']['load_s']:.1f}s")
  e = results["export"]
  print(f"{'export':<12} {e['case']:<42} {e['export_html_s']:>9.3f}s   ({e['html_mb']:.1f} MB)")
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(results, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
