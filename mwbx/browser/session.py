"""The state of one browsing session, without any UI: the query stack with
undo/redo, the counts, the metric sorter and refinement jobs.

The page (:mod:`mwbx.browser.app`) only turns gestures into calls here; every
answer comes from :mod:`mwbx.queries` and :mod:`mwbx.refinement`, so research
code and tests can drive a session the way the page does.
"""

from __future__ import annotations

import dataclasses
import pathlib
import threading
from typing import NamedTuple, Sequence

import numpy as np

from mwbx import queries as mq
from mwbx.bank.shards import SHARDS
from mwbx.errors import MwbxError
from mwbx.progress import Progress
from mwbx.queries.bank_cache import PerBank
from mwbx.refinement import RefineRequest
from mwbx.refinement import run_refinement
from mwbx.yaml_input import short_repr

REDUCTIONS = ("sum", "max")
# The sorter lists at most this many worlds.
SORTER_ROWS = 20
# Refined worlds one refinement of a session may ask for (the page's limit,
# checked here: a client can send any number).
MAX_REFINE_SAMPLES = 4096
QUERY_SUFFIXES = (".yaml", ".yml")
EXPORT_SUFFIXES = (".usd", ".usda", ".usdc", ".mp4", ".npz")  # what the page's Export writes
# The sorter metric ranking by the last enabled orientation query's error (radians, smallest first);
# not the stored metric orientation_error (the angle from the initial orientation).
ORIENTATION_ERROR = "error of the orientation query"
# The sorter's largest normal impulse (N·s) of the last touch query's sides.
HARDEST_HIT = "hardest hit of the touch query"


class Entry(NamedTuple):
  """One query on the stack and whether it counts (toggled off: kept, not applied)."""

  query: mq.Query
  enabled: bool = True


class Counts(NamedTuple):
  """Worlds satisfying each query (i32 per entry, disabled ones included) and
  all enabled ones, out of ``valid`` worlds."""

  per_query: tuple[int, ...]
  all: int
  valid: int


class View(NamedTuple):
  """What the page draws from the query stack: ``each`` bool[W, Q] per entry
  (enabled or not), ``match`` bool[W] valid worlds satisfying every enabled
  query (none when the stack is empty), ``rejected`` bool[W] valid worlds an
  enabled exclude query rejects, and the counts."""

  each: np.ndarray
  match: np.ndarray
  rejected: np.ndarray
  counts: Counts


class SorterRow(NamedTuple):
  """A world in the sorter: its id, how many enabled queries it satisfies, the
  metric value it is sorted by, and its parent (-1: sampled)."""

  world: int
  satisfied: int
  value: float
  parent: int


class RefineCancelled(Exception):
  """Raised inside a refinement's progress callback to stop it."""


class RefineJob:
  """A refinement running in a background thread (see :meth:`Session.refine`).

  Attributes:
    world, n_samples: what it refines.
    progress: the last :class:`mwbx.progress.Progress` it reported (or None).
    new_ids: the ids it added, once done. error: why it failed, if it did
      (any exception, named, not only MwbxError). cancelled: it was stopped by
      :meth:`cancel` and added nothing.
  """

  def __init__(self, world: int, n_samples: int):
    self.world, self.n_samples = int(world), int(n_samples)
    self.progress: Progress | None = None
    self.new_ids: np.ndarray | None = None
    self.error: str | None = None
    self.cancelled = False
    self.done = threading.Event()
    self._cancel = threading.Event()

  def cancel(self) -> None:
    """Stops the refinement at its next progress report (the worlds being
    stepped finish first); nothing joins the bank."""
    self._cancel.set()

  def _report(self, progress: Progress) -> None:
    if self._cancel.is_set():
      raise RefineCancelled
    self.progress = progress


def query_file_path(workdir, name, suffixes=QUERY_SUFFIXES, what: str = "query file",
                    write: bool = False) -> pathlib.Path:
  """The query file ``name`` (relative to ``workdir``, or absolute) as an
  absolute path, refused unless it is a .yaml/.yml file (or one of
  ``suffixes``) under ``workdir`` (symbolic links followed).

  Names come from any client of the page, so the checks hold for any string:
  a NUL or other control character, a part starting with ``~`` (never a home
  folder here) or ``.`` (hidden: the bank's lock and temporary files), and
  the bank's own ``shards`` folder are refused. With ``write`` the file's
  folder must exist already: the page writes into ``workdir`` and the
  folders someone made there, and never makes one.

  Raises:
    MwbxError: one line naming the file and what is wrong with it.
  """
  if workdir is None:
    raise MwbxError(f"{what}s: this session has no directory to keep them in (pass path= or workdir=)")
  root = pathlib.Path(workdir).resolve()
  raw = str(name).strip()
  if not raw:
    raise MwbxError(f"{what}: give a file name, e.g. {'queries' if what == 'query file' else 'world'}{suffixes[0]}")
  shown = short_repr(raw, 120)
  if any(ord(c) < 32 or ord(c) == 127 for c in raw):
    raise MwbxError(f"{what} {shown}: the name holds a NUL or other control character")
  if any(part.startswith("~") for part in pathlib.PurePath(raw).parts):
    raise MwbxError(f"{what} {shown}: a name starting with '~' is refused (it is no home folder here)")
  try:
    full = (root / raw).resolve()
  except (OSError, RuntimeError, ValueError) as err:  # a symbolic link loop, a name too long
    raise MwbxError(f"{what} {shown}: not a usable file name ({type(err).__name__})") from None
  if full == root or not full.is_relative_to(root):
    raise MwbxError(f"{what} {shown}: outside {root}; {what}s stay under that directory")
  if full.suffix.lower() not in suffixes:
    raise MwbxError(f"{what} {shown}: the name must end in {' or '.join(suffixes)}")
  inside = full.relative_to(root).parts
  if any(part.startswith((".", "~")) for part in inside):
    raise MwbxError(f"{what} {shown}: hidden files and folders (names starting with '.') are refused")
  if SHARDS in inside[:-1]:
    raise MwbxError(f"{what} {shown}: inside a bank's own {SHARDS}/ folder; {what}s stay out of it")
  if write and not full.parent.is_dir():
    raise MwbxError(f"{what} {shown}: no folder {full.parent.relative_to(root)} under {root}; files are"
                    f" written into it and its existing folders only (none is made)")
  return full


@dataclasses.dataclass
class Session:
  """A bank being browsed.

  Args:
    bank: the bank (refinements append to it).
    path: where it is saved (``save()``), or None.
    workdir: the directory query files are read from and written to, and
      nowhere else (default: ``path``; neither: no query files).

  Example::

    session = Session(mwbx.Bank.load("out/quickstart"))
    session.add(mwbx.Query.screen(camera, [0.1, 0.3, 0.3, 0.6], bodies=["ball"]))
    session.counts()            # Counts(per_query=(193,), all=193, valid=256)
    session.sorted_rows("angular_travel")
  """

  bank: object
  path: pathlib.Path | None = None
  workdir: pathlib.Path | None = None
  entries: list = dataclasses.field(default_factory=list)
  _undo: list = dataclasses.field(default_factory=list)
  _redo: list = dataclasses.field(default_factory=list)
  _lock: threading.Lock = dataclasses.field(default_factory=threading.Lock)
  _answers: PerBank = dataclasses.field(default_factory=PerBank)  # bool[W, Q] per bank and stack
  job: RefineJob | None = None
  unsaved: list = dataclasses.field(default_factory=list)  # ids refined here and not saved yet

  # -- the query stack -----------------------------------------------------------------

  def _push(self) -> None:
    self._undo.append(list(self.entries))
    self._redo.clear()

  def add(self, query: mq.Query) -> int:
    """Puts a query on the stack; returns its index."""
    query.check(self.bank)  # an unknown name fails now, naming it
    self._push()
    self.entries.append(Entry(query))
    return len(self.entries) - 1

  def toggle(self, index: int) -> None:
    self._check(index)
    self._push()
    entry = self.entries[index]
    self.entries[index] = entry._replace(enabled=not entry.enabled)

  def remove(self, index: int) -> None:
    self._check(index)
    self._push()
    del self.entries[index]

  def undo(self) -> bool:
    """Back to the stack before the last change; False when there is none."""
    if not self._undo:
      return False
    self._redo.append(list(self.entries))
    self.entries = self._undo.pop()
    return True

  def redo(self) -> bool:
    if not self._redo:
      return False
    self._undo.append(list(self.entries))
    self.entries = self._redo.pop()
    return True

  def _check(self, index: int) -> None:
    if not 0 <= index < len(self.entries):
      raise MwbxError(f"query {index}: no such query (the stack holds {len(self.entries)})")

  @property
  def enabled(self) -> tuple[mq.Query, ...]:
    return tuple(e.query for e in self.entries if e.enabled)

  # -- answers ---------------------------------------------------------------------------

  def each(self) -> np.ndarray:
    """bool[W, Q] every entry (enabled or not) on the current bank, evaluated
    once per bank and stack (a redraw asks several times)."""
    queries = tuple(e.query for e in self.entries)
    return self._answers.get(self.bank, "each", self._answers_state(self.bank), lambda: (
        np.asarray(mq.evaluate_each(self.bank, list(queries)), bool) if queries
        else np.zeros((self.bank.n_worlds, 0), bool)))

  def _answers_state(self, bank) -> tuple:
    """What the kept answers of ``bank`` were evaluated for: its world count and the stack."""
    return (bank.n_worlds, tuple(e.query for e in self.entries))

  def view(self) -> View:
    """The answers the page draws (see :class:`View`)."""
    each = self.each()
    k = self._kept()
    match = k.match if self.entries else np.zeros(self.bank.n_worlds, bool)  # no query: nothing highlighted
    return View(each, match, k.rejected, self.counts())

  def _kept(self) -> mq.Kept:
    """:func:`mwbx.queries.kept` of the enabled entries."""
    on = np.array([e.enabled for e in self.entries], bool)
    include = np.array([e.query.include for e in self.entries], bool)
    return mq.kept(self.each()[:, on], include[on], self.bank.valid)

  def orientation_query(self):
    """The last enabled query with an error to rank by (an orientation query:
    the sorter's ``orientation_error``), or None."""
    found = [q for q in self.enabled if q.error_metric == "orientation_error"]
    return found[-1] if found else None

  def touch_query(self):
    """The last enabled touch query (the sorter's hardest hit), or None."""
    found = [q for q in self.enabled if q.error_metric == "hardest_hit"]
    return found[-1] if found else None

  def match(self) -> np.ndarray:
    """bool[W] valid worlds satisfying every enabled query (all valid ones when none)."""
    return self._kept().match

  def counts(self) -> Counts:
    each = self.each()
    valid = np.asarray(self.bank.valid, bool)
    on = np.array([e.enabled for e in self.entries], bool)
    return Counts(tuple(int((each[:, i] & valid).sum()) for i in range(each.shape[1])),
                  int((np.all(each[:, on], axis=1) & valid).sum()), int(valid.sum()))

  def sorted_rows(self, metric: str, reduce: str = "sum", bodies: Sequence[str] | None = None,
                  descending: bool = True, top: int = SORTER_ROWS) -> list[SorterRow]:
    """The sorter (paper §4.3): matching worlds by ``metric`` over ``bodies``
    (sum or max; ``constraints_satisfied`` counts enabled queries); when no
    world satisfies every enabled query, the worlds that satisfy the most."""
    if reduce not in REDUCTIONS:
      raise MwbxError(f"sorter: reduce must be one of {REDUCTIONS}, got {reduce!r}")
    match = self.match()
    on = np.array([e.enabled for e in self.entries], bool)
    satisfied = self.each()[:, on].sum(axis=1).astype(np.int64)
    if metric == mq.metrics.CONSTRAINTS:
      values = satisfied.astype(np.float64)
    elif metric == ORIENTATION_ERROR:
      query = self.orientation_query()
      if query is None:
        raise MwbxError(f"sorter: {ORIENTATION_ERROR!r} needs an orientation query (add one first)")
      values = query.error(self.bank, reduce)  # over the query's own bodies
      descending = False  # the most nearly oriented first
    elif metric == HARDEST_HIT:
      query = self.touch_query()
      if query is None:
        raise MwbxError(f"sorter: {HARDEST_HIT!r} needs a touch query (add one in Contacts first)")
      values = query.error(self.bank)  # N·s, the hardest first
    else:
      values = mq.metrics.score(self.bank, [mq.Term(metric, None if not bodies else tuple(bodies), reduce, 1.0)])
    if match.any():
      ids, values = mq.rank(self.bank, values, match=match, top=top, descending=descending)
    else:
      ids, values = mq.rank(self.bank, satisfied.astype(np.float64), top=top)
    rows = self.bank.row_of(np.asarray(ids, np.int64))
    return [SorterRow(int(i), int(satisfied[r]), float(v), int(self.bank.parent_world[r]))
            for i, r, v in zip(ids, rows, values)]

  # -- files -------------------------------------------------------------------------------

  def query_set(self) -> mq.QuerySet:
    """The enabled queries as a QuerySet (``.save(path)`` writes a query file)."""
    return mq.QuerySet(self.enabled)

  @property
  def query_dir(self) -> pathlib.Path | None:
    """Where query files are kept (``workdir``, else the bank directory)."""
    return self.workdir if self.workdir is not None else self.path

  def export(self, world: int, name, progress=None) -> str:
    """Writes world ``world`` to file ``name`` under :attr:`query_dir`: USD
    (``.usd``/``.usda``/``.usdc``), an mp4 video or an npz of its decoded qpos
    and body poses (:mod:`mwbx.export`); returns the path written."""
    from mwbx import export  # lazy: usd-core and imageio-ffmpeg load on first export
    full = query_file_path(self.query_dir, name, EXPORT_SUFFIXES, "export file", write=True)
    world = int(world)
    suffix = full.suffix.lower()
    if suffix == ".mp4":
      export.render_video(self.bank, world, full, progress=progress)
    elif suffix == ".npz":
      export.export_npz(self.bank, world, full)
    else:
      export.export_usd(self.bank, world, full, progress=progress)
    return str(full)

  def save_queries(self, name) -> str:
    """Writes the enabled queries to ``name`` under :attr:`query_dir`; returns its path."""
    return self.query_set().save(query_file_path(self.query_dir, name, write=True))

  def open_queries(self, name) -> None:
    """Replaces the stack with the queries of file ``name`` under
    :attr:`query_dir` (undo brings the old one back). Errors name the file,
    never its content (the page shows them to every client)."""
    full = query_file_path(self.query_dir, name)
    if not full.is_file():
      raise MwbxError(f"query file {str(name).strip()!r}: no such file under {self.query_dir}")
    try:
      loaded = mq.load_queries(full, self.bank)
    except MwbxError:
      raise MwbxError(f"query file {str(name).strip()!r}: not a query file for this bank (`mwbx query BANK"
                      f" {full}` says why)") from None
    self._push()
    self.entries = [Entry(q) for q in loaded.queries]

  def save(self) -> pathlib.Path:
    """Writes the bank's new worlds as a new shard (nothing saved before
    changes); the session goes on with the bank as saved (its worlds' ids as
    on disk). Returns the bank directory."""
    if self.path is None:
      raise MwbxError("save: this session has no bank directory (pass path=)")
    with self._lock:
      before, self.bank = self.bank, self.bank.save(self.path)
      state = self._answers_state(before)
      kept = self._answers.peek(before, "each", state)
      if kept is not None:  # the same worlds in the same rows
        self._answers.put(self.bank, "each", state, kept)
      self.unsaved.clear()
      return pathlib.Path(self.bank.origin.path)

  # -- refinement --------------------------------------------------------------------------

  def first_entry_of_last_box(self, world: int, objects) -> float:
    """t_min for "first entry of the last box": when the objects first enter the
    frustum of the last enabled include query (paper §5)."""
    boxes = [q for q in self.enabled if q.include and q.frustum is not None]
    if not boxes:
      raise MwbxError("refine: draw an include box first (its first entry is the start time)")
    names = list(objects) if not isinstance(objects, str) else [objects]
    t = mq.first_entry(self.bank, world, names, boxes[-1].frustum)
    if t is None:
      raise MwbxError(f"refine: no object of {', '.join(names)} enters the last box in world {world}")
    return float(t)

  def refine(self, world: int, objects, *, t_min: float, n_samples: int, key=None,
             backend: str | None = None, wait: bool = False, add=(), remove=(), scene=None) -> RefineJob:
    """Refines ``objects`` of world ``world`` from ``t_min`` in a background
    thread; the new worlds join the bank when it is done (``job.done``).

    ``add`` / ``remove`` change the scene at ``t_min`` as ``mwbx refine
    --add/--remove`` does; ``scene``, a later version of the bank's scene
    holding the objects to add: a ``.yaml`` file name under :attr:`query_dir`
    (as query files), the bank moved to it first.

    Raises:
      MwbxError: ``n_samples`` outside 1..MAX_REFINE_SAMPLES, another
        refinement of this session still running (one at a time), or a scene
        file outside :attr:`query_dir`.
    """
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) \
        or not 1 <= n_samples <= MAX_REFINE_SAMPLES:
      raise MwbxError(f"refine: samples must be a whole number from 1 to {MAX_REFINE_SAMPLES}, got {n_samples!r}")
    # Every argument is checked before the job slot is taken: a refused one
    # never leaves a job that is not done (which would refuse every later one).
    scene_path = (None if scene is None or not str(scene).strip()
                  else query_file_path(self.query_dir, scene, what="scene file"))
    if scene_path is not None and not scene_path.is_file():
      raise MwbxError(f"refine: scene file {str(scene).strip()!r}: no such file under {self.query_dir}")
    with self._lock:
      running = self.job
      if running is not None and not running.done.is_set():
        raise MwbxError(f"refine: world {running.world} is being refined ({running.n_samples} samples);"
                        " wait for it or cancel it")
      job = self.job = RefineJob(world, n_samples)

    def work():
      try:
        done = run_refinement(self.bank, RefineRequest(world, objects, t_min=t_min, n_samples=int(n_samples), key=key,
                                                   backend=backend, scene=scene_path, add=add, remove=remove),
                          progress=job._report)
        new = done.new
        if job._cancel.is_set():
          raise RefineCancelled
        with self._lock:
          self.bank = done.bank
          self.unsaved.extend(int(i) for i in np.asarray(new.world_ids))
        job.new_ids = np.asarray(new.world_ids)
      except RefineCancelled:
        job.cancelled = True
      except MwbxError as err:
        job.error = str(err)
      except Exception as err:  # noqa: BLE001 - e.g. MemoryError: reported on the page, not lost in a thread
        job.error = f"{type(err).__name__}: {str(err) or 'out of memory'}"[:500]
      finally:
        job.done.set()

    thread = threading.Thread(target=work, daemon=True, name="mwbx-refine")
    thread.start()
    if wait:
      job.done.wait()
    return job

  def cancel(self) -> RefineJob | None:
    """Cancels the running refinement (None: none was running)."""
    job = self.job
    if job is None or job.done.is_set():
      return None
    job.cancel()
    return job

  def parent(self, world: int) -> int | None:
    """The world ``world`` was refined from (None: a sampled world)."""
    p = int(self.bank.parent_world[self.bank.row_of(int(world))])
    return None if p < 0 else p

  def lineage(self, world: int) -> list[str]:
    """How world ``world`` came to be, one line per step, oldest first: the
    sampled world, then each refinement (its parent, t_min, objects added
    and removed), and the objects absent from it and when."""
    bank = self.bank
    chain = [int(a) for a in bank.ancestors(int(world))][::-1] + [int(world)]
    lines = []
    for wid in chain:
      entry = bank.lineage.get(str(wid), {})
      parent = int(bank.parent_world[bank.row_of(wid)])
      if parent < 0:
        lines.append(f"world {wid}: sampled")
        continue
      changes = [f"+{name} at {float(t):.3g} s" for name, t in entry.get("added", {}).items()]
      changes += [f"-{name} at {float(t):.3g} s" for name, t in entry.get("removed", {}).items()]
      objects = ", ".join(entry.get("objects", ())) or "no objects"
      lines.append(f"world {wid}: {objects} refined from {parent} at {float(bank.refine_time[bank.row_of(wid)]):.3g} s"
                   + (f" ({', '.join(changes)})" if changes else ""))
    absent = bank.absent(int(world))
    if absent:
      lines.append("absent: " + ", ".join(f"{name} {lo:.3g}..{hi:.3g} s" for name, (lo, hi) in absent.items()))
    return lines
