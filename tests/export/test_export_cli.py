"""`mwbx export`: the command writes a saved bank's world as npz, USD and mp4
(read back and checked against ``bank.qpos_frames``), each bad request is one
stderr line with exit status 2, and ``mwbx.export_*`` load on first use."""

import math
import subprocess
import sys
import warnings

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import cli


@pytest.fixture(scope="module")
def saved(tiny_native, tmp_path_factory):
  """(bank directory, the bank as loaded from it, its longest world's id) of a small saved bank."""
  bank, _ = tiny_native.run(4, jax.random.key(0))
  folder = tmp_path_factory.mktemp("export_cli") / "bank"
  bank.save(folder)
  loaded = mwbx.Bank.load(folder)
  row = int(np.argmax(loaded.frame_count))  # worlds stop recording at rest; the spans below need 1 s
  assert (loaded.frame_count[row] - 1) / loaded.record_fps >= 1.0
  return folder, loaded, int(loaded.world_ids[row])


def forward_kinematics(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
  """f64[T, nbody, 3] body origins of each qpos frame (plain mj_kinematics)."""
  data = mujoco.MjData(model)
  out = []
  for q in np.asarray(qpos, np.float64):
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    out.append(data.xpos.copy())
  return np.array(out)


def written(out: str) -> dict[str, str]:
  """The command's stdout lines, by the path each names."""
  lines = out.strip().splitlines()
  assert all(line.startswith("wrote ") for line in lines), out
  return {line.split()[1]: line for line in lines}


def test_export_writes_the_npz_and_usd_of_a_world(saved, tmp_path, capsys):
  pytest.importorskip("pxr", reason="usd-core is the `export` extra (pip install 'mwbx[export]')")
  from pxr import Usd, UsdGeom
  folder, bank, world = saved
  npz, usd = tmp_path / "w.npz", tmp_path / "w.usdc"
  assert cli.main(["export", str(folder), "--world", str(world), "--npz", str(npz), "--usd", str(usd)]) == 0
  qpos = bank.qpos_frames(world)
  frames = len(qpos)
  lines = written(capsys.readouterr().out)
  assert set(lines) == {str(npz), str(usd)}
  for path in (npz, usd):
    assert f"world {world}, {frames} frames at {bank.record_fps:g} fps" in lines[str(path)]
    assert ("kB" in lines[str(path)]) or ("MB" in lines[str(path)])

  out = np.load(npz)
  np.testing.assert_array_equal(out["qpos"], qpos)  # exactly what the bank decodes
  np.testing.assert_array_equal(out["frames"], np.arange(frames))
  assert int(out["world"]) == world and float(out["fps"]) == bank.record_fps
  model = bank.model
  xpos = forward_kinematics(model, qpos)
  np.testing.assert_allclose(out["xpos"], xpos, rtol=0, atol=1e-12)

  stage = Usd.Stage.Open(str(usd))
  assert stage.GetTimeCodesPerSecond() == bank.record_fps
  assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, frames - 1)
  for name in ("cube", "ball"):
    b = model.body(name).id
    prim = UsdGeom.Xformable(stage.GetPrimAtPath(f"/World/bodies/{name}"))
    for frame in (0, 1, frames // 2, frames - 1):
      got = np.array(prim.ComputeLocalToWorldTransform(float(frame)).ExtractTranslation())
      np.testing.assert_allclose(got, xpos[frame, b], rtol=0, atol=1e-9)


def test_export_passes_fps_and_span_to_the_usd_and_keeps_every_frame_in_the_npz(saved, tmp_path, capsys):
  pytest.importorskip("pxr", reason="usd-core is the `export` extra (pip install 'mwbx[export]')")
  from pxr import Usd, UsdGeom
  folder, bank, world = saved
  npz, usd = tmp_path / "w.npz", tmp_path / "w.usda"
  argv = ["export", str(folder), "--world", str(world), "--npz", str(npz), "--usd", str(usd), "--fps", "30",
          "--start", "0.5", "--stop", "1.0"]
  assert cli.main(argv) == 0
  lines = written(capsys.readouterr().out)
  fps = bank.record_fps
  recorded = np.arange(math.ceil(0.5 * fps - 1e-6), math.floor(1.0 * fps + 1e-6) + 1)
  assert f"{len(recorded)} frames at {fps:g} fps" in lines[str(npz)]
  assert "16 frames at 30 fps" in lines[str(usd)]  # 0.5, 0.5 + 1/30, ..., 1.0 s
  qpos = bank.qpos_frames(world)
  np.testing.assert_array_equal(np.load(npz)["qpos"], qpos[recorded])
  np.testing.assert_array_equal(np.load(npz)["frames"], recorded)

  stage = Usd.Stage.Open(str(usd))
  assert stage.GetTimeCodesPerSecond() == 30 and stage.GetEndTimeCode() == 15
  model = bank.model
  shown = np.rint((0.5 + np.arange(16) / 30) * fps).astype(int)
  xpos = forward_kinematics(model, qpos[shown])
  prim = UsdGeom.Xformable(stage.GetPrimAtPath("/World/bodies/ball"))
  for k in (0, 7, 15):
    got = np.array(prim.ComputeLocalToWorldTransform(float(k)).ExtractTranslation())
    np.testing.assert_allclose(got, xpos[k, model.body("ball").id], rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def gl():
  pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is the `export` extra (pip install 'mwbx[export]')")
  from mwbx.export import video
  reason = video.gl_unavailable_reason()
  if reason is not None:
    pytest.skip(f"offscreen OpenGL unavailable: {reason}")


def read_video(path) -> tuple[tuple[int, int], list[np.ndarray]]:
  """((width, height), u8[H, W, 3] frames) of an mp4, decoded by imageio-ffmpeg's ffmpeg."""
  import imageio_ffmpeg
  reader = imageio_ffmpeg.read_frames(str(path))
  with warnings.catch_warnings():  # JAX warns of any fork; ffmpeg's is exec'd at once
    warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
    meta = next(reader)
  width, height = meta["size"]
  return (width, height), [np.frombuffer(b, np.uint8).reshape(height, width, 3) for b in reader]


@pytest.mark.parametrize("flags, frames", [
    ([], 16),
    (["--fps", "10", "--look-at", "0", "-2", "1.5", "0", "0", "0.3"], 6),
])
def test_export_renders_an_mp4_of_the_size_and_length_asked_for(saved, tmp_path, capsys, gl, flags, frames):
  folder, _, world = saved
  mp4 = tmp_path / "w.mp4"
  argv = ["export", str(folder), "--world", str(world), "--mp4", str(mp4), "--width", "160", "--height", "120",
          "--stop", "0.5", *flags]
  assert cli.main(argv) == 0
  fps = 30 if not flags else 10
  assert f"{frames} frames at {fps} fps" in written(capsys.readouterr().out)[str(mp4)]
  size, images = read_video(mp4)
  assert size == (160, 120)
  assert len(images) == frames  # 0, 1/fps, ..., 0.5 s
  assert images[0].std() > 5  # a picture, not a blank frame


@pytest.mark.parametrize("flags, named", [
    ([], "--usd FILE, --mp4 FILE or --npz FILE"),
    (["--world-id-unknown"], "world 99999: no world with this id"),
    (["--mp4", "w.mp4", "--camera", "front", "--look-at", "0", "-2", "1", "0", "0", "0"],
     "give --camera or --look-at, not both"),
    (["--npz", "w.npz", "--camera", "front"], "--camera: places the video's camera"),
    (["--usd", "w.obj"], "--usd: "),
    (["--usd", "w.usda", "--fps", "0"], "--fps: must be positive"),
    (["--npz", "w.npz", "--start", "9"], "--start: must be in"),
    (["--mp4", "w.mp4", "--width", "161"], "--width: must be an even number"),
    (["--mp4", "w.mp4", "--camera", "nope"], "--camera: no camera 'nope'"),
])
def test_a_bad_request_is_one_stderr_line_and_exit_status_2(saved, tmp_path, capsys, monkeypatch, flags, named):
  folder, _, world = saved
  monkeypatch.chdir(tmp_path)
  if flags == ["--world-id-unknown"]:
    world, flags = 99999, ["--npz", "w.npz"]
  assert cli.main(["export", str(folder), "--world", str(world), *flags]) == 2
  captured = capsys.readouterr()
  lines = captured.err.splitlines()
  assert len(lines) == 1, captured.err
  assert lines[0].startswith("mwbx: error: ") and named in lines[0], lines[0]
  assert captured.out == ""
  assert not list(tmp_path.iterdir())  # nothing written


def test_mwbx_reaches_the_exports_and_loads_them_on_first_use():
  from mwbx import export
  assert mwbx.export_usd is export.export_usd
  assert mwbx.render_video is export.render_video
  assert mwbx.export_npz is export.export_npz
  assert {"export_npz", "export_usd", "render_video"} <= set(mwbx.__all__) <= set(dir(mwbx))
  code = ("import sys, mwbx; print('mwbx.export' in sys.modules); mwbx.export_npz;"
          " print('mwbx.export' in sys.modules)")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600)
  assert out.stdout.split() == ["False", "True"]


def test_the_usage_list_and_help_name_the_command():
  assert "mwbx export BANK --world ID" in cli.__doc__
  help_text = cli.build_parser().format_help()
  assert "export" in help_text
  export_help = cli.build_parser()._subparsers._group_actions[0].choices["export"].format_help()
  for flag in ("--usd", "--mp4", "--npz", "--fps", "--start", "--stop", "--camera", "--look-at", "--width",
               "--height", "--skip-corrupt"):
    assert flag in export_help
