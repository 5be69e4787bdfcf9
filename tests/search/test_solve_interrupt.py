"""`mwbx solve` stopped by Ctrl-C keeps the refinements it finished: they are
saved to the bank as at the end of a search, and one line says what was kept
(mwbx/cli.py _cmd_solve, mwbx/search/solver.py SolveInterrupted).

Scene: tests/refine_scenes/tiny (a sphere dropped onto a resting one, a third
far away, 0.5 s); the goal asks the far sphere to fly, which no refinement
reaches, so the search runs until it is interrupted.
"""

import json
import pathlib
import re
import signal
import subprocess
import sys
import time

import jax
import pytest

import mwbx

TESTS = pathlib.Path(__file__).parents[1]

UNREACHABLE_GOAL = """\
queries:
  - name: striker_band
    region: {min: [0.114, -0.1, 0.0], max: [0.125, 0.1, 0.2]}
    bodies: [striker]
    window: [0.5, null]
  - name: far_flies
    region: {min: [1, -1, 1], max: [2, 1, 2]}
    bodies: [far]
"""
# `mwbx` with Python's own Ctrl-C handler, whatever the suite runs with (SIGINT
# may be ignored under nohup or in background jobs).
MWBX_WITH_CTRL_C = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler);"
                    " from mwbx.cli import main; sys.exit(main(sys.argv[1:]))")
# A progress line of the search: refinements done so far. Away from a terminal
# one is printed per tenth of the budget: with a time budget, after 12 s of a
# 120 s search, long before it ends.
SOLVING = re.compile(r"solve: solving (\d+)/")
KEPT = re.compile(r"mwbx: interrupted after (\d+) refinements; kept (\d+) refined worlds \(ids ([0-9., ]+)\) in (.+);"
                  r" best world so far (\d+) \((\d) of 2 queries met\)")


def _ids(spans: str) -> list[int]:
  """'8..11, 14' -> [8, 9, 10, 11, 14]."""
  out = []
  for span in spans.split(", "):
    lo, _, hi = span.partition("..")
    out.extend(range(int(lo), int(hi or lo) + 1))
  return out


@pytest.fixture
def tiny_bank_dir(tmp_path):
  with mwbx.Sampler(mwbx.load_config(TESTS / "refine_scenes" / "tiny.yaml"), backend="native") as sampler:
    bank, _ = sampler.run(8, jax.random.key(0))
  bank.save(tmp_path / "tiny")
  return tmp_path / "tiny"


def test_ctrl_c_keeps_the_refinements_done_and_says_what_it_kept(tiny_bank_dir, tmp_path):
  goal = tmp_path / "goal.yaml"
  goal.write_text(UNREACHABLE_GOAL)
  err_path = tmp_path / "solve.err"
  with open(err_path, "w") as err_file, open(tmp_path / "solve.out", "w") as out_file:
    proc = subprocess.Popen([sys.executable, "-c", MWBX_WITH_CTRL_C, "solve", str(tiny_bank_dir), str(goal),
                             "--time-budget", "120", "--samples", "4", "--backend", "native"],
                            stdout=out_file, stderr=err_file, text=True)
  try:
    deadline = time.monotonic() + 600
    done = 0
    while time.monotonic() < deadline and proc.poll() is None and done < 1:
      done = max([int(n) for n in SOLVING.findall(err_path.read_text())] or [0])
      time.sleep(0.2)
    assert proc.poll() is None, f"solve ended before it could be interrupted: {err_path.read_text()[-2000:]}"
    assert done >= 1, f"no refinement finished in time: {err_path.read_text()[-2000:]}"
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=300)
  finally:
    if proc.poll() is None:
      proc.kill()
      proc.wait()
  err = err_path.read_text()
  assert proc.returncode == 130, err[-2000:]
  assert "nothing was written" not in err, err[-2000:]
  lines = [line for line in err.splitlines() if line.startswith("mwbx: interrupted")]
  assert len(lines) == 1, err[-2000:]
  found = KEPT.fullmatch(lines[0])
  assert found, lines[0]
  refinements, kept, ids, out, best = (int(found[1]), int(found[2]), _ids(found[3]), found[4], int(found[5]))
  assert refinements >= done and kept == len(ids) >= 1 and out == str(tiny_bank_dir)
  bank = mwbx.Bank.load(tiny_bank_dir)
  refined = sorted(bank.world_ids[bank.parent_world >= 0].tolist())
  assert bank.n_worlds == 8 + kept and refined == ids
  assert best in bank.world_ids.tolist()
  history = json.loads((tmp_path / "tiny-solve.json").read_text())
  assert history["message"].startswith("not solved (interrupted;") and history["world"] == best
