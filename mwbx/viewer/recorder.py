"""An offline meshcat window: records drawing commands, writes standalone HTML.

`meshcat.Visualizer(window=SceneRecorder())` accepts the same calls as a live
visualizer but needs no server process: commands are kept in a scene tree
exactly as `meshcat.servers.zmqserver` keeps them, and `static_html()` packs
the tree and meshcat's JavaScript into one self-contained page (the same page
the server's `get_scene` produces).
"""

from __future__ import annotations

import base64
import os

import meshcat.servers.tree as mtree
import umsgpack

# meshcat's bundled three.js viewer (a few MB); read once per process.
_VIEWER_JS = os.path.join(os.path.dirname(mtree.__file__), "..", "viewer", "dist", "main.min.js")
_viewer_js_cache: list[str] = []

_PAGE = """<!DOCTYPE html>
<html>
  <head> <meta charset=utf-8> <title>{title}</title> </head>
  <body>
    <div id="meshcat-pane"></div>
    <script>
{viewer_js}
    </script>
    <script>
      var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
      var mwbx_commands = [
{commands}
      ];
      // Replay in order, then signal that the scene is complete.
      window.mwbx_ready = mwbx_commands.reduce(
        (prev, b64) => prev.then(() => fetch("data:application/octet-binary;base64," + b64)
          .then(res => res.arrayBuffer())
          .then(buf => viewer.handle_command_bytearray(new Uint8Array(buf)))),
        Promise.resolve()).then(() => {{ {after_load} window.mwbx_loaded = true; }});
    </script>
    <style>
      body {{ margin: 0; }}
      #meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
    </style>
  </body>
</html>
"""


def _viewer_js() -> str:
  if not _viewer_js_cache:
    with open(_VIEWER_JS, encoding="utf-8") as f:
      _viewer_js_cache.append(f.read())
  return _viewer_js_cache[0]


class SceneRecorder:
  """Duck-types `meshcat.visualizer.ViewerWindow` for drawing and `static_html`.

  after_load: JavaScript run once every command has been applied (e.g. to aim
  the orbit controls); `viewer` is the `MeshCat.Viewer`.
  """

  server_proc = None
  zmq_url = None
  web_url = None

  def __init__(self, title: str = "mwbx"):
    self.tree = mtree.SceneTree()
    self.title = title
    self.after_load: list[str] = []

  def send(self, command) -> None:
    data = command.lower()
    packed = umsgpack.packb(data)
    cmd = data["type"]
    path = [p for p in data["path"].split("/") if p]
    if cmd == "delete":
      if path:
        parent = mtree.find_node(self.tree, path[:-1])
        parent.pop(path[-1], None)
      else:
        self.tree = mtree.SceneTree()
      return
    node = mtree.find_node(self.tree, path)
    if cmd == "set_transform":
      node.transform = packed
    elif cmd == "set_object":
      node.object = packed
      node.properties = []
    elif cmd == "set_property":
      node.properties.append(packed)
    elif cmd == "set_animation":
      node.animation = packed
    else:
      raise ValueError(f"meshcat command {cmd!r} cannot be recorded")

  def command_blobs(self) -> list[bytes]:
    """The recorded msgpack commands in the order the server would replay
    them (tree walk: object, properties, transform, animation per node)."""
    blobs = []
    animations = []
    for node in mtree.walk(self.tree):
      if node.object is not None:
        blobs.append(node.object)
      blobs.extend(node.properties)
      if node.transform is not None:
        blobs.append(node.transform)
      if node.animation is not None:
        animations.append(node.animation)
    # Animations last: their targets must exist when the clips bind to them.
    return blobs + animations

  def get_scene(self) -> str:
    """One self-contained HTML page showing the recorded scene."""
    commands = ",\n".join(f'"{base64.b64encode(b).decode("ascii")}"' for b in self.command_blobs())
    return _PAGE.format(title=self.title, viewer_js=_viewer_js(), commands=commands,
                        after_load="\n".join(self.after_load))

  def get_image(self):
    raise NotImplementedError("an offline scene has no browser to capture from; "
                              "render its static_html() in a browser instead")
