"""MuJoCo imported without ``MUJOCO_GL``: the variable is read when rendering.

``import mujoco`` reads ``MUJOCO_GL`` at once: a value it does not know
raises, and ``osmesa`` or ``egl`` load their OpenGL library there, so a bad
value or a missing library would fail every ``mwbx`` command (``--version``
included), though only an mp4 export renders. mwbx imports mujoco first
here, with the variable out of the environment, and puts it back:
:mod:`mwbx.export.video` reads it when it opens a renderer, and names it in
one line when it is wrong.

Where mujoco was imported before mwbx, it was imported as the user set it
and nothing changes. Where mwbx was imported first, ``mujoco.Renderer``
opened outside mwbx uses MuJoCo's platform default whatever ``MUJOCO_GL``
says; mwbx's own renderers (:func:`mwbx.export.video.open_renderer`) follow it.
"""

import os
import sys

if "mujoco" not in sys.modules:
  _MUJOCO_GL = os.environ.pop("MUJOCO_GL", None)
  try:
    import mujoco  # noqa: F401  (its GLFW default loads nothing until a context opens)
  finally:
    if _MUJOCO_GL is not None:
      os.environ["MUJOCO_GL"] = _MUJOCO_GL
