"""The browsing page: a viser server showing a bank, its paths and queries.

Draw a box in the 3-D view (``Draw include box`` / ``Draw exclude box``, then
drag): it becomes a frustum query through the camera you are looking
through, and the counts, the path colours and the sorter update at once.
Click a sorter row to play that world back; refine it from the current time
or from the first entry of the last box; step back to its parent; save the
queries as a query file and the bank as a new shard.

Every query the page adds is also printed on stdout with its screen box and
camera, so what the page computed can be checked from outside.

Only a client holding the URL's token gets the page (:mod:`mwbx.browser.guard`);
query files stay under the session's directory; refinements are limited and
run one at a time (:class:`~mwbx.browser.session.Session`).
"""

from __future__ import annotations

import pathlib
import socket
import sys
import threading
import time

import mujoco
import numpy as np

from mwbx import queries as mq
from mwbx.browser.guard import Guard, resolve_host, serve_guarded
from mwbx.browser.session import MAX_REFINE_SAMPLES, REDUCTIONS, Session
from mwbx.errors import MwbxError
from mwbx.viewer import geometry as vgeom
from mwbx.viewer import triangles
from mwbx.viewer.kinematics import body_trajectories

# Each group of paths (faint, matching, excluded) draws at most this many
# segments: an evenly spaced subset of its worlds beyond it, with a count shown.
MAX_PATH_SEGMENTS = 60_000
FAINT_RGB = (185, 185, 185)
EXCLUDE_RGB = (220, 40, 40)
QUERY_RGB = {"include": (40, 200, 60), "exclude": (220, 40, 40)}
ALL_BODIES = "(every tracked body)"
# Worlds played at once (overlaid), and the opacity of all but the first.
MAX_PLAYED = 4
GHOST_OPACITY = 0.45
FIRST_ENTRY = "first entry of the last box"
CURRENT_TIME = "current time"


def free_port(host: str = "127.0.0.1") -> int:
  """A TCP port nothing listens on now (the OS picks it)."""
  with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
    s.bind((host, 0))
    return int(s.getsockname()[1])


def _mesh(geometry) -> tuple[np.ndarray, np.ndarray]:
  """(f32[V, 3], i32[F, 3]) triangles of a meshcat geometry, in its own frame."""
  try:
    return triangles.triangles(geometry)
  except triangles.UnknownGeometry as err:
    raise MwbxError(f"browse: {err}") from None


def _pose(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
  """(wxyz, position) of a 4x4 transform."""
  quat = np.zeros(4)
  mujoco.mju_mat2Quat(quat, np.ascontiguousarray(matrix[:3, :3]).reshape(-1))
  return quat, np.asarray(matrix[:3, 3], np.float64)


def _rgb(rgba) -> tuple[int, int, int]:
  return tuple(int(round(255 * float(c))) for c in rgba[:3])


def camera_from_client(camera) -> mq.Camera:
  """The mwbx camera of a viser client camera (OpenCV axes: x right, y down, z forward)."""
  rot = np.zeros(9)
  mujoco.mju_quat2Mat(rot, np.asarray(camera.wxyz, np.float64))
  rot = rot.reshape(3, 3)
  return mq.Camera(eye=np.asarray(camera.position, np.float64), right=rot[:, 0], up=-rot[:, 1],
                   forward=rot[:, 2], fovy=float(np.degrees(camera.fov)), aspect=float(camera.aspect))


class Browser:
  """A viser page over a :class:`~mwbx.browser.session.Session`.

  Args:
    session: what is browsed.
    host, port: where the page is served (port None: a free one; a busy one:
      the next free one, see ``port`` and ``requested_port``).

  Attributes:
    url: the page's address with its token (what to open).
    loopback: whether ``host`` is reachable from this machine only.
  """

  def __init__(self, session: Session, host: str = "127.0.0.1", port: int | None = None):
    import viser
    self.session = session
    self.loopback = resolve_host(host)
    self.guard = Guard()
    self.requested_port = free_port(host) if port is None else int(port)
    self.server = serve_guarded(
        lambda: viser.ViserServer(host=host, port=self.requested_port, label="mwbx", verbose=False), self.guard)
    self.port = int(self.server.get_port())  # viser moves on to the next port when this one is busy
    self.host = host
    self.model = session.bank.model()
    self.visuals = vgeom.scene_visuals(self.model)
    self.playing_world: int | None = None
    self.frame = 0
    self._stop = threading.Event()
    self.played: dict = {}  # world id -> (body ids, pos, quat, body nodes), in play order
    self._handles: dict = {}
    self._build_scene()
    self._build_gui()
    self.refresh()
    self._player = threading.Thread(target=self._play_loop, daemon=True, name="mwbx-playback")
    self._player.start()

  @property
  def url(self) -> str:
    host = f"[{self.host}]" if ":" in self.host else self.host
    return f"http://{host}:{self.port}/?token={self.guard.token}"

  # -- scene ------------------------------------------------------------------------------

  def _build_scene(self) -> None:
    scene = self.server.scene
    scene.set_up_direction("+z")
    self._frame_view()
    self.moving = {}  # body id -> [(name, vertices, faces, rgb, wxyz, position)] of its geoms
    for v in self.visuals:
      verts, faces = _mesh(v.geometry)
      wxyz, pos = _pose(v.local)
      if v.static:
        scene.add_mesh_simple(f"/scene/{v.name}", verts, faces, color=_rgb(v.rgba), wxyz=wxyz, position=pos,
                              opacity=None if v.rgba.a >= 1 else float(v.rgba.a))
      else:
        self.moving.setdefault(int(v.body_id), []).append((v.name, verts, faces, _rgb(v.rgba), wxyz, pos))
    # Colour per body: the colour of its first geom (a path of the ball is the ball's colour).
    bank = self.session.bank
    colour = {}
    for v in self.visuals:
      colour.setdefault(int(v.body_id), _rgb(v.rgba))
    self.body_rgb = np.array([colour.get(int(b), (60, 160, 60)) for b in bank.body_ids], np.uint8)

  def _frame_view(self) -> None:
    """Initial camera: from outside every body's paths in the valid worlds
    (widened by the largest moving geom), along the model's first fixed scene
    camera (never one riding on or tracking a body), else from the front right."""
    from mwbx.viewer import framing
    bank = self.session.bank
    rows = np.flatnonzero(np.asarray(bank.valid, bool))
    if not rows.size:
      return
    lo, hi = framing.scene_bounds(bank, self.model, rows, None, None)
    spec = framing.view_spec(self.model, None, None)
    fov = float(self.server.initial_camera.fov)  # radians
    centre, eye = framing.frame_box(lo, hi, spec._replace(fovy=float(np.degrees(fov))))
    self.server.initial_camera.look_at = centre
    self.server.initial_camera.position = eye

  def _paths(self, bodies: np.ndarray, match: np.ndarray, exclude: np.ndarray) -> dict:
    """Draws the selected bodies' paths: faint, per-body colour where all queries
    hold, red where an exclude box rejects. Each group draws at most
    MAX_PATH_SEGMENTS segments (an evenly spaced subset of its worlds);
    returns {group: worlds left out}."""
    bank = self.session.bank
    com, count = np.asarray(bank.com), np.asarray(bank.com_count)
    valid = np.asarray(bank.valid, bool)
    groups = {"faint": valid & ~match & ~exclude, "match": valid & match, "exclude": valid & exclude}
    if self.only_matches.value:
      groups["faint"] = groups["exclude"] = np.zeros_like(valid)
    per_world = max(1, (com.shape[1] - 1) * bodies.size)
    cap = max(1, MAX_PATH_SEGMENTS // per_world)
    left_out = {}
    for name, mask in groups.items():
      rows = np.flatnonzero(mask)
      left_out[name] = max(0, rows.size - cap)
      if left_out[name]:
        rows = rows[np.linspace(0, rows.size - 1, cap).astype(np.int64)]
      old = self._handles.pop(f"paths/{name}", None)
      if old is not None:
        old.remove()
      if not rows.size or com.shape[1] < 2:
        continue
      pts = com[rows][:, :, bodies]  # [n, P, k, 3]
      seg = np.stack([pts[:, :-1], pts[:, 1:]], axis=-2)  # [n, P-1, k, 2, 3]
      keep = np.arange(com.shape[1] - 1)[None, :] < (count[rows] - 1)[:, None]  # recorded segments only
      seg = seg[keep]  # [m, k, 2, 3]
      if name == "match":
        rgb = np.broadcast_to(self.body_rgb[bodies][None, :, None, :], seg.shape)
      else:
        rgb = np.broadcast_to(np.asarray(FAINT_RGB if name == "faint" else EXCLUDE_RGB, np.uint8), seg.shape)
      if seg.size:
        self._handles[f"paths/{name}"] = self.server.scene.add_line_segments(
            f"/paths/{name}", seg.reshape(-1, 2, 3).astype(np.float32),
            np.ascontiguousarray(rgb, np.uint8).reshape(-1, 2, 3),
            thickness=2.0 if name != "faint" else 1.0, thickness_units="screen")
    return left_out

  def _frustums(self) -> None:
    scene = self.server.scene
    for key in [k for k in self._handles if k.startswith("queries/")]:
      self._handles.pop(key).remove()
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    for i, entry in enumerate(self.session.entries):
      q = entry.query
      corners = None if q.frustum is None else q.frustum.corners  # joint queries draw nothing
      if corners is None or not entry.enabled:
        continue
      seg = np.array([[corners[a], corners[b]] for a, b in edges], np.float32)
      colours = np.broadcast_to(np.asarray(QUERY_RGB[q.sign], np.uint8), seg.shape).copy()
      self._handles[f"queries/q{i}"] = scene.add_line_segments(f"/queries/q{i}", seg, colours, thickness=2.0,
                                                               thickness_units="screen")

  # -- GUI --------------------------------------------------------------------------------

  def _build_gui(self) -> None:
    gui = self.server.gui
    bank = self.session.bank
    names = [ALL_BODIES] + list(bank.groups) + list(bank.objects) + [
        f"body:{b}" for b in bank.body_names if b not in bank.objects]
    end = float((int(bank.frame_count.max()) - 1) / bank.record_fps) if bank.n_worlds else 1.0
    self.end_time = end
    with gui.add_folder("Queries"):
      self.counts_md = gui.add_markdown("")
      self.bodies = gui.add_dropdown("Bodies", names, initial_value=ALL_BODIES)
      self.mode = gui.add_dropdown("Mode", ("any", "all"), initial_value="any")
      self.only_matches = gui.add_checkbox("Only matching paths", False)
      self.only_matches.on_update(lambda _: self.refresh())
      self.bodies.on_update(lambda _: self.refresh())
      self.window = gui.add_multi_slider("Time window (s)", 0.0, max(end, 1e-3), max(end, 1e-3) / 100,
                                         (0.0, max(end, 1e-3)))
      include = gui.add_button("Draw include box")
      exclude = gui.add_button("Draw exclude box")
      include.on_click(lambda event: self._arm_box("include", event.client))
      exclude.on_click(lambda event: self._arm_box("exclude", event.client))
      self.query_pick = gui.add_dropdown("Query", ("(none)",), initial_value="(none)")
      toggle = gui.add_button("Toggle query")
      remove = gui.add_button("Remove query")
      toggle.on_click(lambda _: self._with_pick(self.session.toggle))
      remove.on_click(lambda _: self._with_pick(self.session.remove))
      undo = gui.add_button("Undo")
      redo = gui.add_button("Redo")
      undo.on_click(lambda _: self.session.undo() and self.refresh())
      redo.on_click(lambda _: self.session.redo() and self.refresh())
      self.query_file = gui.add_text("Query file", "queries.yaml",
                                     hint=f"a .yaml file under {self.session.query_dir}")
      save_q = gui.add_button("Save queries")
      open_q = gui.add_button("Open queries")
      save_q.on_click(lambda _: self._report(lambda: f"saved {self.session.save_queries(self.query_file.value)}"))
      open_q.on_click(lambda _: self._report(lambda: self.session.open_queries(self.query_file.value)
                                             or f"opened {self.query_file.value.strip()}"))
    with gui.add_folder("Sorter"):
      self.metric = gui.add_dropdown("Metric", tuple(bank.metric_names) + (mq.metrics.CONSTRAINTS,),
                                     initial_value=bank.metric_names[0])
      self.reduce = gui.add_dropdown("Over bodies", REDUCTIONS, initial_value="sum")
      self.metric.on_update(lambda _: self._sorter())
      self.reduce.on_update(lambda _: self._sorter())
      self.sorter_md = gui.add_markdown("")
      self.compare = gui.add_checkbox("Add to the playing worlds", False,
                                      hint=f"overlay up to {MAX_PLAYED} worlds, each labelled with its id")
      self.sorter = gui.add_folder("Worlds (click to play)")
      self.row_buttons: list = []
    with gui.add_folder("Playback"):
      self.playing_md = gui.add_markdown("no world playing")
      self.paused = gui.add_checkbox("Pause", False)
      self.time_slider = gui.add_slider("Time (s)", 0.0, max(end, 1e-3), 1.0 / bank.record_fps, 0.0)
      self.time_slider.on_update(lambda _: self._seek())
    with gui.add_folder("Refine"):
      self.objects = gui.add_dropdown("Objects", tuple(bank.objects) + tuple(bank.groups),
                                      initial_value=next(iter(bank.objects)))
      self.start = gui.add_dropdown("From", (CURRENT_TIME, FIRST_ENTRY), initial_value=CURRENT_TIME)
      self.samples = gui.add_number("Samples", 16, min=1, max=MAX_REFINE_SAMPLES, step=1,
                                    hint=f"1 to {MAX_REFINE_SAMPLES}")
      refine = gui.add_button("Refine playing world")
      refine.on_click(lambda _: self._refine())
      cancel = gui.add_button("Cancel refinement")
      cancel.on_click(lambda _: self._cancel())
      self.progress = gui.add_progress_bar(0.0, visible=False)
      parent = gui.add_button("Go to parent")
      parent.on_click(lambda _: self._parent())
      save = gui.add_button("Save bank")
      save.on_click(lambda _: self._report(lambda: f"saved {self.session.save()}"))
      self.status_md = gui.add_markdown("")

  def _report(self, action) -> None:
    try:
      message = action()
      self.refresh()
    except MwbxError as err:
      message = f"error: {err}"
    self.status_md.content = f"{message}"
    print(f"mwbx browse: {message}", flush=True)

  def _with_pick(self, action) -> None:
    label = self.query_pick.value
    if label.startswith("q"):
      self._report(lambda: action(int(label[1:].split(" ")[0])) or f"{label}: done")

  def _arm_box(self, sign: str, client) -> None:
    scene = self.server.scene

    @scene.on_rect_select()
    def _(event):
      scene.remove_rect_select_callback(_)
      self._add_box(sign, event)

    self.status_md.content = f"drag a box in the view for an {sign} query"

  def _add_box(self, sign: str, event) -> None:
    camera = camera_from_client(event.client.camera)
    box = mq.ScreenBox.from_corners(event.screen_min, event.screen_max)
    bodies = None if self.bodies.value == ALL_BODIES else (self.bodies.value,)
    lo, hi = self.window.value
    window = None if (lo <= 0.0 and hi >= self.end_time) else (float(lo), float(hi))
    try:
      query = mq.Query.screen(camera, box, sign=sign, bodies=bodies, mode=self.mode.value, window=window,
                              name=f"q{len(self.session.entries)}")
      index = self.session.add(query)
    except MwbxError as err:
      self.status_md.content = f"error: {err}"
      return
    self.refresh()
    count = self.session.counts()
    self.status_md.content = f"q{index}: {count.per_query[index]} worlds"
    print(f"mwbx browse: query {index} {sign} box={[box.u0, box.v0, box.u1, box.v1]}"
          f" bodies={list(bodies) if bodies else None} mode={self.mode.value} window={window}"
          f" camera eye={camera.eye.tolist()} right={camera.right.tolist()} up={camera.up.tolist()}"
          f" forward={camera.forward.tolist()} fovy={camera.fovy} aspect={camera.aspect}"
          f" -> {count.per_query[index]} worlds, all queries {count.all} of {count.valid}", flush=True)

  # -- refresh ----------------------------------------------------------------------------

  def refresh(self) -> None:
    session = self.session
    bank = session.bank
    counts = session.counts()
    each = session._each()
    exclude = np.zeros(bank.n_worlds, bool)
    for i, e in enumerate(session.entries):
      if e.enabled and not e.query.include:
        exclude |= ~each[:, i]
    match = session.match() if session.entries else np.zeros(bank.n_worlds, bool)
    bodies = (np.arange(len(bank.body_names)) if self.bodies.value == ALL_BODIES
              else np.asarray(bank.select_bodies(self.bodies.value)))
    left_out = self._paths(bodies, match & ~exclude, exclude & np.asarray(bank.valid))
    self._frustums()
    self._counts_text(counts, left_out)
    self._sorter(counts)

  def _counts_text(self, counts, left_out: dict) -> None:
    session = self.session
    lines = [f"**{counts.all} of {counts.valid} worlds** satisfy all queries"]
    for i, (e, n) in enumerate(zip(session.entries, counts.per_query)):
      q = e.query
      state = "" if e.enabled else " (off)"
      what = f"joint {q.joint} turns {q.turn}" if q.frustum is None else \
          f"{q.sign} {','.join(q.bodies) if q.bodies else 'any body'}"
      lines.append(f"- q{i} {what}: {n}{state}")
    hidden = [f"{n} {name}" for name, n in left_out.items() if n]
    if hidden:
      lines.append(f"(paths not drawn: {', '.join(hidden)} worlds)")
    self.counts_md.content = "\n".join(lines)
    labels = tuple(f"q{i} {e.query.sign}{'' if e.enabled else ' (off)'}" for i, e in enumerate(session.entries))
    self.query_pick.options = labels or ("(none)",)

  def _sorter(self, counts=None) -> None:
    session = self.session
    counts = session.counts() if counts is None else counts
    bodies = None if self.bodies.value == ALL_BODIES else [self.bodies.value]
    rows = session.sorted_rows(self.metric.value, self.reduce.value, bodies=bodies)
    closest = not counts.all and session.entries
    over = "every tracked body" if bodies is None else bodies[0]
    self.sorter_md.content = (f"{'closest worlds: ' if closest else ''}world · queries satisfied · "
                              f"{self.metric.value}:{self.reduce.value} over {over} · parent")
    for button in self.row_buttons:
      button.remove()
    self.row_buttons = []
    with self.sorter:
      for r in rows:
        label = (f"world {r.world} · {r.satisfied} · {r.value:.4g}"
                 + ("" if r.parent < 0 else f" · from {r.parent}"))
        button = self.server.gui.add_button(label)
        button.on_click(lambda _, world=r.world: self.play(world, add=self.compare.value))
        self.row_buttons.append(button)

  # -- playback ---------------------------------------------------------------------------

  def play(self, world: int, add: bool = False) -> None:
    """Plays world ``world`` back in the scene (decoded from the codec); with
    ``add`` next to the ones playing (overlaid, translucent, each labelled),
    at most MAX_PLAYED worlds."""
    bank = self.session.bank
    world = int(world)
    if not add:
      for w in list(self.played):
        self._unplay(w)
    elif world in self.played:
      return
    elif len(self.played) >= MAX_PLAYED:
      self._unplay(next(iter(self.played)))
    qpos = bank.qpos_frames(world).astype(np.float64)
    body_ids = np.array(sorted(self.moving), np.int64)
    pos, quat = body_trajectories(self.model, qpos, body_ids)
    ghost = bool(self.played)
    scene = self.server.scene
    nodes = {}
    for body in body_ids:
      node = scene.add_frame(f"/play/w{world}/b{body}", show_axes=False)
      for name, verts, faces, rgb, wxyz, position in self.moving[int(body)]:
        scene.add_mesh_simple(f"/play/w{world}/b{body}/{name}", verts, faces, color=rgb, wxyz=wxyz,
                              position=position, opacity=GHOST_OPACITY if ghost else None)
      nodes[int(body)] = node
    if body_ids.size:  # the label rides on the world's first body
      scene.add_label(f"/play/w{world}/b{body_ids[0]}/label", f"world {world}")
    self.played[world] = (body_ids, pos, quat, nodes)
    self.playing_world = world
    if not add:
      self.frame = 0
    parent = self.session.parent(world)
    shown = ", ".join(f"world {w}" for w in self.played)
    self.playing_md.content = (f"playing **{shown}**" + (f" (world {world} refined from {parent})"
                                                         if parent is not None else ""))
    print(f"mwbx browse: playing world {world}" + (" (added)" if add else ""), flush=True)

  def _unplay(self, world: int) -> None:
    self.server.scene.remove_by_name(f"/play/w{world}")
    del self.played[world]

  def _show_frame(self) -> None:
    with self.server.atomic():
      for body_ids, pos, quat, nodes in list(self.played.values()):
        f = min(self.frame, pos.shape[0] - 1)
        for k, b in enumerate(body_ids):
          nodes[int(b)].position = pos[f, k]
          nodes[int(b)].wxyz = quat[f, k]

  def _seek(self) -> None:
    if self.played:
      self.frame = int(round(self.time_slider.value * self.session.bank.record_fps))
      self._show_frame()

  def _play_loop(self) -> None:
    while not self._stop.is_set():
      if self.played and not self.paused.value:
        self._show_frame()
        longest = max(p[1].shape[0] for p in list(self.played.values()))
        self.frame = (self.frame + 1) % longest
      time.sleep(1.0 / self.session.bank.record_fps)

  # -- refinement ---------------------------------------------------------------------------

  def _refine(self) -> None:
    world = self.playing_world
    if world is None:
      self.status_md.content = "play a world first (the one to refine)"
      return
    objects = self.objects.value
    try:
      t_min = (self.session.first_entry_of_last_box(world, [objects]) if self.start.value == FIRST_ENTRY
               else self.frame / self.session.bank.record_fps)
    except MwbxError as err:
      self.status_md.content = f"error: {err}"
      return
    n = self.samples.value  # any number a client sends: the session checks it
    try:
      n = int(n) if float(n) == int(n) else n
    except (TypeError, ValueError, OverflowError):
      pass
    try:
      job = self.session.refine(world, objects, t_min=t_min, n_samples=n)
    except MwbxError as err:
      self._say(f"error: {err}")
      return
    self.progress.visible = True
    print(f"mwbx browse: refining {objects} of world {world} from {t_min:.4f} s, {n} samples", flush=True)

    def watch():
      while not job.done.wait(0.1):
        if job.progress is not None:
          self.progress.value = 100.0 * job.progress.done / max(1, job.progress.total)
      self.progress.visible = False
      if job.cancelled:
        message = f"refinement of world {world} cancelled; nothing added"
      elif job.error:
        message = f"error: {job.error}"
      else:
        ids = job.new_ids
        message = f"refined world {world}: new worlds {int(ids[0])}..{int(ids[-1])} (parent {world})"
        self.refresh()
      self.status_md.content = message
      print(f"mwbx browse: {message}", flush=True)

    threading.Thread(target=watch, daemon=True, name="mwbx-refine-watch").start()

  def _cancel(self) -> None:
    job = self.session.cancel()
    self._say("no refinement is running" if job is None else f"cancelling the refinement of world {job.world}")

  def _say(self, message: str) -> None:
    self.status_md.content = message
    print(f"mwbx browse: {message}", flush=True)

  def _parent(self) -> None:
    if self.playing_world is None:
      return
    parent = self.session.parent(self.playing_world)
    if parent is None:
      self.status_md.content = f"world {self.playing_world} was sampled: it has no parent"
    else:
      self.play(parent)

  def leave(self, autosave: bool = False) -> list[str]:
    """What is left when the page goes away: a running refinement is
    cancelled, refined worlds not saved are saved (``autosave``) or named.
    Returns the lines to tell the user."""
    lines = []
    job = self.session.cancel()
    if job is not None:
      lines.append(f"the refinement of world {job.world} still running was cancelled")
      job.done.wait(timeout=60)
    unsaved = list(self.session.unsaved)
    if not unsaved:
      return lines
    span = f"{len(unsaved)} refined world{'s' if len(unsaved) > 1 else ''} (ids {unsaved[0]}..{unsaved[-1]})"
    if autosave and self.session.path is not None:
      try:
        lines.append(f"saved {span} to {self.session.save()}")
      except MwbxError as err:
        lines.append(f"could not save {span}: {err}")
    else:
      lines.append(f"{span} were not saved and are gone (Save bank on the page keeps them; --autosave saves"
                   " them on exit)")
    return lines

  def close(self) -> None:
    """Stops playback and the server."""
    self._stop.set()
    self.server.stop()


def browse(bank, *, path=None, host: str = "127.0.0.1", port: int | None = None,
           open_browser: bool = False, block: bool = True, workdir=None, autosave: bool = False) -> Browser:
  """Serves the browsing page for ``bank`` (``path``: its directory, for saving).

  Args:
    workdir: where the page's query files live (default: ``path``).
    autosave: on Ctrl-C, save the worlds refined on the page and not saved
      (else they are named as lost).

  Returns the :class:`Browser`; with ``block`` it serves until Ctrl-C and stops.

  Example::

    mwbx.browse(mwbx.Bank.load("out/quickstart"), path="out/quickstart")
  """
  path = None if path is None else pathlib.Path(path)
  session = Session(bank, path, None if workdir is None else pathlib.Path(workdir))
  page = Browser(session, host=host, port=port)
  if not page.loopback:
    print(f"mwbx: warning: --host {host} is not a loopback address: anyone who can reach port {page.port} there"
          " and holds the token can use the page (it runs refinements and writes query files under"
          f" {session.query_dir}); the token travels unencrypted", file=sys.stderr, flush=True)
  if page.port != page.requested_port:
    print(f"mwbx: port {page.requested_port} is busy; serving on port {page.port}", file=sys.stderr, flush=True)
  print(f"mwbx: browsing {bank.n_worlds} worlds at {page.url}", file=sys.stderr, flush=True)
  if open_browser:
    import webbrowser
    webbrowser.open(page.url)
  if block:
    try:
      while True:
        time.sleep(0.2)
    except KeyboardInterrupt:
      pass
    finally:
      for line in page.leave(autosave):
        print(f"mwbx: {line}", file=sys.stderr, flush=True)
      page.close()
  return page
