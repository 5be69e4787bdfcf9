"""The meshcat server process of a live view, tied to its parent's life.

meshcat starts its server in a new session, so it outlives a parent killed by
a signal (and keeps its port). Here the server is started the same way but
asks the kernel (Linux ``PR_SET_PDEATHSIG``) to be sent SIGTERM when its
parent dies, and :class:`LiveView` stops it on ``close()``, on exit from a
``with`` block, and at interpreter exit.

meshcat's own server listens for browsers on every interface (while printing
a 127.0.0.1 URL); this one serves on loopback only (``_SERVE``), and its URL
is the one it really bound (meshcat moves on to the next port when 7000 is
busy, and says so). Tornado refuses websockets from other origins.
"""

from __future__ import annotations

import atexit
import ctypes
import os
import signal
import subprocess
import sys

import meshcat
from meshcat.servers.zmqserver import match_web_url, match_zmq_url

from mwbx.viewer.errors import ViewerError

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
LOOPBACK = "127.0.0.1"
# meshcat's server entry point with its web server bound to loopback (its
# ZMQ socket already is): the app's listen() gets the address meshcat leaves out.
_SERVE = f"""
from meshcat.servers import zmqserver

class LoopbackBridge(zmqserver.ZMQWebSocketBridge):
  def make_app(self):
    app = super().make_app()
    listen = app.listen
    app.listen = lambda port, **kwargs: listen(port, address={LOOPBACK!r}, **kwargs)
    return app

zmqserver.ZMQWebSocketBridge = LoopbackBridge
zmqserver.main()
"""


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
  try:
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
  except OSError:
    pass  # not Linux: close() and atexit still stop the server


def start_server() -> tuple[subprocess.Popen, str, str]:
  """(process, zmq url, web url) of a new meshcat server that dies with this process."""
  env = dict(os.environ)
  env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.dirname(meshcat.__file__)))
  proc = subprocess.Popen([sys.executable, "-u", "-c", _SERVE],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                          start_new_session=True, preexec_fn=_die_with_parent)
  line = ""
  while "zmq_url" not in line:
    line = proc.stdout.readline().strip().decode("utf-8", "replace")
    if proc.poll() is not None:
      err = proc.stderr.read().decode("utf-8", "replace").strip().splitlines()
      raise ViewerError(f"the meshcat server exited with code {proc.returncode}"
                        f"{': ' + err[-1] if err else ''}")
  zmq_url = match_zmq_url(line)
  web_url = match_web_url(proc.stdout.readline().strip().decode("utf-8", "replace"))
  atexit.register(_stop, proc)
  return proc, zmq_url, web_url


def _stop(proc: subprocess.Popen | None) -> None:
  if proc is not None and proc.poll() is None:
    proc.terminate()
    try:
      proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
      proc.kill()
      proc.wait()


class LiveView(meshcat.Visualizer):
  """A meshcat visualizer whose server (when it started one) stops with it.

  Example::

    with mwbx.view(bank, worlds=[3]) as vis:
      print(vis.url())
      input("press enter to stop")
  """

  def __init__(self, zmq_url: str | None = None):
    proc = None
    if zmq_url is None:
      proc, zmq_url, _ = start_server()
    super().__init__(zmq_url=zmq_url)
    self.window.server_proc = proc

  @property
  def server_proc(self) -> subprocess.Popen | None:
    """The server process this view started (None: drawn into another's)."""
    return self.window.server_proc

  def wait(self) -> None:
    """Blocks until the server exits (or Ctrl-C)."""
    if self.server_proc is not None:
      self.server_proc.wait()

  def close(self) -> None:
    """Stops the server this view started; idempotent."""
    _stop(self.server_proc)

  def __enter__(self) -> "LiveView":
    return self

  def __exit__(self, *exc) -> None:
    self.close()
