"""`mwbx export` and mwbx.export write only where they should: a new file or
a regular file replaced whole (never a FIFO, device, directory or a symlink's
target), under the suffix of their format, into a folder checked before any
work; every bad request is one stderr line; MUJOCO_GL is read only when
rendering; and a killed writer's temporary file is removed by the next export."""

import os
import pathlib
import signal
import stat
import subprocess
import sys
import textwrap

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.export import export_npz
from mwbx.export import render_video
from mwbx.export import target
from mwbx.export import video

# The console script `mwbx`, run with this interpreter.
MWBX = [sys.executable, "-c", "import sys; from mwbx.cli import main; sys.exit(main())"]


@pytest.fixture(scope="module")
def saved(tiny_native, tmp_path_factory):
  """(bank directory, the bank as loaded from it, a world id) of a small saved bank."""
  bank, _ = tiny_native.run(2, jax.random.key(0))
  folder = tmp_path_factory.mktemp("export_targets") / "bank"
  bank.save(folder)
  loaded = mwbx.Bank.load(folder)
  return folder, loaded, int(loaded.world_ids[0])


@pytest.fixture(scope="module")
def gl():
  pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is the `export` extra (pip install 'mwbx[export]')")
  reason = video.gl_unavailable_reason()
  if reason is not None:
    pytest.skip(f"offscreen OpenGL unavailable: {reason}")


def export_error(saved, capsys, *flags) -> str:
  """The one stderr line of `mwbx export BANK --world W FLAGS`, which must fail with status 2."""
  folder, _, world = saved
  assert cli.main(["export", str(folder), "--world", str(world), *map(str, flags)]) == 2
  captured = capsys.readouterr()
  lines = captured.err.splitlines()
  assert len(lines) == 1 and lines[0].startswith("mwbx: error: "), captured.err
  assert "wrote" not in captured.out
  return lines[0]


def temps(folder: pathlib.Path) -> list[str]:
  return sorted(p.name for p in folder.iterdir() if ".mwbx-tmp-" in p.name or ".tmp-" in p.name)


# 1. Only a new file or a regular file is replaced.


@pytest.mark.parametrize("kind", ["fifo", "symlink out", "directory"])
def test_a_special_target_is_refused_and_left_as_it_was(saved, tmp_path, capsys, kind):
  out = tmp_path / "out"
  out.mkdir()
  path = out / "w.npz"
  outside = tmp_path / "outside.npz"  # where a symlink would lead the write
  outside.write_bytes(b"keep")
  if kind == "fifo":
    os.mkfifo(path)
  elif kind == "symlink out":
    path.symlink_to(outside)
  else:
    path.mkdir()
  line = export_error(saved, capsys, "--npz", path)
  assert f"--npz: {path}: is a" in line and "regular file" in line, line
  mode = os.lstat(path).st_mode
  assert {"fifo": stat.S_ISFIFO, "symlink out": stat.S_ISLNK,
          "directory": stat.S_ISDIR}[kind](mode)
  assert outside.read_bytes() == b"keep"
  assert temps(out) == []
  # The library refuses it too, and a regular file beside it is still replaced.
  _, bank, world = saved
  with pytest.raises(mwbx.MwbxError, match="regular file"):
    export_npz(bank, world, path)
  regular = out / "r.npz"
  regular.write_bytes(b"old")
  assert export_npz(bank, world, regular) == regular
  assert np.load(regular)["qpos"].shape[0] > 0


def test_a_target_turned_special_before_the_rename_is_not_replaced(tmp_path):
  path = tmp_path / "w.npz"
  tmp = target.reserve_temp(path)
  os.mkfifo(path)  # appears while the export is being written
  with pytest.raises(mwbx.MwbxError, match="is a FIFO"):
    target.replace(tmp, path, "npz export")
  assert stat.S_ISFIFO(os.lstat(path).st_mode)
  assert not tmp.exists()


def test_a_device_target_is_refused(saved, tmp_path, capsys):
  path = tmp_path / "null.npz"
  try:
    os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # what /dev/null is
  except (PermissionError, AttributeError, OSError):
    path.symlink_to("/dev/null")  # not root: a symlink to it, refused as well
  line = export_error(saved, capsys, "--npz", path)
  assert "regular file" in line
  assert not stat.S_ISREG(os.lstat(path).st_mode)
  assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


# 2. The suffix matches the format.


@pytest.mark.parametrize("flag, name, suffixes", [
    ("--npz", "w.usda", ".npz"),
    ("--mp4", "w.avi", ".mp4"),
    ("--usd", "w.usdz", ".usd, .usda, .usdc"),
])
def test_a_suffix_of_another_format_is_refused(saved, tmp_path, capsys, flag, name, suffixes):
  line = export_error(saved, capsys, flag, tmp_path / name)
  assert f"{flag}: {tmp_path / name}: " in line and f"name ends in {suffixes}" in line, line
  assert not list(tmp_path.iterdir())
  _, bank, world = saved
  if flag == "--npz":
    with pytest.raises(mwbx.MwbxError, match=r"ends in \.npz"):
      export_npz(bank, world, tmp_path / name)


# 3. Every error one line, naming the flag, value or folder.


@pytest.mark.parametrize("flag, name", [("--mp4", "w.mp4"), ("--usd", "w.usda"), ("--npz", "w.npz")])
def test_a_folder_that_cannot_be_written_is_named_before_any_work(saved, tmp_path, capsys, flag, name):
  pytest.importorskip("pxr", reason="usd-core is the `export` extra (pip install 'mwbx[export]')")
  pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is the `export` extra")
  afile = tmp_path / "afile"
  afile.write_text("a file, not a folder")
  line = export_error(saved, capsys, flag, afile / "sub" / name)
  assert f"{flag}: " in line and f"{afile} is not a folder" in line, line
  if os.path.isdir("/proc/self"):  # procfs takes no new files, even from root (chmod would not stop root)
    line = export_error(saved, capsys, flag, f"/proc/{name}")
    assert "cannot write in the folder /proc" in line and "pxr" not in line and "ffmpeg" not in line.lower()
  assert afile.read_text() == "a file, not a folder"


def test_a_missing_folder_is_made(saved, tmp_path):
  _, bank, world = saved
  path = export_npz(bank, world, tmp_path / "a" / "b" / "w.npz")
  assert path.is_file() and temps(path.parent) == []


@pytest.mark.parametrize("flags, named", [
    (["--width", "100000", "--height", "100000"], "--width: must be at most 8192 pixels, got 100000"),
    (["--width", "64", "--height", "20000"], "--height: must be at most 8192 pixels, got 20000"),
    (["--fps", "5000"], "--fps: "),
    (["--fps", "0.001"], "--fps: "),
    (["--fps", "-30"], "--fps: "),
    (["--fps", "nan"], "--fps: "),
    (["--look-at", "1e308", "1e308", "1e308", "0", "0", "0"], "--look-at: "),
])
def test_a_bad_video_number_is_one_line_naming_its_flag(saved, tmp_path, capsys, flags, named):
  line = export_error(saved, capsys, "--mp4", tmp_path / "w.mp4", "--stop", "0.01", *flags)
  assert named in line, line
  assert "cannot open an OpenGL context" not in line  # not blamed on EGL
  assert not list(tmp_path.iterdir())


def test_a_huge_fps_is_refused_for_usd_too(saved, tmp_path, capsys):
  line = export_error(saved, capsys, "--usd", tmp_path / "w.usda", "--fps", "5000", "--stop", "0.01")
  assert "--fps: must be at most 1000" in line, line


def test_the_size_limit_follows_the_mjcf_offscreen_buffer():
  model = mujoco.MjModel.from_xml_string(
      "<mujoco><visual><global offwidth='10000'/></visual><worldbody/></mujoco>")
  video.check_size(9000, 480, model)  # the MJCF's buffer allows it
  with pytest.raises(mwbx.MwbxError, match="width: must be at most 10000"):
    video.check_size(10002, 480, model)
  with pytest.raises(mwbx.MwbxError, match=r"height: must be at most 8192 .*offheight"):
    video.check_size(640, 9000, model)


# 4. MUJOCO_GL is read when rendering, not when mujoco is imported.


def run_mwbx(*args, **env) -> subprocess.CompletedProcess:
  """`mwbx ARGS` in a new process with ``env`` added to the environment."""
  # This process's EGL renderer set PYOPENGL_PLATFORM=egl, which would make mujoco skip OSMesa quietly.
  base = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
  return subprocess.run([*MWBX, *map(str, args)], capture_output=True, text=True, timeout=600,
                        env={**base, **env})


@pytest.mark.parametrize("value", ["bogus", "osmesa"])
def test_mujoco_gl_does_not_break_a_command_that_does_not_render(saved, value):
  out = run_mwbx("--version", MUJOCO_GL=value)
  assert out.returncode == 0 and out.stdout.strip() == f"mwbx {mwbx.__version__}", out.stderr
  assert out.stderr == ""
  out = run_mwbx("info", saved[0], MUJOCO_GL=value)
  assert out.returncode == 0 and "worlds" in out.stdout, out.stderr
  assert "Traceback" not in out.stderr


def test_a_bad_mujoco_gl_is_one_line_when_rendering(saved, tmp_path, capsys, monkeypatch):
  pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is the `export` extra")
  monkeypatch.setenv("MUJOCO_GL", "bogus")
  line = export_error(saved, capsys, "--mp4", tmp_path / "w.mp4", "--width", "64", "--height", "48")
  assert "MUJOCO_GL: 'bogus'" in line and "egl, osmesa or glfw" in line, line
  _, bank, world = saved
  with pytest.raises(mwbx.MwbxError, match="MUJOCO_GL"):
    render_video(bank, world, tmp_path / "w.mp4", width=64, height=48)
  assert not list(tmp_path.iterdir())


def test_mujoco_gl_osmesa_renders_or_says_what_to_install(saved, tmp_path):
  pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is the `export` extra")
  mp4 = tmp_path / "w.mp4"
  out = run_mwbx("export", saved[0], "--world", saved[2], "--mp4", mp4, "--width", "64", "--height", "48",
                 "--stop", "0.05", MUJOCO_GL="osmesa")
  if out.returncode == 0:  # libOSMesa is installed
    assert mp4.is_file()
    return
  lines = [line for line in out.stderr.splitlines() if not line.startswith("export:")]
  assert out.returncode == 2 and len(lines) == 1, out.stderr
  assert "MUJOCO_GL=osmesa" in lines[0] and "libosmesa6" in lines[0]


# 5. A killed writer's temporary file goes with the next export.


def kill_a_writer(path: pathlib.Path) -> pathlib.Path:
  """The temporary file a writer of ``path`` left when it was SIGKILLed."""
  code = textwrap.dedent(f"""
      import os, pathlib, signal
      from mwbx.export import target
      print(target.reserve_temp(pathlib.Path({str(path)!r})), flush=True)
      os.kill(os.getpid(), signal.SIGKILL)
  """)
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
  assert out.returncode == -signal.SIGKILL, out.stderr
  tmp = pathlib.Path(out.stdout.strip())
  assert tmp.is_file() and tmp.parent == path.parent
  return tmp


def test_a_killed_writers_temp_is_removed_by_the_next_export(saved, tmp_path, capsys):
  path = tmp_path / "w.npz"
  stale = kill_a_writer(path)
  assert stale.name.startswith(".w.npz.mwbx-tmp-") and stale.suffix == ".npz"
  pid = int(stale.name.split("-")[-2])
  assert pid != os.getpid()
  live = target.reserve_temp(path)  # a writer still running (this process): kept
  other = tmp_path / (stale.name.replace(".w.npz.", ".x.npz.", 1))  # another file's: kept
  other.write_bytes(b"")
  folder, _, world = saved
  assert cli.main(["export", str(folder), "--world", str(world), "--npz", str(path)]) == 0
  assert path.is_file()
  assert not stale.exists()
  assert live.exists() and other.exists()
  live.unlink()


def test_a_killed_video_writers_temp_is_removed_by_the_next_video(saved, tmp_path, gl):
  _, bank, world = saved
  path = tmp_path / "w.mp4"
  stale = kill_a_writer(path)
  render_video(bank, world, path, width=64, height=48, stop=0.05)
  assert path.is_file() and not stale.exists()
  assert temps(tmp_path) == []
