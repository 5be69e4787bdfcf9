"""Many processes sample one bank: `mwbx sample --num-processes 2` on this
machine (jax.distributed over gloo on CPU, a fresh port per test), merged
bank equal to a one-process run; a killed worker holds nobody up, and the
same commands resume its worlds."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np

import mwbx
from test_shards import same_worlds

REPO = pathlib.Path(__file__).resolve().parents[2]
TINY = REPO / "tests" / "refine_scenes" / "tiny.yaml"
N_WORLDS = 24


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


def _workers(out: pathlib.Path, n: int = 2, chunk: int = 2):
  port = _free_port()
  return [subprocess.Popen(
      [sys.executable, "-m", "mwbx.cli", "sample", str(TINY), "--worlds", str(N_WORLDS), "--backend", "native",
       "--chunk-size", str(chunk), "--out", str(out), "--num-processes", str(n), "--process-id", str(i),
       "--coordinator", f"127.0.0.1:{port}", "--timeout", "120"],
      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(n)]


def _wait(procs, timeout=900):
  outs = []
  for p in procs:
    try:
      outs.append(p.communicate(timeout=timeout))
    finally:
      if p.poll() is None:
        p.kill()
  return outs


def _whole():
  return mwbx.sample(mwbx.load_config(TINY), N_WORLDS, jax.random.key(0), backend="native")


def test_two_processes_make_the_bank_one_process_makes(tmp_path):
  out = tmp_path / "bank"
  procs = _workers(out)
  outs = _wait(procs)
  for p, (_, err) in zip(procs, outs):
    assert p.returncode == 0, err[-2000:]
  assert "process 0 of 2" in outs[0][1] and "process 1 of 2" in outs[1][1]
  bank = mwbx.Bank.load(out)
  runs = json.loads((out / "manifest.json").read_text())["runs"]
  assert sorted(r["process"] for r in runs) == [0, 1] and all(r["finished"] for r in runs)
  assert runs[0]["id_ranges"] != runs[1]["id_ranges"]
  same_worlds(bank._take(np.argsort(bank.world_ids)), _whole())


def test_a_killed_worker_does_not_hold_up_the_other_and_is_resumed(tmp_path):
  out = tmp_path / "bank"
  procs = _workers(out)
  try:
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and procs[1].poll() is None:  # its first shard, then kill it
      manifest = out / "manifest.json"
      if manifest.exists() and any(e.get("worlds") and r.get("process") == 1
                                   for r in json.loads(manifest.read_text())["runs"]
                                   for e in json.loads(manifest.read_text())["shards"]):
        break
      time.sleep(0.01)
    os.kill(procs[1].pid, signal.SIGKILL)
    (_, err0), _ = _wait(procs)
  finally:
    for p in procs:
      if p.poll() is None:
        p.kill()
  assert procs[0].returncode == 0, err0[-2000:]  # the survivor finished its share
  runs = json.loads((out / "manifest.json").read_text())["runs"]
  assert [r["finished"] for r in sorted(runs, key=lambda r: r["process"])] == [True, False]
  partial = mwbx.Bank.load(out)
  assert 0 < partial.n_worlds < N_WORLDS
  outs = _wait(_workers(out))  # the same commands again
  assert "resuming:" in outs[0][1], outs[0][1][-2000:]
  bank = mwbx.Bank.load(out)
  assert bank.n_worlds == N_WORLDS
  same_worlds(bank._take(np.argsort(bank.world_ids)), _whole())


def test_a_missing_worker_ends_the_wait(tmp_path):
  """Process 0 alone: it says what it waits for and ends (jax aborts) after --timeout."""
  port = _free_port()
  result = subprocess.run(
      [sys.executable, "-m", "mwbx.cli", "sample", str(TINY), "--worlds", "4", "--out", str(tmp_path / "b"),
       "--num-processes", "2", "--process-id", "0", "--coordinator", f"127.0.0.1:{port}", "--timeout", "5"],
      capture_output=True, text=True, timeout=600)
  assert result.returncode != 0
  assert "joining 2 sampling processes" in result.stderr and "waiting up to 5 s" in result.stderr
  assert not (tmp_path / "b").exists()  # nothing written
