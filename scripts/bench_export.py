"""Export benchmark: one 5 s SIGGRAPH world to USD and to a 720p mp4.

Samples 16 SIGGRAPH worlds (configs/siggraph.yaml, native backend; most come
to rest, and stop recording, after 2-3 s), takes the valid one recorded
longest (world 8 of seed 0 runs the full 5 s) and times, against named
baselines measured in the same run:

  usd   export_usd (every recorded frame, 120 fps) to .usdc and .usda; the
        first call includes importing usd-core
        vs decode + FK: the world's qpos decoded and forward kinematics run
        over its frames (mwbx.export.world_poses), what every export starts from
  mp4   render_video at 1280x720, 30 fps, H.264
        vs decode + FK at the video's frames, and vs rendering the same frames
        without encoding them (mujoco.Renderer only)

Goals (the issue): USD <= 5 s, mp4 <= 60 s on 2 CPU cores.
Writes docs/bench/export.json. Usage:
  MUJOCO_GL=egl .venv/bin/python scripts/bench_export.py [--worlds 16] [--out docs/bench/export.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import pathlib
import platform
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402

import mwbx  # noqa: E402
from mwbx.export import export_usd, render_video, world_poses  # noqa: E402
from mwbx.export import video  # noqa: E402


def timed(fn) -> float:
  t0 = time.perf_counter()
  fn()
  return time.perf_counter() - t0


def best(fn, repeats: int) -> float:
  return min(timed(fn) for _ in range(repeats))


def gl_renderer_name(renderer) -> str:
  """The OpenGL renderer string of ``renderer``'s context (e.g. llvmpipe)."""
  try:
    from OpenGL import GL
    renderer._gl_context.make_current()
    return GL.glGetString(GL.GL_RENDERER).decode()
  except Exception as err:  # noqa: BLE001 (informational only)
    return f"unknown ({type(err).__name__})"


def render_only(bank, world: int, width: int, height: int, fps: float) -> tuple[float, str]:
  """Seconds to render the video's frames without encoding them, and the GL renderer."""
  poses = world_poses(bank, world, fps=fps)
  model = copy.copy(bank.model)
  model.vis.global_.offwidth, model.vis.global_.offheight = width, height
  renderer = video.open_renderer(model, width, height)
  try:
    camera = video._camera(bank, world, model, None, None, width / height)
    t0 = time.perf_counter()
    for _ in video.render_frames(model, poses, renderer, camera):
      pass
    return time.perf_counter() - t0, gl_renderer_name(renderer)
  finally:
    renderer.close()


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--worlds", type=int, default=16, help="SIGGRAPH worlds to sample (default 16)")
  parser.add_argument("--repeats", type=int, default=3, help="best of this many runs (default 3)")
  parser.add_argument("--out", default=str(ROOT / "docs" / "bench" / "export.json"))
  args = parser.parse_args()

  t0 = time.perf_counter()
  bank = mwbx.sample(mwbx.load_config(ROOT / "configs" / "siggraph.yaml"), n_worlds=args.worlds,
                     key=jax.random.key(0), backend="native")
  sample_s = time.perf_counter() - t0
  valid = np.flatnonzero(bank.valid)
  world = int(bank.world_ids[valid[np.argmax(bank.frame_count[valid])]])  # the longest recording
  n_frames = int(bank.frame_count[bank.row_of(world)])
  model = bank.model
  case = (f"SIGGRAPH world {world}: {n_frames} frames at {bank.record_fps:g} fps "
          f"({(n_frames - 1) / bank.record_fps:g} s), {model.nbody - 1} bodies, {model.ngeom} geoms")
  print(f"sampled {args.worlds} SIGGRAPH worlds in {sample_s:.1f} s; {case}")

  out_dir = pathlib.Path(tempfile.mkdtemp(prefix="mwbx-bench-export-"))
  decode_fk_s = best(lambda: world_poses(bank, world), args.repeats)
  usd_cold_s = timed(lambda: export_usd(bank, world, out_dir / "cold.usdc"))
  usdc_s = best(lambda: export_usd(bank, world, out_dir / "w.usdc"), args.repeats)
  usda_s = best(lambda: export_usd(bank, world, out_dir / "w.usda"), args.repeats)
  usd = {"case": case, "baseline": "decode + FK over the world's frames (world_poses)",
         "baseline_s": decode_fk_s, "usdc_first_call_s": usd_cold_s, "usdc_s": usdc_s, "usda_s": usda_s,
         "usdc_over_baseline": usdc_s / decode_fk_s, "usda_over_baseline": usda_s / decode_fk_s,
         "usdc_mb": (out_dir / "w.usdc").stat().st_size / 1e6,
         "usda_mb": (out_dir / "w.usda").stat().st_size / 1e6, "goal_s": 5.0}
  print(f"usd: .usdc {usdc_s:.3f} s (first call, importing usd-core: {usd_cold_s:.3f} s), .usda {usda_s:.3f} s; "
        f"decode + FK {decode_fk_s:.3f} s: {usdc_s / decode_fk_s:.1f}x / {usda_s / decode_fk_s:.1f}x of it")

  width, height, fps = 1280, 720, 30.0
  frames = len(world_poses(bank, world, fps=fps).times)
  decode_fk_video_s = best(lambda: world_poses(bank, world, fps=fps), args.repeats)
  # Interleaved, best of 2 each: llvmpipe's timings drift on a shared machine.
  render_runs, mp4_runs = [], []
  for _ in range(2):
    render_s, gl_name = render_only(bank, world, width, height, fps)
    render_runs.append(render_s)
    mp4_runs.append(timed(lambda: render_video(bank, world, out_dir / "w.mp4", width=width, height=height,
                                               fps=fps)))
  render_s, mp4_s = min(render_runs), min(mp4_runs)
  mp4 = {"case": f"{case}; {width}x{height}, {fps:g} fps, {frames} frames, H.264 crf {video._CRF} "
                 f"preset {video._PRESET}",
         "gl_renderer": gl_name, "mp4_s": mp4_s, "frames_per_s": frames / mp4_s,
         "baseline": "decode + FK at the video's frames", "baseline_s": decode_fk_video_s,
         "mp4_over_baseline": mp4_s / decode_fk_video_s,
         "render_only_s": render_s, "mp4_over_render_only": mp4_s / render_s,
         "mp4_runs_s": mp4_runs, "render_only_runs_s": render_runs,
         "mp4_mb": (out_dir / "w.mp4").stat().st_size / 1e6, "goal_s": 60.0}
  print(f"mp4: {mp4_s:.2f} s ({frames / mp4_s:.1f} frames/s, GL {gl_name}); render only {render_s:.2f} s "
        f"({mp4_s / render_s:.2f}x); decode + FK {decode_fk_video_s:.3f} s")

  machine = (f"{platform.machine()}, {os.cpu_count()} CPU cores, "
             f"{'GPU: ' + str(jax.devices()[0]) if jax.default_backend() != 'cpu' else 'no GPU'}, "
             f"python {platform.python_version()}, MUJOCO_GL={os.environ.get('MUJOCO_GL') or 'unset (egl)'}")
  result = {"machine": machine, "sample_s": sample_s, "usd": usd, "mp4": mp4}
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  out.write_text(json.dumps(result, indent=2) + "\n")
  print(f"wrote {out} (exports kept in {out_dir})")


if __name__ == "__main__":
  main()
