"""Runs of ``mwbx sample`` in a bank directory: reserving their world ids and
telling live runs from dead ones.

A run is a record in the manifest (seed, the ids it is to produce, finished
or not) plus a liveness lock: ``BANK/runs/<run id>.lock``, ``flock``ed by the
running process for as long as it lives (the kernel releases it when the
process dies, however it dies). Planning a run happens under the bank's lock:

- a new run reserves ``n_worlds`` (``--worlds``) fresh ids (the manifest's
  ``next_id`` moves past them at once), so two runs started together sample
  disjoint ids;
- an unfinished run whose liveness lock can be taken is dead: the next run
  resumes it (samples its missing ids) and marks it superseded; an
  unfinished run whose lock is held is alive and left alone.
"""

from __future__ import annotations

import fcntl
import os
import pathlib
from typing import Mapping

import numpy as np

from mwbx.errors import MwbxError

RUNS = "runs"


def _lock_path(bank: pathlib.Path, run_id: str) -> pathlib.Path:
  return pathlib.Path(bank) / RUNS / f"{run_id}.lock"


class Liveness:
  """The held liveness lock of one run (released by :meth:`release` or at exit).

  Args:
    bank: the bank directory.
    run_id: the run record's id.
  """

  def __init__(self, bank: str | os.PathLike, run_id: str):
    self.path = _lock_path(pathlib.Path(bank), run_id)
    self.path.parent.mkdir(parents=True, exist_ok=True)
    self._file = open(self.path, "a+b")
    fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a fresh id: nobody else holds it

  def release(self) -> None:
    """Ends the run's liveness (after its record is marked finished, or on the
    way out of an interrupted run, which is then resumable)."""
    if self._file is None:
      return
    self.path.unlink(missing_ok=True)
    self._file.close()
    self._file = None


def is_live(bank: str | os.PathLike, run_id: str | None) -> bool:
  """Whether the process of run ``run_id`` still runs (holds its liveness lock).

  A run without a lock file (finished, or recorded before runs had one) is
  not live.
  """
  if not run_id:
    return False
  path = _lock_path(pathlib.Path(bank), run_id)
  try:
    f = open(path, "rb")
  except FileNotFoundError:
    return False
  with f:
    try:
      fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
      return True
    fcntl.flock(f, fcntl.LOCK_UN)
    return False


def forget(bank: str | os.PathLike, run_id: str | None) -> None:
  """Removes the lock file a dead run left behind."""
  if run_id:
    _lock_path(pathlib.Path(bank), run_id).unlink(missing_ok=True)


def id_ranges(ids: np.ndarray) -> list[list[int]]:
  """Sorted ids as [first, last] runs of consecutive ids (the manifest's form)."""
  ids = np.unique(np.asarray(ids, np.int64))
  if not ids.size:
    return []
  breaks = np.flatnonzero(np.diff(ids) != 1)
  starts = np.concatenate([[0], breaks + 1])
  ends = np.concatenate([breaks, [ids.size - 1]])
  return [[int(ids[a]), int(ids[b])] for a, b in zip(starts, ends)]


def ranges_ids(ranges) -> set[int]:
  """The ids of [first, last] ranges."""
  return {i for lo, hi in ranges for i in range(int(lo), int(hi) + 1)}


def plan(directory, template, *, n_worlds: int | None, seed: int | None, run_id: str,
         share, flags: Mapping[str, str] | None = None) -> tuple[dict, Liveness]:
  """Plans a sampling run under the bank's lock and records it (see the module).

  Args:
    directory: the :class:`~mwbx.bank.BankDirectory`.
    template: a bank of the run's scene (no worlds needed): creates the
      manifest of a new directory, and is checked against an existing one.
    n_worlds: worlds of a new run (default 256).
    seed: the run's seed (None: the bank's, or 0).
    run_id: the new run record's id.
    share: ``ids -> this process's share`` (the planning process's part of a group).
    flags: how the caller spells ``n_worlds`` and ``seed``, for messages
      (e.g. ``{"n_worlds": "--worlds", "seed": "--seed"}``); default: as here.

  Returns:
    (plan: ``seed``, ``todo`` (every id of the run, for the whole group),
    ``resume`` ([done, target] or None), ``record`` (this process's record),
    this run's held liveness lock).
  """
  flags = dict(flags or {})
  with directory._locked():
    fresh = directory.manifest is None
    directory._check_scene(template)
    manifest = directory.manifest
    bank_seed = manifest.get("run", {}).get("seed") if not fresh else None
    if seed is not None and bank_seed is not None and seed != bank_seed:
      raise MwbxError(f"{flags.get('seed', 'seed')}: {directory.path} was sampled with seed {bank_seed},"
                      f" not {seed}")
    unfinished = directory.unfinished_runs()
    live = [r for r in unfinished if is_live(directory.path, r.get("id"))]
    dead = [r for r in unfinished if r not in live]
    if dead:
      target = set().union(*(ranges_ids(r.get("group_ranges", r["id_ranges"])) for r in dead))
      busy = set().union(set(), *(ranges_ids(r.get("group_ranges", r["id_ranges"])) for r in live))
      done = directory.stored_ids() & target
      todo = sorted(target - done - busy)
      for record in dead:  # this run takes over their ids
        record.update(finished=True, superseded=True)
        forget(directory.path, record.get("id"))
      run_seed, resume = dead[-1]["seed"], [len(done), len(target)]
    else:
      n = 256 if n_worlds is None else int(n_worlds)
      if n < 1:
        raise MwbxError(f"{flags.get('n_worlds', 'n_worlds')}: must be at least 1, got {n}")
      first = int(manifest["next_id"])
      todo, resume = list(range(first, first + n)), None
      manifest["next_id"] = first + n  # reserved: no other run or save gives these ids
      run_seed = seed if seed is not None else (0 if bank_seed is None else bank_seed)
    manifest.setdefault("run", {}).setdefault("seed", run_seed)
    record = {"id": run_id, "seed": run_seed, "id_ranges": id_ranges(share(todo)),
              "group_ranges": id_ranges(todo), "finished": False}
    alive = Liveness(directory.path, run_id)  # held before the record is visible
    directory._put_run(record)
    try:
      directory.commit()
    except BaseException:
      alive.release()
      raise
  return {"seed": run_seed, "todo": todo, "resume": resume, "record": record}, alive
