"""Progress reports: a bar on a terminal, a few plain lines in a log, complete at the end."""

import io

import jax

import mwbx
from mwbx.progress import Progress, reporter


def test_plain_lines_are_few_and_end_at_100_percent():
  out = io.StringIO()
  with reporter("sample", stream=out, interactive=False, min_seconds=0) as report:
    for done in range(257):
      report(Progress("simulating", done, 256, done * 1000))
    report(Progress("compressing", 256, 256, 256000))
  lines = out.getvalue().splitlines()
  assert 11 <= len(lines) <= 13, lines  # every 10 % and each phase change, not every update
  assert lines[0].startswith("sample: simulating 0/256 worlds (0%)")
  assert "simulating 256/256 worlds (100%)" in lines[-2] and "compressing 256/256" in lines[-1]
  assert "ETA" in lines[3] and "world-steps/s" in lines[3]


def test_a_fast_phase_prints_its_first_and_last_lines_only():
  out = io.StringIO()
  with reporter("export", stream=out, interactive=False, min_seconds=60) as report:
    for k in range(11):
      report(Progress("writing USD", k / 10, 1, 0))
  lines = out.getvalue().splitlines()
  assert len(lines) == 2, lines
  assert lines[0].startswith("export: writing USD 0/1 worlds (0%)") and "1/1 worlds (100%)" in lines[1]


def test_a_fraction_of_a_world_is_shown_as_one():
  out = io.StringIO()
  with reporter("export", stream=out, interactive=False, min_seconds=0) as report:
    report(Progress("writing USD", 0.0, 1, 0))
    report(Progress("writing USD", 0.5, 1, 0))
  assert "writing USD 0.5/1 worlds (50%)" in out.getvalue().splitlines()[1]


def test_a_report_note_follows_the_rate():
  out = io.StringIO()
  with reporter("solve", stream=out, interactive=False, min_seconds=0) as report:
    report(Progress("solving", 0, 10, 0, note="best world 3: 1 of 2 met"))
    report(Progress("solving", 5, 10, 5000, note="best world 7: 2 of 2 met"))
  lines = out.getvalue().splitlines()
  assert lines[0].endswith("; best world 3: 1 of 2 met"), lines
  assert "refinements (50%)" in lines[1] and lines[1].endswith("; best world 7: 2 of 2 met"), lines
  out = io.StringIO()
  with reporter("solve", stream=out, interactive=True) as report:
    report(Progress("solving", 5, 10, 5000, note="best world 7: 2 of 2 met"))
  assert "best world 7: 2 of 2 met" in out.getvalue()


def test_bar_completes_when_the_last_report_fell_short():
  out = io.StringIO()
  with reporter("refine", stream=out, interactive=True) as report:
    report(Progress("refining", 2.5, 64, 100))
  assert "64/64" in out.getvalue().split("\r")[-1]


def test_sampler_and_refinement_report_every_phase(tiny_native):
  seen = []
  bank, _ = tiny_native.run(6, jax.random.key(0), progress=seen.append)
  phases = [p.phase for p in seen]
  # Contact events are found inside the simulation's steps: no phase of their own.
  assert "simulating" in phases and phases[-1] == "compressing" and seen[-1].done == 6
  assert "contact events" not in phases and bank.events.ticks_per_frame > 1
  for phase in ("simulating", "compressing"):
    done = [p.done for p in seen if p.phase == phase]
    assert done[-1] == 6 and all(b >= a for a, b in zip(done, done[1:]))
  refined = []
  mwbx.refine(bank, 2, bank.objects and next(iter(bank.objects)), t_min=0.05, n_samples=3,
              key=jax.random.key(1), backend="native", progress=refined.append)
  assert [p.phase for p in refined][-1] == "compressing"
  moving = [p.done for p in refined if p.phase == "refining"]
  assert moving and 0 < max(moving) <= 3 and all(b >= a for a, b in zip(moving, moving[1:]))


def test_first_ctrl_c_is_taken_at_the_next_report_and_a_second_at_once():
  """`mwbx sample`, `refine` and `solve` report through this: a SIGINT inside
  JAX's tracing could surface as another error, so the first one waits for
  the next report; a second one interrupts where it lands."""
  import signal

  import pytest

  from mwbx import cli
  previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # (the suite may ignore SIGINT)
  try:
    with cli._reporter_with_safe_points("solve") as update:
      update(Progress("solving", 0, 4, 0))
      signal.raise_signal(signal.SIGINT)  # no KeyboardInterrupt here
      with pytest.raises(KeyboardInterrupt):
        update(Progress("solving", 1, 4, 10))
    with cli._reporter_with_safe_points("refine"):
      signal.raise_signal(signal.SIGINT)
      with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
  finally:
    signal.signal(signal.SIGINT, previous)
