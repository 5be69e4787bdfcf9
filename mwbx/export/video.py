"""A world as an mp4: offscreen MuJoCo rendering of its decoded motion.

Each video frame sets the world's decoded ``qpos`` (the nearest recorded frame
to the frame's time), runs forward kinematics and renders it with
``mujoco.Renderer``; frames stream into ffmpeg (imageio-ffmpeg's bundled
binary, H.264, yuv420p) while the next one renders.

OpenGL: MuJoCo chooses its backend from ``MUJOCO_GL`` when it is imported.
Where that is unset on a Linux machine with no display, its default (GLFW)
needs a window system, so the renderer is opened on EGL instead (GPU drivers,
or Mesa's software rasterizer on a CPU machine); set ``MUJOCO_GL`` (``egl``,
``osmesa``, ``glfw``) to choose yourself.
"""

from __future__ import annotations

import contextlib
import copy
import math
import os
import pathlib
import sys
import uuid
import warnings
from typing import Sequence

import mujoco
import numpy as np

from mwbx.errors import MwbxError
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


@contextlib.contextmanager
def _gl_backend():
  """Opens renderers on EGL where MuJoCo's default backend needs a display
  (see the module docstring); else leaves MuJoCo's choice alone."""
  if not _headless():
    yield
    return
  # The module whose GLContext mujoco.Renderer opens (mujoco.rendering.classic.gl_context in 4.x).
  gl_context = sys.modules[mujoco.Renderer.__module__].gl_context
  try:
    from mujoco.egl import GLContext  # lazy: loads libEGL, only for headless rendering
  except (ImportError, OSError, AttributeError) as err:
    raise MwbxError(f"render_video: no display and EGL cannot load ({err}); {_GL_HELP}") from None
  saved = gl_context.GLContext
  gl_context.GLContext = GLContext
  try:
    yield
  finally:
    gl_context.GLContext = saved


def open_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
  """A ``mujoco.Renderer`` of ``width`` x ``height`` pixels for ``model`` (whose
  offscreen buffer must be at least that large); MwbxError if OpenGL fails."""
  try:
    with _gl_backend():
      return mujoco.Renderer(model, height, width)
  except MwbxError:
    raise
  except Exception as err:  # noqa: BLE001 (GL failures come as many types)
    backend = os.environ.get("MUJOCO_GL") or ("egl" if _headless() else "glfw")
    raise MwbxError(f"render_video: cannot open an OpenGL context (MUJOCO_GL={backend}: "
                    f"{str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__}); "
                    f"{_GL_HELP}") from None


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
  distance = float(np.linalg.norm(offset))
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


def _check_size(width: int, height: int) -> None:
  for name, value in (("width", width), ("height", height)):
    if not isinstance(value, (int, np.integer)) or value < 2 or value % 2:
      raise MwbxError(f"{name}: must be an even number of pixels >= 2 (H.264, yuv420p), got {value!r}")


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
    path: the ``.mp4`` file; replaced whole or not at all.
    camera: an MJCF camera name to render from.
    look_at: ``(eye, target)``, two 3-vectors in metres: a free camera at eye
      looking at target (world +z up, the model's ``visual/global/fovy``).
      Neither given: the viewer's first view of this world (its MJCF scene
      camera's direction, else obliquely from the front right, fitted to
      what moves).
    width, height: pixels, even.
    fps: frames per second of the video.
    start, stop: time span, s (default: the whole recording).
    progress: optional callback taking :class:`mwbx.progress.Progress`
      (phase ``rendering video``, ``done`` the fraction of the world rendered).

  Returns:
    the path written.

  Raises:
    MwbxError: naming the world, camera, size, span or file at fault, saying
      to install imageio-ffmpeg, or that OpenGL cannot open (and what to set).

  Example:
    >>> render_video(bank, 3, "world3.mp4", camera="front")           # 1280x720, 30 fps
    >>> render_video(bank, 3, "top.mp4", look_at=((0, 0, 3), (0, 0, 0.5)), width=640, height=480)
  """
  imageio_ffmpeg = _ffmpeg()
  _check_size(width, height)
  path = pathlib.Path(path)
  poses = world_poses(bank, world, fps=fps, start=start, stop=stop)
  model = copy.copy(bank.model())  # the renderer's own: buffer size, fovy and hidden groups change
  model.vis.global_.offwidth = max(int(width), model.vis.global_.offwidth)
  model.vis.global_.offheight = max(int(height), model.vis.global_.offheight)
  cam = _camera(bank, int(world), model, camera, look_at, width / height)
  tmp = path.parent / f".{path.stem}.tmp-{uuid.uuid4().hex[:12]}{path.suffix or '.mp4'}"
  try:
    path.parent.mkdir(parents=True, exist_ok=True)
  except OSError as err:
    raise MwbxError(f"{path}: cannot write video ({why(err)})") from None
  renderer = open_renderer(model, int(width), int(height))
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
    os.replace(tmp, path)
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
      remove_quietly(tmp)
    renderer.close()
  return path
