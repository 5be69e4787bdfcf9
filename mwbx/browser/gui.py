"""The page's widgets (viser GUI), wired to the :class:`~mwbx.browser.app.Browser` callbacks.

Folders: Queries (bodies, several bodies, mode, whole geometry, window, draw
buttons, the stack, query files), Orientation, Contacts (two sides that touch
or never do), Sorter (metric, rows, overlay or side by side), Playback (what
plays, its lineage, pause, time, export) and Refine (objects, start, samples,
scene changes, cancel, parent, save).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import viser

from mwbx import queries as mq
from mwbx.browser.scene import MAX_SLOTS
from mwbx.browser.session import HARDEST_HIT, MAX_REFINE_SAMPLES, ORIENTATION_ERROR, REDUCTIONS

ALL_BODIES = "(every tracked body)"
NO_OBJECTS = "(none: only add/remove)"
FIRST_ENTRY = "first entry of the last box"
CURRENT_TIME = "current time"
BODY_AXES = ("z", "y", "x", "-z", "-y", "-x")
MAX_PLAYED = MAX_SLOTS


@dataclasses.dataclass
class Widgets:
  """The page's widgets that the :class:`~mwbx.browser.app.Browser` reads or
  updates, one typed handle each, by folder (:func:`build`)."""

  end_time: float  # s, the time sliders' span
  buttons: dict[str, viser.GuiButtonHandle]  # label -> button (the sorter's rows aside)
  # Queries
  counts_md: viser.GuiMarkdownHandle
  bodies: viser.GuiDropdownHandle
  several_folder: viser.GuiFolderHandle
  several: dict[str, viser.GuiCheckboxHandle]  # body name -> its tick
  mode: viser.GuiDropdownHandle
  geometry: viser.GuiCheckboxHandle
  only_matches: viser.GuiCheckboxHandle
  window: viser.GuiMultiSliderHandle
  query_pick: viser.GuiDropdownHandle
  query_file: viser.GuiTextHandle
  # Orientation
  axis: viser.GuiDropdownHandle
  within: viser.GuiNumberHandle
  # Contacts
  touch_a: viser.GuiDropdownHandle
  touch_b: viser.GuiDropdownHandle
  touch_impulse: viser.GuiNumberHandle
  # Sorter
  metric: viser.GuiDropdownHandle
  reduce: viser.GuiDropdownHandle
  sorter_md: viser.GuiMarkdownHandle
  compare: viser.GuiCheckboxHandle
  side_by_side: viser.GuiCheckboxHandle
  chosen: viser.GuiTextHandle
  sorter: viser.GuiFolderHandle
  row_buttons: list[viser.GuiButtonHandle]  # the sorter's rows, remade on each sort
  # Playback
  playing_md: viser.GuiMarkdownHandle
  lineage_md: viser.GuiMarkdownHandle
  paused: viser.GuiCheckboxHandle
  time_slider: viser.GuiSliderHandle
  export_file: viser.GuiTextHandle
  # Refine
  objects: viser.GuiDropdownHandle
  start: viser.GuiDropdownHandle
  samples: viser.GuiNumberHandle
  scene_file: viser.GuiTextHandle
  add_objects: viser.GuiTextHandle
  remove_objects: viser.GuiTextHandle
  progress: Any  # viser's progress bar handle
  status_md: viser.GuiMarkdownHandle


def wire(page, handle, action) -> None:
  """Calls ``action(event)`` when ``handle`` is clicked (a button) or changed,
  through ``page.guarded``: whatever value a client sends, a failure is one
  ``error:`` line in the status line, never an exception in viser's thread."""
  register = handle.on_click if hasattr(handle, "on_click") else handle.on_update
  register(lambda event: page.guarded(lambda: action(event), handle.label))


def build(page) -> Widgets:
  """Adds the widgets to ``page.server.gui``, one folder at a time, each
  widget wired to the page's actions (``page.refresh``, ``page.arm_box``,
  ``page.refine``, ...) beside it; returns the ones read later."""
  gui = page.server.gui
  buttons: dict = {}

  def on(handle, action: Callable) -> None:
    wire(page, handle, action)
    if hasattr(handle, "on_click"):
      buttons[handle.label] = handle

  bank = page.session.bank
  end = float((int(bank.frame_count.max()) - 1) / bank.record_fps) if bank.n_worlds else 1.0
  fields = {"end_time": end, "buttons": buttons}
  for folder in (_queries, _orientation, _contacts, _sorter, _playback, _refine):
    fields.update(folder(gui, page, on, end))
  return Widgets(**fields)


def _queries(gui, page, on, end: float) -> dict:
  """Bodies, several bodies, mode, whole geometry, window, the draw buttons,
  the stack of queries and query files."""
  names = page.body_names()
  span = max(end, 1e-3)
  with gui.add_folder("Queries"):
    counts_md = gui.add_markdown("")
    bodies = gui.add_dropdown("Bodies", names, initial_value=ALL_BODIES)
    several_folder = gui.add_folder("Several bodies", expand_by_default=False)
    with several_folder:
      gui.add_markdown("tick any number: they replace *Bodies*")
      several = {}
      for name in names[1:]:
        several[name] = gui.add_checkbox(name, False)
        on(several[name], lambda _: page.refresh())
    mode = gui.add_dropdown("Mode", ("any", "all"), initial_value="any")
    geometry = gui.add_checkbox("Whole geometry", False,
                                hint="a box asks about any point of the bodies' geoms, not their COM")
    only_matches = gui.add_checkbox("Only matching paths", False)
    on(only_matches, lambda _: page.refresh())
    on(bodies, lambda _: page.refresh())
    window = gui.add_multi_slider("Time window (s)", 0.0, span, span / 100, (0.0, span))
    include = gui.add_button("Draw include box")
    exclude = gui.add_button("Draw exclude box")
    on(include, lambda event: page.arm_box("include", event.client))
    on(exclude, lambda event: page.arm_box("exclude", event.client))
    query_pick = gui.add_dropdown("Query", ("(none)",), initial_value="(none)")
    toggle = gui.add_button("Toggle query")
    remove = gui.add_button("Remove query")
    on(toggle, lambda _: page.with_pick(page.session.toggle))
    on(remove, lambda _: page.with_pick(page.session.remove))
    undo = gui.add_button("Undo")
    redo = gui.add_button("Redo")
    on(undo, lambda _: page.session.undo() and page.refresh())
    on(redo, lambda _: page.session.redo() and page.refresh())
    query_file = gui.add_text("Query file", "queries.yaml", hint=f"a .yaml file under {page.session.query_dir}")
    save_q = gui.add_button("Save queries")
    open_q = gui.add_button("Open queries")
    on(save_q, lambda _: page.report(lambda: f"saved {page.session.save_queries(query_file.value)}"))
    on(open_q, lambda _: page.report(lambda: page.session.open_queries(query_file.value)
                                     or f"opened {query_file.value.strip()}"))
  return dict(counts_md=counts_md, bodies=bodies, several_folder=several_folder, several=several, mode=mode,
              geometry=geometry, only_matches=only_matches, window=window, query_pick=query_pick,
              query_file=query_file)


def _orientation(gui, page, on, end: float) -> dict:
  """An orientation query for the chosen bodies: upright, or near the start."""
  with gui.add_folder("Orientation"):
    gui.add_markdown("for the chosen bodies; the window as above (whole span: at the end)")
    axis = gui.add_dropdown("Body axis up", BODY_AXES, initial_value="z")
    within = gui.add_number("Within (deg)", 15.0, min=0.0, max=180.0, step=1.0)
    upright = gui.add_button("Upright at the end")
    initial = gui.add_button("Near its initial orientation")
    on(upright, lambda _: page.add_orientation(upright=True))
    on(initial, lambda _: page.add_orientation(upright=False))
  return dict(axis=axis, within=within)


def _contacts(gui, page, on, end: float) -> dict:
  """A touch query: two sides that touch, or never do."""
  bank = page.session.bank
  with gui.add_folder("Contacts"):
    gui.add_markdown("two sides that touch, or never touch, in the time window above")
    actors = tuple(bank.event_actors) + tuple(bank.groups) or ("(no contact events in this bank)",)
    touch_a = gui.add_dropdown("This", actors, initial_value=actors[0])
    touch_b = gui.add_dropdown("touches", actors, initial_value=actors[min(1, len(actors) - 1)])
    touch_impulse = gui.add_number("Impulse at least (N·s)", 0.0, min=0.0, step=0.01,
                                   hint="0: any touch; else only a touch delivering this normal impulse")
    touches = gui.add_button("Add: they touch")
    never = gui.add_button("Add: they never touch")
    on(touches, lambda _: page.add_touch(include=True))
    on(never, lambda _: page.add_touch(include=False))
  return dict(touch_a=touch_a, touch_b=touch_b, touch_impulse=touch_impulse)


def _sorter(gui, page, on, end: float) -> dict:
  """The metric to sort by, how played worlds are shown, and the rows."""
  bank = page.session.bank
  with gui.add_folder("Sorter"):
    # A scene of flexes only has no turning to sort by: start on the path length.
    first = bank.metric_names[0]
    if first in mq.metrics.ROTATIONAL and bank.flex_body_mask().all() and "path_length" in bank.metric_names:
      first = "path_length"
    metric = gui.add_dropdown("Metric", tuple(bank.metric_names) + (mq.metrics.CONSTRAINTS, ORIENTATION_ERROR,
                                                                    HARDEST_HIT),
                              initial_value=first)
    reduce = gui.add_dropdown("Over bodies", REDUCTIONS, initial_value="sum")
    on(metric, lambda _: page.sorter())
    on(reduce, lambda _: page.sorter())
    sorter_md = gui.add_markdown("")
    compare = gui.add_checkbox("Add to the playing worlds", False,
                               hint=f"play up to {MAX_PLAYED} worlds at once, each labelled with its id")
    side_by_side = gui.add_checkbox("Side by side", False,
                                    hint="the played worlds in a grid of copies of the scene, not overlaid")
    on(side_by_side, lambda _: page.layout())
    chosen = gui.add_text("Worlds to compare", "", hint=f"2 to {MAX_PLAYED} world ids, e.g. 3, 7, 12")
    show = gui.add_button("Show side by side")
    on(show, lambda _: page.compare())
    sorter = gui.add_folder("Worlds (click to play)")
  return dict(metric=metric, reduce=reduce, sorter_md=sorter_md, compare=compare, side_by_side=side_by_side,
              chosen=chosen, sorter=sorter, row_buttons=[])


def _playback(gui, page, on, end: float) -> dict:
  """What plays, its lineage, pause, time and export."""
  bank = page.session.bank
  with gui.add_folder("Playback"):
    playing_md = gui.add_markdown("no world playing")
    lineage_md = gui.add_markdown("")
    paused = gui.add_checkbox("Pause", False)
    time_slider = gui.add_slider("Time (s)", 0.0, max(end, 1e-3), 1.0 / bank.record_fps, 0.0)
    on(time_slider, lambda _: page.seek())
    export_file = gui.add_text("Export file", "world.usd",
                               hint=f"a .usd, .mp4 or .npz file under {page.session.query_dir}")
    export = gui.add_button("Export playing world")
    on(export, lambda _: page.export())
  return dict(playing_md=playing_md, lineage_md=lineage_md, paused=paused, time_slider=time_slider,
              export_file=export_file)


def _refine(gui, page, on, end: float) -> dict:
  """Objects, start, samples, scene changes, cancel, parent, save, and the status line."""
  bank = page.session.bank
  with gui.add_folder("Refine"):
    objects = gui.add_dropdown("Objects", tuple(bank.objects) + tuple(bank.groups) + (NO_OBJECTS,),
                               initial_value=next(iter(bank.objects)))
    start = gui.add_dropdown("From", (CURRENT_TIME, FIRST_ENTRY), initial_value=CURRENT_TIME)
    samples = gui.add_number("Samples", 16, min=1, max=MAX_REFINE_SAMPLES, step=1, hint=f"1 to {MAX_REFINE_SAMPLES}")
    scene_file = gui.add_text("Scene file", "", hint="a later scene version (.yaml under "
                              f"{page.session.query_dir}) holding the objects to add; blank: none")
    add_objects = gui.add_text("Add objects", "", hint="objects of the scene file, inserted at the start time")
    remove_objects = gui.add_text("Remove objects", "", hint="objects parked from the start time on")
    refine = gui.add_button("Refine playing world")
    on(refine, lambda _: page.refine())
    cancel = gui.add_button("Cancel refinement")
    on(cancel, lambda _: page.cancel())
    progress = gui.add_progress_bar(0.0, visible=False)
    parent = gui.add_button("Go to parent")
    on(parent, lambda _: page.parent())
    save = gui.add_button("Save bank")
    on(save, lambda _: page.report(page.save))
    status_md = gui.add_markdown("")
  return dict(objects=objects, start=start, samples=samples, scene_file=scene_file, add_objects=add_objects,
              remove_objects=remove_objects, progress=progress, status_md=status_md)
