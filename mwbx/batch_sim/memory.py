"""The host memory a sampling run needs, estimated before it starts.

A run that cannot fit should stop with the figure at once, not after minutes
with a ``MemoryError`` (or the kernel's OOM killer) deep inside numpy: an
``end_time`` of 1e7 s asked for a 1001 GiB chunk buffer, ``--worlds
1000000000`` for a 40 GB list of ids. The estimates count the big host arrays
(the chunk's recording buffers and their copies while compressing, the
bank's per-world arrays, the run plan's ids), not Python's overhead, so a
refusal is certain and an acceptance is a good guess.

``MWBX_MEMORY_AVAILABLE`` (bytes) stands in for the machine's available
memory (tests; or to keep a run within a share of a shared machine).
"""

from __future__ import annotations

import os

from mwbx.errors import MwbxError

ENV_AVAILABLE = "MWBX_MEMORY_AVAILABLE"
# Host bytes per world id of a run's plan: the ids as a Python list (pointer
# and int object) and as an int64 array, and the plan's JSON for other processes.
PLAN_BYTES_PER_WORLD = 64
GIB = 1 << 30


def available_bytes() -> int:
  """Memory a run may use, bytes: ``$MWBX_MEMORY_AVAILABLE``, else the
  kernel's ``MemAvailable`` (``/proc/meminfo``), else free physical pages."""
  value = os.environ.get(ENV_AVAILABLE)
  if value:
    try:
      return int(float(value))
    except ValueError:
      raise MwbxError(f"${ENV_AVAILABLE}: expected a number of bytes, got {value[:40]!r}") from None
  try:
    with open("/proc/meminfo") as f:
      for line in f:
        if line.startswith("MemAvailable:"):
          return int(line.split()[1]) * 1024
  except (OSError, ValueError, IndexError):
    pass
  try:
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
  except (ValueError, OSError, AttributeError):
    return 1 << 62  # unknown: assume it fits


def chunk_bytes(batch: int, n_frames: int, nq: int, n_bodies: int, query_stride: int, *, nbody: int,
                nstate: int, nsensordata: int, steps_per_frame: int) -> int:
  """Host bytes of one chunk's buffers while it is simulated and compressed.

  Args:
    batch: worlds simulated together.
    n_frames: recorded frames per world at most (end_frame + 1).
    nq: generalized coordinates; n_bodies: tracked bodies.
    query_stride: recorded frames per stored COM point.
    nbody: MuJoCo bodies (applied wrenches); nstate: full physics state
      size; nsensordata: sensor values; steps_per_frame: physics steps per frame.

  Returns:
    bytes: the recorded qpos f32[C, T, nq] (twice: the buffer, and the
    codec's working copy), the recorded COM f32[C, T, B, 3], its copies at
    the query rate, the per-step wrenches and sensors and the states.
  """
  qpos = 4 * batch * n_frames * nq
  com = 4 * batch * n_frames * n_bodies * 3
  com_stored = 4 * batch * (n_frames // max(query_stride, 1) + 1) * n_bodies * 3
  per_step = batch * steps_per_frame * (8 * nbody * 6 + 4 * nsensordata)
  states = 3 * 8 * batch * nstate
  return 2 * qpos + com + 3 * com_stored + per_step + states


def stored_bytes_per_world(n_frames: int, n_bodies: int, query_stride: int, n_metrics: int) -> int:
  """Host bytes a sampled world adds to an in-memory bank, at least: its COM
  polylines f32[Tq, B, 3] and metric table f32[B, M] (its compressed qpos
  comes on top, typically less)."""
  return 4 * (n_frames // max(query_stride, 1) + 1) * n_bodies * 3 + 4 * n_bodies * n_metrics + 64


def check(needed: int, what: str, advice: str) -> None:
  """Refuses a run whose estimate does not fit in the available memory.

  Args:
    needed: estimated bytes.
    what: what needs them, for the message (names the values at fault).
    advice: what to change.

  Raises:
    MwbxError: "<what> needs about X GiB of memory, but Y GiB is available; <advice>".
  """
  available = available_bytes()
  if needed > available:
    raise MwbxError(f"{what} needs about {_gib(needed)} of memory, but {_gib(available)} is available;"
                    f" {advice}")


def _gib(n: int) -> str:
  return f"{n / GIB:,.1f} GiB" if n >= GIB / 10 else f"{n / (1 << 20):,.1f} MiB"
