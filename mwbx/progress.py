"""Progress of long work, as data: what the sampler and refinement report.

Every long phase reports :class:`Progress` to an optional callback; the CLI
draws it as a tqdm bar on a terminal and as a few plain lines otherwise
(:func:`reporter`). Research code can pass any callable.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Callable, NamedTuple, TextIO


class Progress(NamedTuple):
  """One progress report.

  Attributes:
    phase: ``simulating``, ``compressing`` (sampling) or ``refining``,
      ``compressing`` (refinement).
    done: worlds done in this phase so far (simulated, compressed; refining:
      world-equivalents, the world-steps run over the most one world can take,
      so it moves while worlds step in lockstep).
    total: worlds in this run.
    world_steps: physics steps run so far, summed over worlds.
    note: what the phase has reached, shown after the rate (solving: the best
      world and the queries it meets); empty for none.
  """

  phase: str
  done: float
  total: int
  world_steps: int
  note: str = ""


ProgressFn = Callable[[Progress], None]

# Plain (non-terminal) output: a line per phase change and per this fraction,
# at most one a this many seconds in between (a phase of a tenth of a second
# prints its first and last lines, not eleven).
PLAIN_STEP = 0.1
PLAIN_MIN_SECONDS = 1.0
# Phases that step worlds: the only ones a world-steps/s rate describes.
STEPPING_PHASES = ("simulating", "refining", "guided sampling", "solving")
# What ``done`` counts, where it is not worlds.
UNITS = {"solving": "refinement"}


def _unit(phase: str) -> str:
  return UNITS.get(phase, "world")


class reporter:
  """A progress callback: one tqdm bar per phase on a terminal, plain lines elsewhere.

  Use as a context manager; leaving it completes the bars of a finished run.

  Example::

    with reporter("sample") as report:
      bank = mwbx.sample(config, 256, key, progress=report)
  """

  def __init__(self, label: str, stream: TextIO | None = None, interactive: bool | None = None,
               min_seconds: float = PLAIN_MIN_SECONDS):
    self.label = label
    self.stream = stream or sys.stderr
    self.interactive = self.stream.isatty() if interactive is None else interactive
    self.min_seconds = min_seconds
    self.bars: dict = {}        # phase -> tqdm bar (terminal)
    self.next_line: dict = {}   # phase -> fraction at which the next plain line is due
    self.line_at: dict = {}     # phase -> when its last plain line was printed
    self.phase_start: dict = {}  # phase -> when it was first reported (its ETA's clock)
    self.last: dict[str, Progress] = {}
    self.phase = None
    self.start = None  # (time, world_steps) at the first report: rates leave compilation out

  def __enter__(self) -> "reporter":
    return self

  def __exit__(self, kind, *exc) -> None:
    self.close(finished=kind is None)

  def _rate(self, p: Progress, now: float) -> str:
    t0, steps0 = self.start
    if p.phase not in STEPPING_PHASES or now <= t0 or p.world_steps <= steps0:
      return ""
    rate = (p.world_steps - steps0) / (now - t0)
    return f"{rate / 1e3:,.0f}k world-steps/s" if rate >= 1e4 else f"{rate:,.0f} world-steps/s"

  def __call__(self, p: Progress) -> None:
    now = time.perf_counter()
    if self.start is None:
      self.start = (now, p.world_steps)
    changed = p.phase != self.phase
    self.phase = p.phase
    self.phase_start.setdefault(p.phase, now)
    self.last[p.phase] = p
    frac = p.done / max(p.total, 1)
    if self.interactive:
      bar = self.bars.get(p.phase)
      if bar is None:
        from tqdm import tqdm
        bar = self.bars[p.phase] = tqdm(total=p.total, desc=f"{self.label}: {p.phase}", unit=_unit(p.phase),
                                        dynamic_ncols=True, file=self.stream, position=len(self.bars))
      bar.n = round(p.done, 1) if p.done % 1 else int(p.done)
      bar.set_postfix_str(", ".join(x for x in (self._rate(p, now), p.note) if x), refresh=False)
      bar.refresh()
      return
    due = frac >= self.next_line.get(p.phase, 0.0) and (
        frac >= 1 or now - self.line_at.get(p.phase, -1e9) >= self.min_seconds)
    if changed or due:
      self._line(p, now)
      self.line_at[p.phase] = now
      # The next line at the next multiple of PLAIN_STEP; none after 100 %.
      self.next_line[p.phase] = 2.0 if frac >= 1 else min(1.0, (frac // PLAIN_STEP + 1) * PLAIN_STEP)

  def _line(self, p: Progress, now: float) -> None:
    elapsed = now - self.start[0]
    frac = p.done / max(p.total, 1)
    in_phase = now - self.phase_start.get(p.phase, self.start[0])
    eta = f", ETA {in_phase * (1 - frac) / frac:.0f} s" if 0 < frac < 1 else ""
    rate = self._rate(p, now)
    note = f"; {p.note}" if p.note else ""
    done = f"{p.done:.1f}" if p.done % 1 else f"{p.done:.0f}"  # 0.5 of 1 world, not "0/1 (50%)"
    print(f"{self.label}: {p.phase} {done}/{p.total} {_unit(p.phase)}s ({frac:.0%}), {elapsed:.1f} s"
          f"{', ' + rate if rate else ''}{eta}{note}", file=self.stream, flush=True)

  def close(self, finished: bool = True) -> None:
    """Ends the bars; a finished run shows every phase complete."""
    if finished:
      for p in list(self.last.values()):
        if p.done < p.total:
          self(p._replace(done=p.total))
    for bar in self.bars.values():
      bar.close()
    self.bars = {}


NOTICE = logging.getLogger("mwbx.notice")


class _StderrNow(logging.StreamHandler):
  """Writes to whatever ``sys.stderr`` is when a record comes (it may be swapped after the handler is made)."""

  @property
  def stream(self):
    return sys.stderr

  @stream.setter
  def stream(self, value):
    del value


def notices_to_stderr() -> None:
  """Sends mwbx's notices (logger ``mwbx.notice``: what a page or a bank has
  to say once) to stderr as ``mwbx: ...`` lines; idempotent."""
  if not NOTICE.handlers:
    handler = _StderrNow()
    handler.setFormatter(logging.Formatter("mwbx: %(message)s"))
    NOTICE.addHandler(handler)
    NOTICE.setLevel(logging.INFO)
    NOTICE.propagate = False
