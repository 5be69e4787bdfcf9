"""A world as an mp4: offscreen MuJoCo rendering of its decoded motion.

Each video frame sets the world's decoded ``qpos`` (the nearest recorded frame
to the frame's time), runs forward kinematics and renders it with
``mujoco.Renderer``; frames stream into ffmpeg (imageio-ffmpeg's bundled
binary, H.264, yuv420p) while the next one renders.

OpenGL: ``MUJOCO_GL`` (``egl``, ``osmesa``, ``glfw``) is read here, when a
renderer opens, not when MuJoCo is imported (:mod:`mwbx.mujoco_gl` imports
it without the variable, so a bad value or a missing library fails only a
render, in one line). Where it is unset on a Linux machine with no display,
MuJoCo's default (GLFW) needs a window system, so the renderer is opened on
EGL instead (GPU drivers, or Mesa's software rasterizer on a CPU machine).
"""

from __future__ import annotations

import contextlib
import copy
import importlib
import math
import os
import pathlib
import sys
import warnings
from typing import Sequence

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.export import target
from mwbx.export.poses import WorldPoses, world_poses
from mwbx.files import remove_quietly, why
from mwbx.progress import Progress, ProgressFn
from mwbx.viewer.display import camera_pose
from mwbx.viewer.framing import scene_bounds, view_spec

PHASE = "rendering video"
# Geom group the renderer hides (MjvOption.geomgroup) where an object is absent.
_HIDDEN_GROUP = 5
# H.264 quality (constant rate factor: lower is better; 18-23 looks clean) and
# x264's speed preset (veryfast keeps encoding behind rendering on 2 cores).
_CRF = "20"
_PRESET = "veryfast"
# What to do when no OpenGL context opens.
_GL_HELP = ("install Mesa's EGL (Debian/Ubuntu: apt install libegl1 libegl-mesa0), or start Python with "
            "MUJOCO_GL=osmesa (apt install libosmesa6)")
# MUJOCO_GL values and the MuJoCo module whose GLContext each opens (glx is
# MuJoCo's other name for GLFW on Linux, cgl its macOS backend).
_GL_MODULES = {"egl": "mujoco.egl", "osmesa": "mujoco.osmesa", "glfw": "mujoco.glfw", "glx": "mujoco.glfw",
               "cgl": "mujoco.cgl"}
_GL_FIX = {
    "egl": _GL_HELP,
    "osmesa": "install OSMesa (Debian/Ubuntu: apt install libosmesa6), or set MUJOCO_GL=egl",
    "glfw": "GLFW needs a display; with none, unset MUJOCO_GL or set MUJOCO_GL=egl",
}
# Video frame size limits, pixels: up to 8K (7680x4320) in either direction
# unless the MJCF's offscreen buffer is larger; beyond that OpenGL drivers
# and H.264 levels give out.
MAX_SIDE = 8192
# Video frame rate limits, frames per second: ffmpeg takes the rate as a
# fraction, and below 1 or above 1000 players misbehave.
MIN_FPS, MAX_FPS = 1.0, 1000.0


def _ffmpeg():
  """imageio_ffmpeg, or one MwbxError naming what to install."""
  try:
    import imageio_ffmpeg  # lazy: the optional `export` extra
  except ImportError:
    raise MwbxError("render_video: needs imageio-ffmpeg (pip install imageio-ffmpeg, or pip install "
                    "'mwbx[export]')") from None
  return imageio_ffmpeg


def _headless() -> bool:
  """Linux without a display and without MUJOCO_GL: MuJoCo's GLFW default cannot open."""
  return (sys.platform.startswith("linux") and not os.environ.get("MUJOCO_GL")
          and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"))


def gl_backend_name() -> str:
  """The OpenGL backend renderers open: ``MUJOCO_GL``, else EGL where there
  is no display (Linux) and GLFW where there is.

  Raises:
    MwbxError: naming MUJOCO_GL and the values it takes when it holds another.
  """
  value = os.environ.get("MUJOCO_GL", "").strip().lower()
  if not value:
    return "egl" if _headless() else "glfw"
  if value not in _GL_MODULES:
    raise MwbxError(f"MUJOCO_GL: {os.environ['MUJOCO_GL']!r} is not an OpenGL backend; set it to egl, osmesa "
                    "or glfw, or unset it (EGL where there is no display)")
  return value


def _first_line(err: BaseException) -> str:
  text = str(err).strip()
  return text.splitlines()[0] if text else type(err).__name__


@contextlib.contextmanager
def _gl_backend():
  """Opens renderers on the backend :func:`gl_backend_name` names (mujoco was
  imported without MUJOCO_GL, so its own choice is its platform default)."""
  name = gl_backend_name()
  if not os.environ.get("MUJOCO_GL", "").strip() and not _headless():
    yield  # a display and no MUJOCO_GL: MuJoCo's own choice for this platform
    return
  # The module whose GLContext mujoco.Renderer opens (mujoco.rendering.classic.gl_context in 4.x).
  gl_context = sys.modules[mujoco.Renderer.__module__].gl_context
  try:
    context_class = importlib.import_module(_GL_MODULES[name]).GLContext  # lazy: loads its GL library
  except Exception as err:  # noqa: BLE001 (a missing library shows as ImportError, OSError or AttributeError)
    raise MwbxError(f"MUJOCO_GL={name}: its OpenGL library cannot load ({_first_line(err)}); "
                    f"{_GL_FIX.get(name, _GL_HELP)}") from None
  saved = getattr(gl_context, "GLContext", None)
  gl_context.GLContext = context_class
  try:
    yield
  finally:
    gl_context.GLContext = saved


def open_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
  """A ``mujoco.Renderer`` of ``width`` x ``height`` pixels for ``model`` (whose
  offscreen buffer must be at least that large); MwbxError if OpenGL fails."""
  try:
    # GLFW warns of each failed step (no DISPLAY, ...) before it fails: the error below says it once.
    with _gl_backend(), warnings.catch_warnings(record=True):
      return mujoco.Renderer(model, height, width)
  except MwbxError:
    raise
  except Exception as err:  # noqa: BLE001 (GL failures come as many types)
    backend = gl_backend_name()
    raise MwbxError(f"render_video: cannot open an OpenGL context (MUJOCO_GL={backend}: {_first_line(err)}); "
                    f"{_GL_FIX.get(backend, _GL_HELP)}") from None


def gl_unavailable_reason() -> str | None:
  """None when offscreen rendering works in this process, else why not."""
  model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
  try:
    open_renderer(model, 16, 16).close()
  except MwbxError as err:
    return str(err)
  return None


def free_camera(eye: Sequence[float], target: Sequence[float]) -> mujoco.MjvCamera:
  """A free ``MjvCamera`` at ``eye`` looking at ``target`` (f[3] m each), world +z up.

  Raises:
    MwbxError: naming look_at when either is not a finite 3-vector or they coincide.
  """
  eye = np.asarray(eye, np.float64).reshape(-1)
  target = np.asarray(target, np.float64).reshape(-1)
  if eye.shape != (3,) or target.shape != (3,) or not (np.all(np.isfinite(eye)) and np.all(np.isfinite(target))):
    raise MwbxError(f"look_at: must be (eye, target), two finite 3-vectors in metres, got "
                    f"{eye.tolist()}, {target.tolist()}")
  offset = target - eye
  with np.errstate(over="ignore", invalid="ignore"):  # far apart: inf, refused below
    distance = float(np.linalg.norm(offset))
  if not math.isfinite(distance):
    raise MwbxError(f"look_at: eye and target are too far apart to render, {eye.tolist()}, {target.tolist()}")
  if distance < 1e-9:
    raise MwbxError(f"look_at: eye and target coincide at {eye.tolist()}")
  forward = offset / distance
  camera = mujoco.MjvCamera()
  camera.type = mujoco.mjtCamera.mjCAMERA_FREE
  camera.lookat[:] = target
  camera.distance = distance
  camera.azimuth = math.degrees(math.atan2(forward[1], forward[0]))
  camera.elevation = math.degrees(math.asin(float(np.clip(forward[2], -1.0, 1.0))))
  return camera


def _camera(bank, world: int, model: mujoco.MjModel, camera: str | None, look_at, aspect: float):
  """What update_scene takes: an MJCF camera id, or a free camera (look_at,
  or the viewer's first view of the world). May set ``model``'s free-camera fovy."""
  if camera is not None and look_at is not None:
    raise MwbxError("render_video: give camera or look_at, not both")
  if camera is not None:
    cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, str(camera))
    if cam < 0:
      names = [model.camera(c).name for c in range(model.ncam) if model.camera(c).name]
      raise MwbxError(f"camera: no camera {camera!r} in the MJCF (have: {', '.join(names) or 'none'})")
    return cam
  if look_at is not None:
    try:
      eye, target = look_at
    except (TypeError, ValueError):
      raise MwbxError(f"look_at: must be (eye, target), two 3-vectors in metres, got {look_at!r}") from None
    return free_camera(eye, target)
  lo, hi = scene_bounds(bank, model, np.array([bank.row_of(world)]), None, None)
  pose = camera_pose(lo, hi, view_spec(model), aspect)
  model.vis.global_.fovy = pose.fovy
  return free_camera(pose.eye, pose.target)


def check_size(width: int, height: int, model: mujoco.MjModel | None = None, prefix: str = "") -> None:
  """MwbxError naming ``width`` or ``height`` (after ``prefix``, e.g. ``--``)
  unless both are even pixel counts from 2 up to :data:`MAX_SIDE`, or up to
  ``model``'s offscreen buffer (``visual/global offwidth, offheight``) where
  that is larger; without ``model``, only the lower bound and evenness."""
  for name, value in (("width", width), ("height", height)):
    integer = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not integer or value < 2 or value % 2:
      raise MwbxError(f"{prefix}{name}: must be an even number of pixels >= 2 (H.264, yuv420p), got {value!r}")
    if model is None:
      continue
    limit = max(MAX_SIDE, int(getattr(model.vis.global_, f"off{name}")))
    if value > limit:
      raise MwbxError(f"{prefix}{name}: must be at most {limit} pixels, got {value} (a larger offscreen "
                      f"buffer is the MJCF's <visual><global off{name}=\"N\"/></visual>, if OpenGL takes it)")


def check_fps(fps, prefix: str = "") -> None:
  """MwbxError naming ``fps`` unless it is a number in [MIN_FPS, MAX_FPS]."""
  number = isinstance(fps, (int, float, np.number)) and not isinstance(fps, bool)
  if not (number and math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
    raise MwbxError(f"{prefix}fps: a video's frame rate must be from {MIN_FPS:g} to {MAX_FPS:g} frames per "
                    f"second, got {fps!r}")


def render_frames(model: mujoco.MjModel, poses: WorldPoses, renderer: mujoco.Renderer, camera):
  """Yields u8[H, W, 3] images of ``poses``'s frames (parked bodies hidden)."""
  data = mujoco.MjData(model)
  option = mujoco.MjvOption()
  option.geomgroup[_HIDDEN_GROUP] = 0
  groups = model.geom_group.copy()
  hideable = ~poses.present.all(axis=0)  # bool[nbody]
  for k in range(len(poses.times)):
    if hideable.any():
      hidden = ~poses.present[k][model.geom_bodyid]
      model.geom_group[:] = np.where(hidden, _HIDDEN_GROUP, groups)
    data.qpos[:] = poses.qpos[k]
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)  # cameras and lights on bodies follow them
    if model.nflex:
      mujoco.mj_flex(model, data)  # deformables' vertices
    renderer.update_scene(data, camera, option)
    yield renderer.render()


def render_video(bank, world: int, path: str | os.PathLike, *, camera: str | None = None,
                 look_at: tuple[Sequence[float], Sequence[float]] | None = None, width: int = 1280,
                 height: int = 720, fps: float = 30.0, start: float = 0.0, stop: float | None = None,
                 progress: ProgressFn | None = None) -> pathlib.Path:
  """Renders world ``world`` to an mp4 (H.264) with MuJoCo's offscreen renderer.

  Video frame k shows the recorded frame nearest to ``start + k / fps`` s, so
  a clip of duration D s has ``floor(D * fps) + 1`` frames.

  Args:
    bank: a :class:`mwbx.Bank`.
    world: world id.
    path: the ``.mp4`` file: a new file, or a regular file replaced whole
      or not at all (a symlink, FIFO, device or directory is refused).
    camera: an MJCF camera name to render from.
    look_at: ``(eye, target)``, two 3-vectors in metres: a free camera at eye
      looking at target (world +z up, the model's ``visual/global/fovy``).
      Neither given: the viewer's first view of this world (its MJCF scene
      camera's direction, else obliquely from the front right, fitted to
      what moves).
    width, height: pixels, even, at most 8192 (or the MJCF's
      ``visual/global offwidth``/``offheight`` where larger).
    fps: frames per second of the video, 1 to 1000.
    start, stop: time span, s (default: the whole recording).
    progress: optional callback taking :class:`mwbx.progress.Progress`
      (phase ``rendering video``, ``done`` the fraction of the world rendered).

  Returns:
    the path written.

  Raises:
    MwbxError: naming the world, camera, size, span, file or folder at
      fault, saying to install imageio-ffmpeg, or that OpenGL cannot open
      (naming MUJOCO_GL and what to set or install).

  Example:
    >>> render_video(bank, 3, "world3.mp4", camera="front")           # 1280x720, 30 fps
    >>> render_video(bank, 3, "top.mp4", look_at=((0, 0, 3), (0, 0, 0.5)), width=640, height=480)
  """
  imageio_ffmpeg = _ffmpeg()
  path = target.check_target(path, "mp4")
  check_size(width, height, bank.model)
  check_fps(fps)
  gl_backend_name()  # a bad MUJOCO_GL is named before any work
  poses = world_poses(bank, world, fps=fps, start=start, stop=stop)
  model = copy.copy(bank.model)  # the renderer's own: buffer size, fovy and hidden groups change
  model.vis.global_.offwidth = max(int(width), model.vis.global_.offwidth)
  model.vis.global_.offheight = max(int(height), model.vis.global_.offheight)
  cam = _camera(bank, int(world), model, camera, look_at, width / height)
  tmp = target.reserve_temp(path)  # the folder is writable before anything renders
  try:
    renderer = open_renderer(model, int(width), int(height))
  except BaseException:
    remove_quietly(tmp)
    raise
  writer = None
  try:
    writer = imageio_ffmpeg.write_frames(str(tmp), (int(width), int(height)), fps=float(fps), codec="libx264",
                                         pix_fmt_out="yuv420p", quality=None, macro_block_size=1,
                                         output_params=["-crf", _CRF, "-preset", _PRESET], ffmpeg_log_level="error")
    with warnings.catch_warnings():  # JAX warns of any fork; ffmpeg's is exec'd at once, nothing to act on
      warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
      writer.send(None)  # starts ffmpeg
    total = len(poses.times)
    for k, image in enumerate(render_frames(model, poses, renderer, cam)):
      writer.send(np.ascontiguousarray(image))
      if progress is not None and (k % 10 == 9 or k == total - 1):
        progress(Progress(PHASE, (k + 1) / total, 1, 0))
    writer.close()
    writer = None
    target.replace(tmp, path, "video")
  except OSError as err:
    remove_quietly(tmp)
    raise MwbxError(f"{path}: cannot write video ({why(err)})") from None
  except RuntimeError as err:  # ffmpeg stopped (a full disk, a bad path)
    remove_quietly(tmp)
    raise MwbxError(f"{path}: cannot write video (ffmpeg: {str(err).strip().splitlines()[0]})") from None
  finally:
    if writer is not None:  # stopped part way: the partial file goes
      with contextlib.suppress(Exception):
        writer.close()
    remove_quietly(tmp)  # gone after the rename; else what a failure left
    renderer.close()
  return path
