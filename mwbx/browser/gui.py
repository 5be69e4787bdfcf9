"""The page's widgets (viser GUI), wired to the :class:`~mwbx.browser.app.Browser` callbacks.

Folders: Queries (bodies, several bodies, mode, whole geometry, window, draw
buttons, the stack, query files), Orientation, Contacts (two sides that touch
or never do), Sorter (metric, rows, overlay or side by side), Playback (what
plays, its lineage, pause, time, export) and Refine (objects, start, samples,
scene changes, cancel, parent, save).
"""

from __future__ import annotations

import types

from mwbx import queries as mq
from mwbx.browser.scene import MAX_SLOTS
from mwbx.browser.session import MAX_REFINE_SAMPLES, ORIENTATION_ERROR, REDUCTIONS

ALL_BODIES = "(every tracked body)"
NO_OBJECTS = "(none: only add/remove)"
FIRST_ENTRY = "first entry of the last box"
CURRENT_TIME = "current time"
BODY_AXES = ("z", "y", "x", "-z", "-y", "-x")
MAX_PLAYED = MAX_SLOTS


class Widgets(types.SimpleNamespace):
  """The page's widgets that the :class:`~mwbx.browser.app.Browser` reads or
  updates (``bodies``, ``several``, ``geometry``, ``window``, ``metric``,
  ``sorter``, ``time_slider``, ``status_md``, ...), ``buttons`` (label ->
  button, the sorter's rows aside), and ``end_time``, the time sliders' span
  (s)."""


def wire(page, handle, action) -> None:
  """Calls ``action(event)`` when ``handle`` is clicked (a button) or changed,
  through ``page.guarded``: whatever value a client sends, a failure is one
  ``error:`` line in the status line, never an exception in viser's thread."""
  register = handle.on_click if hasattr(handle, "on_click") else handle.on_update
  register(lambda event: page.guarded(lambda: action(event), handle.label))


def build(page) -> Widgets:
  """Adds the widgets to ``page.server.gui``, each wired to the page's
  actions (``page.refresh``, ``page.arm_box``, ``page.refine``, ...), and
  returns the ones read later."""
  w = Widgets()
  w.buttons = {}
  gui = page.server.gui

  def on(handle, action) -> None:
    wire(page, handle, action)
    if hasattr(handle, "on_click"):
      w.buttons[handle.label] = handle

  bank = page.session.bank
  names = page.body_names()
  end = float((int(bank.frame_count.max()) - 1) / bank.record_fps) if bank.n_worlds else 1.0
  w.end_time = end
  with gui.add_folder("Queries"):
    w.counts_md = gui.add_markdown("")
    w.bodies = gui.add_dropdown("Bodies", names, initial_value=ALL_BODIES)
    w.several_folder = gui.add_folder("Several bodies", expand_by_default=False)
    with w.several_folder:
      gui.add_markdown("tick any number: they replace *Bodies*")
      w.several = {}
      for name in names[1:]:
        w.several[name] = gui.add_checkbox(name, False)
        on(w.several[name], lambda _: page.refresh())
    w.mode = gui.add_dropdown("Mode", ("any", "all"), initial_value="any")
    w.geometry = gui.add_checkbox("Whole geometry", False,
                                     hint="a box asks about any point of the bodies' geoms, not their COM")
    w.only_matches = gui.add_checkbox("Only matching paths", False)
    on(w.only_matches, lambda _: page.refresh())
    on(w.bodies, lambda _: page.refresh())
    w.window = gui.add_multi_slider("Time window (s)", 0.0, max(end, 1e-3), max(end, 1e-3) / 100,
                                       (0.0, max(end, 1e-3)))
    include = gui.add_button("Draw include box")
    exclude = gui.add_button("Draw exclude box")
    on(include, lambda event: page.arm_box("include", event.client))
    on(exclude, lambda event: page.arm_box("exclude", event.client))
    w.query_pick = gui.add_dropdown("Query", ("(none)",), initial_value="(none)")
    toggle = gui.add_button("Toggle query")
    remove = gui.add_button("Remove query")
    on(toggle, lambda _: page.with_pick(page.session.toggle))
    on(remove, lambda _: page.with_pick(page.session.remove))
    undo = gui.add_button("Undo")
    redo = gui.add_button("Redo")
    on(undo, lambda _: page.session.undo() and page.refresh())
    on(redo, lambda _: page.session.redo() and page.refresh())
    w.query_file = gui.add_text("Query file", "queries.yaml",
                                   hint=f"a .yaml file under {page.session.query_dir}")
    save_q = gui.add_button("Save queries")
    open_q = gui.add_button("Open queries")
    on(save_q, lambda _: page.report(lambda: f"saved {page.session.save_queries(w.query_file.value)}"))
    on(open_q, lambda _: page.report(lambda: page.session.open_queries(w.query_file.value)
                                           or f"opened {w.query_file.value.strip()}"))
  with gui.add_folder("Orientation"):
    gui.add_markdown("for the chosen bodies; the window as above (whole span: at the end)")
    w.axis = gui.add_dropdown("Body axis up", BODY_AXES, initial_value="z")
    w.within = gui.add_number("Within (deg)", 15.0, min=0.0, max=180.0, step=1.0)
    upright = gui.add_button("Upright at the end")
    initial = gui.add_button("Near its initial orientation")
    on(upright, lambda _: page.add_orientation(upright=True))
    on(initial, lambda _: page.add_orientation(upright=False))
  with gui.add_folder("Contacts"):
    gui.add_markdown("two sides that touch, or never touch, in the time window above")
    actors = tuple(bank.event_actors) + tuple(bank.groups) or ("(no contact events in this bank)",)
    w.touch_a = gui.add_dropdown("This", actors, initial_value=actors[0])
    w.touch_b = gui.add_dropdown("touches", actors, initial_value=actors[min(1, len(actors) - 1)])
    touches = gui.add_button("Add: they touch")
    never = gui.add_button("Add: they never touch")
    on(touches, lambda _: page.add_touch(include=True))
    on(never, lambda _: page.add_touch(include=False))
  with gui.add_folder("Sorter"):
    # A scene of flexes only has no turning to sort by: start on the path length.
    first = bank.metric_names[0]
    if first in mq.metrics.ROTATIONAL and bank.flex_body_mask().all() and "path_length" in bank.metric_names:
      first = "path_length"
    w.metric = gui.add_dropdown("Metric", tuple(bank.metric_names) + (mq.metrics.CONSTRAINTS, ORIENTATION_ERROR),
                                   initial_value=first)
    w.reduce = gui.add_dropdown("Over bodies", REDUCTIONS, initial_value="sum")
    on(w.metric, lambda _: page.sorter())
    on(w.reduce, lambda _: page.sorter())
    w.sorter_md = gui.add_markdown("")
    w.compare = gui.add_checkbox("Add to the playing worlds", False,
                                    hint=f"play up to {MAX_PLAYED} worlds at once, each labelled with its id")
    w.side_by_side = gui.add_checkbox("Side by side", False,
                                         hint="the played worlds in a grid of copies of the scene, not overlaid")
    on(w.side_by_side, lambda _: page.layout())
    w.chosen = gui.add_text("Worlds to compare", "", hint=f"2 to {MAX_PLAYED} world ids, e.g. 3, 7, 12")
    compare = gui.add_button("Show side by side")
    on(compare, lambda _: page.compare())
    w.sorter = gui.add_folder("Worlds (click to play)")
    w.row_buttons: list = []
  with gui.add_folder("Playback"):
    w.playing_md = gui.add_markdown("no world playing")
    w.lineage_md = gui.add_markdown("")
    w.paused = gui.add_checkbox("Pause", False)
    w.time_slider = gui.add_slider("Time (s)", 0.0, max(end, 1e-3), 1.0 / bank.record_fps, 0.0)
    on(w.time_slider, lambda _: page.seek())
    w.export_file = gui.add_text("Export file", "world.usd", hint="a .usd, .mp4 or .npz file under "
                                    f"{page.session.query_dir}")
    export = gui.add_button("Export playing world")
    on(export, lambda _: page.export())
  with gui.add_folder("Refine"):
    w.objects = gui.add_dropdown("Objects", tuple(bank.objects) + tuple(bank.groups) + (NO_OBJECTS,),
                                    initial_value=next(iter(bank.objects)))
    w.start = gui.add_dropdown("From", (CURRENT_TIME, FIRST_ENTRY), initial_value=CURRENT_TIME)
    w.samples = gui.add_number("Samples", 16, min=1, max=MAX_REFINE_SAMPLES, step=1,
                                  hint=f"1 to {MAX_REFINE_SAMPLES}")
    w.scene_file = gui.add_text("Scene file", "", hint="a later scene version (.yaml under "
                                   f"{page.session.query_dir}) holding the objects to add; blank: none")
    w.add_objects = gui.add_text("Add objects", "", hint="objects of the scene file, inserted at the start time")
    w.remove_objects = gui.add_text("Remove objects", "", hint="objects parked from the start time on")
    refine = gui.add_button("Refine playing world")
    on(refine, lambda _: page.refine())
    cancel = gui.add_button("Cancel refinement")
    on(cancel, lambda _: page.cancel())
    w.progress = gui.add_progress_bar(0.0, visible=False)
    parent = gui.add_button("Go to parent")
    on(parent, lambda _: page.parent())
    save = gui.add_button("Save bank")
    on(save, lambda _: page.report(page.save))
    w.status_md = gui.add_markdown("")
  return w
