"""meshcat display of sampled worlds: geometry, playback, COM paths, query
frustums, and standalone HTML export."""

import warnings as _warnings

# meshcat imports pyzmq's deprecated ioloop module on import; nothing to act on.
with _warnings.catch_warnings():
  _warnings.simplefilter("ignore", DeprecationWarning)
  import meshcat as _meshcat  # noqa: F401

from mwbx.viewer.api import DrawInfo
from mwbx.viewer.api import draw
from mwbx.viewer.api import export_html
from mwbx.viewer.api import view
from mwbx.viewer.errors import ViewerError
from mwbx.viewer.display import DrawnVolume
from mwbx.viewer.recorder import SceneRecorder
from mwbx.viewer.select import choose_worlds
from mwbx.viewer.server import LiveView
