"""Sampling one bank with many processes (hosts): who samples which worlds.

``mwbx sample … --num-processes N --process-id I --coordinator HOST:PORT``
(or ``--distributed``, where ``jax.distributed.initialize()`` finds them
itself, e.g. under Slurm) joins a ``jax.distributed`` group only to agree on
the run: process 0 reads the bank's manifest and decides the world ids and
the seed (a new run, or the unfinished worlds of a killed one), publishes
that plan in the coordinator's key-value store, and every process takes its
contiguous share of the ids. Then the group is left again (shut down): the
processes sample independently, each writing its own shards into the shared
bank directory (manifest updates are serialised by a file lock), so a
worker that dies holds nobody up and its finished shards stay. A world
depends only on the seed and its id, so the merged bank equals a
single-process run with the same seed.

Joining waits at most ``timeout`` seconds for the others (and for the plan);
where they do not come, jax ends the process (after the line saying what it
waited for).
"""

from __future__ import annotations

import json
import sys
from typing import Mapping, NamedTuple

import numpy as np

from mwbx.errors import MwbxError

PLAN_KEY = "mwbx/sample-plan"


class ProcessGroup(NamedTuple):
  """This process's place among the sampling processes.

  Attributes:
    process_id: 0 … num_processes - 1; process 0 plans the run.
    num_processes: how many processes share the run.
  """

  process_id: int = 0
  num_processes: int = 1

  @property
  def leader(self) -> bool:
    return self.process_id == 0


def join(coordinator: str | None, num_processes: int | None, process_id: int | None, *,
         auto: bool = False, timeout: int = 300, flags: Mapping[str, str] | None = None) -> ProcessGroup:
  """Joins the ``jax.distributed`` group (or stays alone).

  Args:
    coordinator: ``HOST:PORT`` of process 0's coordinator.
    num_processes, process_id: this group's size and this process's index.
    auto: let ``jax.distributed.initialize()`` detect all three (Slurm, MPI).
    timeout: seconds to wait for the other processes.
    flags: how the caller spells ``coordinator``, ``num_processes`` and
      ``process_id``, for messages (e.g. ``{"process_id": "--process-id"}``);
      default: as here.

  Returns:
    the group; ``ProcessGroup()`` (alone) when nothing was asked.
  """
  if not auto and (num_processes is None or num_processes <= 1):
    return ProcessGroup()
  import jax
  named = {name: (flags or {}).get(name, name) for name in ("coordinator", "num_processes", "process_id")}
  if not auto:
    if coordinator is None or process_id is None:
      raise MwbxError(f"{named['num_processes']}: also give {named['process_id']} and"
                      f" {named['coordinator']} HOST:PORT")
    if not 0 <= process_id < num_processes:
      raise MwbxError(f"{named['process_id']}: must be in 0..{num_processes - 1}, got {process_id}")
  kwargs = {} if auto else dict(coordinator_address=coordinator, num_processes=num_processes,
                                process_id=process_id)
  if not auto and process_id == 0:
    kwargs["coordinator_bind_address"] = coordinator
  # jax ends the process (abort) when the others do not come in time: say first what it waits for.
  print(f"mwbx: joining {num_processes or 'the'} sampling processes at {coordinator or 'the detected coordinator'}"
        f" (waiting up to {timeout} s)", file=sys.stderr, flush=True)
  try:
    jax.distributed.initialize(**kwargs, initialization_timeout=timeout)
  except Exception as err:  # noqa: BLE001 - jax raises RuntimeError/ValueError/XlaRuntimeError here
    raise MwbxError(f"{named['coordinator']}: could not join the {num_processes or ''} sampling processes"
                    f" within {timeout} s ({str(err).strip().splitlines()[0][:200]})") from None
  return ProcessGroup(jax.process_index(), jax.process_count())


def share_plan(group: ProcessGroup, plan: dict | None, timeout: int = 300) -> dict:
  """Process 0 gives ``plan`` (JSON), the others receive it; all then leave
  the group (no collective runs after this, so no process waits on another)."""
  if group.num_processes == 1:
    return plan
  import jax
  from jax._src import distributed as jax_distributed
  client = jax_distributed.global_state.client
  try:
    if group.leader:
      client.key_value_set(PLAN_KEY, json.dumps(plan))
    else:
      plan = json.loads(client.blocking_key_value_get(PLAN_KEY, timeout * 1000))
  except Exception as err:  # noqa: BLE001
    raise MwbxError(f"process {group.process_id}: no run plan from process 0 within {timeout} s"
                    f" ({str(err).strip().splitlines()[0][:200]})") from None
  jax.distributed.shutdown()
  return plan


def my_share(ids: np.ndarray, group: ProcessGroup) -> np.ndarray:
  """i64[k] this process's contiguous share of the run's ids (sorted)."""
  ids = np.sort(np.asarray(ids, np.int64))
  return np.array_split(ids, group.num_processes)[group.process_id]
