"""The browsing page: a viser server showing a bank, its paths and queries.

Draw a box in the 3-D view (``Draw include box`` / ``Draw exclude box``, then
drag): it becomes a frustum query through the camera you are looking
through, about the chosen bodies' centres of mass or, with *Whole geometry*,
any point of their geoms; *Upright at the end* and *Near its initial
orientation* add orientation queries. The counts, the path colours and the
sorter update at once. Click a sorter row to play that world back (overlaid
on others, or side by side); refine it from the current time or from the
first entry of the last box, adding or removing objects; step back to its
parent; save the queries as a query file and the bank as a new shard.

Every query the page adds is also printed on stdout with what defines it, so
what the page computed can be checked from outside.

Only a client holding the URL's token gets the page (:mod:`mwbx.browser.guard`);
query and scene files stay under the session's directory; refinements are
limited and run one at a time (:class:`~mwbx.browser.session.Session`). The
3-D scene is :mod:`mwbx.browser.scene`, playback :mod:`mwbx.browser.player`,
paths and volumes :mod:`mwbx.browser.drawing`; this module is the GUI.
"""

from __future__ import annotations

import logging
import math
import pathlib
import socket
import sys
import threading
import time

import mujoco
import numpy as np

from mwbx import queries as mq
from mwbx.browser import drawing, gui
from mwbx.browser.gui import ALL_BODIES, FIRST_ENTRY, MAX_PLAYED, NO_OBJECTS
from mwbx.browser.guard import Guard, resolve_host, serve_guarded
from mwbx.browser.player import Player
from mwbx.browser.scene import Stage
from mwbx.browser.session import HARDEST_HIT, ORIENTATION_ERROR, Session
from mwbx.errors import MwbxError
from mwbx.progress import NOTICE, notices_to_stderr
from mwbx.viewer import display, framing
from mwbx.viewer import flex as flex_lib
from mwbx.viewer.kinematics import body_trajectories
from mwbx.yaml_input import short_repr, short_repr_text

# The page's log: what each action did, one line each (``mwbx browse: ...`` on
# stdout once :func:`browse` serves; research code configures it as it likes).
LOG = logging.getLogger("mwbx.browse")
# What the person serving the page must see (its address, a busy port, an
# exposed host, refinements not saved) goes to NOTICE: ``mwbx: ...`` lines on stderr.


def log_to_stdout() -> None:
  """Sends the page's log to stdout as ``mwbx browse: ...`` lines (once)."""
  if not LOG.handlers:
    handler = logging.StreamHandler(sys.stdout)
    handler.setFormatter(logging.Formatter("mwbx browse: %(message)s"))
    LOG.addHandler(handler)
    LOG.setLevel(logging.INFO)
    LOG.propagate = False


def free_port(host: str = "127.0.0.1") -> int:
  """A TCP port nothing listens on now (the OS picks it)."""
  with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
    s.bind((host, 0))
    return int(s.getsockname()[1])


def camera_from_client(camera) -> mq.Camera:
  """The mwbx camera of a viser client camera (OpenCV axes: x right, y down, z forward)."""
  rot = np.zeros(9)
  mujoco.mju_quat2Mat(rot, np.asarray(camera.wxyz, np.float64))
  rot = rot.reshape(3, 3)
  return mq.Camera(eye=np.asarray(camera.position, np.float64), right=rot[:, 0], up=-rot[:, 1],
                   forward=rot[:, 2], fovy=float(np.degrees(camera.fov)), aspect=float(camera.aspect))


def _names(text: str) -> tuple[str, ...]:
  """'a, b c' -> ('a', 'b', 'c')."""
  return tuple(n for n in text.replace(",", " ").split() if n)


class Browser:
  """A viser page over a :class:`~mwbx.browser.session.Session`.

  Args:
    session: what is browsed.
    host, port: where the page is served (port None: a free one; a busy one:
      the next free one, see ``port`` and ``requested_port``).

  Attributes:
    url: the page's address with its token (what to open).
    loopback: whether ``host`` is reachable from this machine only.
    stage: the 3-D scene (:class:`~mwbx.browser.scene.Stage`).
    player: playback (:class:`~mwbx.browser.player.Player`).
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
    # One lock for what the GUI callbacks (viser's threads), the playback
    # thread and a refinement's watcher share: the played worlds and the frame
    # (the player's), the stage, the drawn paths and volumes, the playing world.
    self.lock = threading.RLock()
    self.playing_world: int | None = None
    self._handles: dict = {}
    self.server.scene.set_up_direction("+z")
    # Plain lighting: an environment map and shadow passes cost software
    # WebGL seconds per frame, so the page answered clicks seconds late.
    self.server.scene.configure_environment_map(None)
    self.server.scene.configure_default_lights(True, cast_shadow=False)
    self._build_stage()
    self._build_gui()
    self.player = Player(session, self.stage, paused=lambda: bool(self.ui.paused.value), lock=self.lock)
    self.refresh()

  @property
  def url(self) -> str:
    host = f"[{self.host}]" if ":" in self.host else self.host
    return f"http://{host}:{self.port}/?token={self.guard.token}"

  @property
  def visuals(self):
    return self.stage.visuals

  @property
  def moving(self) -> dict:
    return self.stage.moving

  @property
  def frame(self) -> int:
    return self.player.frame

  @property
  def path_segments(self) -> dict:
    """{path class: segments drawn now} (what the page redraws each frame)."""
    with self.lock:
      return {name.split("/", 1)[1]: drawing.segments_drawn(h) for name, h in self._handles.items()
              if name.startswith("paths/")}

  # -- scene ------------------------------------------------------------------------------

  def _build_stage(self) -> None:
    bank = self.session.bank
    self.model = bank.model
    rows = np.flatnonzero(np.asarray(bank.valid, bool))
    extent = (np.full(3, -0.5), np.full(3, 0.5))
    if rows.size:
      # Initial camera: from outside every body's paths in the valid worlds
      # (widened by the largest moving geom), along the model's first fixed
      # scene camera, else from the front right.
      lo, hi = framing.scene_bounds(bank, self.model, rows, None, None)
      extent = (lo, hi)
      spec = framing.view_spec(self.model, None, None)
      fov = float(self.server.initial_camera.fov)  # radians
      pose = display.camera_pose(lo, hi, spec._replace(fovy=float(np.degrees(fov))))
      self.server.initial_camera.look_at = pose.target
      self.server.initial_camera.position = pose.eye
    # Frustums are drawn as deep as the scene is wide, three times over (as in the viewer).
    diagonal = float(np.linalg.norm(extent[1] - extent[0]))
    self.frustum_depth = 3.0 * max(diagonal / 2, 0.2)
    self.path_simplifier = display.PathSimplifier(drawing.PATH_TOLERANCE * diagonal)
    self.stage = Stage(self.server, self.model, extent)
    if rows.size:  # the scene as its first valid world starts, dimmed, until a world plays
      qpos = bank.qpos_frames(int(bank.world_ids[rows[0]]))[:1].astype(np.float64)
      pos, quat = body_trajectories(self.model, qpos, self.stage.pose_ids)
      self.stage.show_start(pos[0], quat[0])

  def _scene_changed(self) -> None:
    """After a refinement moved the bank to a later scene version (new
    bodies): a new stage, and the new names in the pickers."""
    bank = self.session.bank
    if bank.model.nbody == self.model.nbody:
      return
    with self.lock:
      self.player.forget()
      self.stage.remove()
      self._build_stage()
      self.stage.set_side_by_side(self.ui.side_by_side.value)
      self.player.stage = self.stage
      self.playing_world = None
    names = self.body_names()
    self.ui.bodies.options = names
    self.ui.objects.options = tuple(bank.objects) + tuple(bank.groups) + (NO_OBJECTS,)
    with self.ui.several_folder:
      for name in names[1:]:
        if name not in self.ui.several:
          self.ui.several[name] = self.server.gui.add_checkbox(name, False)
          gui.wire(self, self.ui.several[name], lambda _: self.refresh())
    self.ui.playing_md.content = "no world playing (the scene changed)"

  # -- GUI --------------------------------------------------------------------------------

  def body_names(self) -> tuple[str, ...]:
    bank = self.session.bank
    return tuple([ALL_BODIES] + list(bank.groups) + list(bank.objects) + [
        f"body:{b}" for b in bank.body_names if b not in bank.objects])

  def _build_gui(self) -> None:
    self.ui = gui.build(self)

  def _selection(self) -> tuple[str, ...] | None:
    """The bodies queries are about: the ticked *Several bodies*, else the
    *Bodies* choice (None: every tracked body)."""
    ticked = tuple(name for name, box in self.ui.several.items() if box.value)
    if ticked:
      return ticked
    return None if self.ui.bodies.value == ALL_BODIES else (self.ui.bodies.value,)

  def report(self, action, what: str = "") -> None:
    """Runs ``action`` (which returns what to tell the user), redraws, and
    says what it returned, or why it failed (:meth:`guarded`)."""

    def run():
      message = action()
      self.refresh()
      self._say(message)

    self.guarded(run, what)

  def guarded(self, action, what: str = "") -> None:
    """Runs ``action`` for a page callback: whatever a client sent, a failure
    ends as one ``error:`` line in the status line, never as an exception in
    viser's thread (which left the page saying nothing, or something stale).

    Args:
      action: the callback's work (its return value is ignored).
      what: the widget that asked, for messages (``Refine playing world``).
    """
    try:
      action()
    except MwbxError as err:
      self._say(f"error: {err}")
    except Exception as err:  # noqa: BLE001 - any value a client sends lands here, not in a traceback
      where = f"{what}: " if what else ""
      self._say(f"error: {where}refused ({type(err).__name__}: {short_repr_text(str(err), 200)})",
                f"error: {where}{type(err).__name__}: {err}")
      LOG.debug("the refused callback", exc_info=True)

  def with_pick(self, action) -> None:
    label = str(self.ui.query_pick.value)
    if not label.startswith("q"):
      self._say("pick a query first")
      return
    try:
      index = int(label[1:].split(" ")[0])
    except ValueError:
      self._say(f"error: query: no query {short_repr(label, 80)}")
      return
    self.report(lambda: action(index) or f"{label}: done")

  def _window(self):
    lo, hi = self.ui.window.value
    return None if (lo <= 0.0 and hi >= self.ui.end_time) else (float(lo), float(hi))

  def arm_box(self, sign: str, client) -> None:
    scene = self.server.scene

    @scene.on_rect_select()
    def _(event):
      scene.remove_rect_select_callback(_)
      self.guarded(lambda: self._add_box(sign, event), f"{sign} box")

    self._say(f"drag a box in the view for an {sign} query")

  def _add_query(self, make, detail=None) -> None:
    """The one way a query enters from the page: ``make(name)`` builds it
    from the widgets and the client's event (every part of which is the
    client's: a NaN, a huge box or an unknown name is a MwbxError, one status
    line), the session adds it, the page redraws and says how many worlds it
    matches; ``detail(index, count)``: the log line (default: the status line)."""
    try:
      index = self.session.add(make(f"q{len(self.session.entries)}"))
    except MwbxError as err:
      self._say(f"error: {err}")
      return
    count = self.refresh()
    query = self.session.entries[index].query
    self._say(f"q{index} {query.describe()}: {count.per_query[index]} worlds",
              None if detail is None else detail(index, count))

  def _add_box(self, sign: str, event) -> None:
    got = {}

    def make(name):
      got["camera"] = camera_from_client(event.client.camera)
      got["box"] = mq.ScreenBox.from_corners(event.screen_min, event.screen_max)
      got["bodies"], got["window"] = self._selection(), self._window()
      got["shape"] = "geometry" if self.ui.geometry.value else "com"
      return mq.Query.screen(got["camera"], got["box"], sign=sign, bodies=got["bodies"], mode=self.ui.mode.value,
                             window=got["window"], name=name, shape=got["shape"])

    def detail(index, count):
      camera, box = got["camera"], got["box"]
      return (f"query {index} {sign} box={[box.u0, box.v0, box.u1, box.v1]}"
              f" bodies={_names_text(got['bodies'])} mode={self.ui.mode.value}"
              f" window={got['window']} camera eye={camera.eye.tolist()} right={camera.right.tolist()}"
              f" up={camera.up.tolist()} forward={camera.forward.tolist()} fovy={camera.fovy} aspect={camera.aspect}"
              f" -> {count.per_query[index]} worlds, all queries {count.all} of {count.valid} shape={got['shape']}")

    self._add_query(make, detail)

  def add_orientation(self, upright: bool) -> None:
    got = {}

    def make(name):
      got["bodies"], got["window"] = self._selection(), self._window()
      goal = dict(axis=self.ui.axis.value) if upright else dict(target="initial")
      got["query"] = mq.OrientationQuery(bodies=got["bodies"], within_deg=self.ui.within.value, window=got["window"],
                                         mode=self.ui.mode.value, name=name, **goal)
      return got["query"]

    def detail(index, count):
      what = f"upright axis={self.ui.axis.value}" if upright else "initial"
      return (f"query {index} orientation {what} within_deg={got['query'].within_deg}"
              f" bodies={_names_text(got['bodies'])} mode={self.ui.mode.value}"
              f" window={got['window']} -> {count.per_query[index]} worlds, all queries {count.all} of {count.valid}")

    self._add_query(make, detail)

  def add_touch(self, include: bool) -> None:
    a, b = self.ui.touch_a.value, self.ui.touch_b.value
    least = float(self.ui.touch_impulse.value or 0.0)
    impulse = (least, None) if least > 0 else None  # how hard: only touches delivering at least this
    self._add_query(lambda name: mq.TouchQuery(a, b, window=self._window(), sign="include" if include else "exclude",
                                               name=name, impulse=impulse))

  def export(self) -> None:
    world = self.playing_world
    if world is None:
      self._say("export: play a world first (click one in the sorter)")
      return
    self.report(lambda: f"world {world} written to {self.session.export(world, self.ui.export_file.value)}")

  # -- refresh ----------------------------------------------------------------------------

  def refresh(self):
    """Redraws paths, volumes, counts and the sorter from the session; returns the counts."""
    session = self.session
    bank = session.bank
    view = session.view()
    selection = self._selection()
    note = ""
    if selection is not None:
      bodies = np.asarray(bank.select_bodies(list(selection)))
    else:
      every = flex_lib.path_bodies(bank)  # one path per flex, not one per vertex
      bodies = drawing.most_moving(bank, every)
      if len(bodies) < len(every):
        names = ", ".join(bank.body_names[b] for b in bodies[:4]) + (", …" if len(bodies) > 4 else "")
        note = f"(paths of the {len(bodies)} of {len(every)} bodies that move most: {names})"
    with self.lock:
      left_out = drawing.draw_paths(self.server, self._handles, bank, bodies, view.match, view.rejected,
                                    self.ui.only_matches.value, simplify=self.path_simplifier)
      drawing.draw_frustums(self.server, self._handles, session.entries, self.frustum_depth)
      self._counts_text(view.counts, left_out, note)
      self.sorter(view.counts)
    return view.counts

  def _counts_text(self, counts, left_out: dict, note: str = "") -> None:
    session = self.session
    lines = [f"**{counts.all} of {counts.valid} worlds** satisfy all queries"]
    for i, (e, n) in enumerate(zip(session.entries, counts.per_query)):
      state = "" if e.enabled else " (off)"
      lines.append(f"- q{i} {e.query.describe()}: {n}{state}")
    hidden = [f"{n} {name}" for name, n in left_out.items() if n]
    if hidden:
      lines.append(f"(paths not drawn: {', '.join(hidden)} worlds)")
    if note:
      lines.append(note)
    self.ui.counts_md.content = "\n".join(lines)
    labels = tuple(f"q{i} {e.query.sign}{'' if e.enabled else ' (off)'}" for i, e in enumerate(session.entries))
    self.ui.query_pick.options = labels or ("(none)",)

  def sorter(self, counts=None) -> None:
    session = self.session
    counts = session.counts() if counts is None else counts
    selection = self._selection()
    bodies = None if selection is None else list(selection)
    try:
      rows = session.sorted_rows(self.ui.metric.value, self.ui.reduce.value, bodies=bodies)
    except MwbxError as err:
      self.ui.sorter_md.content = f"error: {err}"
      return
    closest = not counts.all and session.entries
    over = "every tracked body" if bodies is None else ", ".join(bodies)
    if self.ui.metric.value == ORIENTATION_ERROR:
      over = f"the bodies of {session.orientation_query().name or 'the last orientation query'} (rad, smallest first)"
    elif self.ui.metric.value == HARDEST_HIT:
      over = f"the sides of {session.touch_query().describe()} (N·s of normal impulse, hardest first)"
    self.ui.sorter_md.content = (f"{'closest worlds: ' if closest else ''}world · queries satisfied · "
                              f"{self.ui.metric.value}:{self.ui.reduce.value} over {over} · parent")
    with self.lock, self.ui.sorter:
      for button in self.ui.row_buttons:
        button.remove()
      self.ui.row_buttons = []
      for r in rows:
        label = (f"world {r.world} · {r.satisfied} · {r.value:.4g}"
                 + ("" if r.parent < 0 else f" · from {r.parent}"))
        button = self.server.gui.add_button(label)
        gui.wire(self, button, lambda _, world=r.world: self.play(world, add=self.ui.compare.value))
        self.ui.row_buttons.append(button)

  # -- playback ---------------------------------------------------------------------------

  def play(self, world: int, add: bool = False) -> None:
    """Plays world ``world`` back (decoded from the codec; its slot's meshes
    are on the page already, only poses move); with ``add`` besides the ones
    playing (overlaid, translucent, or side by side), at most MAX_PLAYED."""
    world = int(world)
    try:
      self.session.bank.row_of(world)
    except MwbxError as err:
      self._say(f"error: {err}")
      return
    # The poses and the text go out as one batch, at once: the page applies a
    # batch that touches the scene at its next frame, and viser otherwise
    # sends what is queued at its next window (up to 1/60 s later).
    with self.lock, self.server.atomic():
      self.player.play(world, add=add)
      self.playing_world = world
      shown = ", ".join(f"world {w}" for w in self.player.played)
      self.ui.playing_md.content = f"playing **{shown}**"
      self.ui.lineage_md.content = "\n".join(f"- {line}" for line in self.session.lineage(world))
    self.server.flush()
    LOG.info(f"playing world {world}" + (" (added)" if add else ""))

  def layout(self) -> None:
    with self.lock:
      self.stage.set_side_by_side(self.ui.side_by_side.value)
    LOG.info(f"layout {'side by side' if self.ui.side_by_side.value else 'overlay'}"
          f" of {list(self.player.played)}")

  def compare(self) -> None:
    """Plays the worlds typed in *Worlds to compare* side by side, from the start."""
    try:
      worlds = [int(w) for w in _names(self.ui.chosen.value)]
    except ValueError:
      self._say(f"error: worlds to compare: give 2 to {MAX_PLAYED} world ids, got {self.ui.chosen.value!r}")
      return
    if not 2 <= len(worlds) <= MAX_PLAYED or len(set(worlds)) != len(worlds):
      self._say(f"error: worlds to compare: give 2 to {MAX_PLAYED} different world ids, got {worlds}")
      return
    for w in worlds:
      try:
        self.session.bank.row_of(w)
      except MwbxError as err:
        self._say(f"error: worlds to compare: {err}")
        return
    self.ui.side_by_side.value = True  # (its callback lays the grid out)
    with self.lock:
      self.stage.set_side_by_side(True)
      for i, w in enumerate(worlds):
        self.play(w, add=i > 0)
    self._say(f"side by side: {', '.join(f'world {w}' for w in worlds)}")

  def seek(self) -> None:
    t = float(self.ui.time_slider.value)
    if not math.isfinite(t):  # a client may send any number; the slider's span holds the rest
      self._say(f"error: time: must be a finite number of seconds, got {t}")
      return
    t = min(max(t, 0.0), self.ui.end_time)
    self.player.seek(int(round(t * self.session.bank.record_fps)))

  # -- refinement ---------------------------------------------------------------------------

  def refine(self) -> None:
    with self.lock:
      world, frame = self.playing_world, self.player.frame
    if world is None:
      self._say("play a world first (the one to refine)")
      return
    objects = () if self.ui.objects.value == NO_OBJECTS else self.ui.objects.value
    add, remove = _names(self.ui.add_objects.value), _names(self.ui.remove_objects.value)
    try:
      entering = [objects] if objects else list(add + remove)
      t_min = (self.session.first_entry_of_last_box(world, entering) if self.ui.start.value == FIRST_ENTRY
               else frame / self.session.bank.record_fps)
    except MwbxError as err:
      self._say(f"error: {err}")
      return
    n = self.ui.samples.value  # any number a client sends: the session checks it
    try:
      n = int(n) if float(n) == int(n) else n
    except (TypeError, ValueError, OverflowError):
      pass
    try:
      job = self.session.refine(world, objects, t_min=t_min, n_samples=n, add=add, remove=remove,
                                scene=self.ui.scene_file.value)
    except MwbxError as err:
      self._say(f"error: {err}")
      return
    self.ui.progress.visible = True
    changes = "".join(f", {k} {','.join(v)}" for k, v in (("adding", add), ("removing", remove)) if v)
    LOG.info(f"refining {objects or 'no objects'} of world {world} from {t_min:.4f} s, {n} samples"
          f"{changes}")

    def watch():
      while not job.done.wait(0.1):
        if job.progress is not None:
          self.ui.progress.value = 100.0 * job.progress.done / max(1, job.progress.total)
      self.ui.progress.visible = False
      if job.cancelled:
        message = f"refinement of world {world} cancelled; nothing added"
      elif job.error:
        message = f"error: {job.error}"
      else:
        ids = job.new_ids
        message = f"refined world {world}: new worlds {int(ids[0])}..{int(ids[-1])} (parent {world})"
        self._scene_changed()
        self.refresh()
      self._say(message)

    threading.Thread(target=watch, daemon=True, name="mwbx-refine-watch").start()

  def cancel(self) -> None:
    job = self.session.cancel()
    self._say("no refinement is running" if job is None else f"cancelling the refinement of world {job.world}")

  def _say(self, message: str, detail: str | None = None) -> None:
    """The page's one way to report: ``message`` on its status line (one
    line: an error of several lines is joined with ``; ``), and ``detail``
    (default: the message) in the log (``mwbx browse:`` lines)."""
    message = "; ".join(line.strip() for line in str(message).splitlines() if line.strip())
    self.ui.status_md.content = message
    LOG.info(message if detail is None else detail)

  def parent(self) -> None:
    world = self.playing_world
    if world is None:
      return
    parent = self.session.parent(world)
    if parent is None:
      self._say(f"world {world} was sampled: it has no parent")
    else:
      self.play(parent)

  def save(self) -> str:
    """Saves the bank (:meth:`Session.save`); worlds playing whose ids the
    save changed (another writer took them) play on under their ids on disk.
    Returns what to tell the user."""
    unsaved = list(self.session.unsaved)
    path = self.session.save()
    origin = self.session.bank.origin
    if origin.renamed:
      with self.lock:
        self.player.renamed(origin.renamed)
        if self.playing_world is not None:
          self.playing_world = origin.id_on_disk(self.playing_world)
    ids = [origin.id_on_disk(i) for i in unsaved]
    return f"saved {_refined_span(ids) if ids else 'the bank'} to {path}"

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
    span = _refined_span(unsaved)
    if autosave and self.session.path is not None:
      try:
        lines.append(self.save())
      except MwbxError as err:
        lines.append(f"could not save {span}: {err}")
    else:
      lines.append(f"{span} were not saved and are gone (Save bank on the page keeps them; --autosave saves"
                   " them on exit)")
    return lines

  def close(self) -> None:
    """Stops playback and the server."""
    self.player.stop()
    self.server.stop()


def _names_text(names) -> str:
  """Body names as the log writes them, without spaces (``['a','b']``; None: every body)."""
  return "[" + ",".join(repr(n) for n in names) + "]" if names else "None"


def _refined_span(ids: list[int]) -> str:
  """``N refined worlds (ids a..b)`` for a page's message."""
  return f"{len(ids)} refined world{'s' if len(ids) > 1 else ''} (ids {ids[0]}..{ids[-1]})"


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
  log_to_stdout()
  notices_to_stderr()
  session = Session(bank, path, None if workdir is None else pathlib.Path(workdir))
  page = Browser(session, host=host, port=port)
  if not page.loopback:
    NOTICE.warning(f"warning: --host {host} is not a loopback address: anyone who can reach port {page.port} there"
                   " and holds the token can use the page (it runs refinements and writes query files under"
                   f" {session.query_dir}); the token travels unencrypted")
  if page.port != page.requested_port:
    NOTICE.info(f"port {page.requested_port} is busy; serving on port {page.port}")
  NOTICE.info(f"browsing {bank.n_worlds} worlds at {page.url}")
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
        NOTICE.info(line)
      page.close()
  return page
