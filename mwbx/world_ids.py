"""World id lists as users type them (`--worlds 3,17,20..29`, `mwbx drop BANK IDS`).

World ids are a bank's ``world_ids`` (unique within a bank forever); a range
``a..b`` includes both ends. Used by `mwbx view` and `mwbx drop`, so it sits
below both and raises :class:`~mwbx.errors.MwbxError`.
"""

from __future__ import annotations

import numpy as np

from mwbx.errors import MwbxError
from mwbx.yaml_input import short_repr

# Ids one range may name when it is not bounded by a bank's ids.
MAX_RANGE_IDS = 1_000_000


def parse_world_ids(text: str, flag: str = "text", known=None) -> list[int]:
  """'3,17, 20..22' -> [3, 17, 20, 21, 22] (``a..b`` includes both ends); the
  message names the flag and the bad item.

  Args:
    text: ids and ranges, comma separated.
    flag: how the caller names ``text``, for messages (a command line:
      ``--worlds``).
    known: optional i64[W] ids of the bank: a range then stands for the
      bank's ids within it (``0..1000000000`` is every world, not a billion
      ids); single ids are kept as given (an unknown one is an error later).
      Without it a range may hold at most :data:`MAX_RANGE_IDS` ids.
  """
  known = None if known is None else np.unique(np.asarray(known, np.int64))
  out: list[int] = []
  for item in text.split(","):
    item = item.strip()
    if not item:
      continue
    lo, dots, hi = item.partition("..")
    try:
      lo, hi = (int(lo), int(hi)) if dots else (int(item), int(item))
    except ValueError:
      raise MwbxError(f"{flag}: {short_repr(item)} is not a world id or range (expected e.g. 3,17,20..29)") from None
    if not dots:
      out.append(lo)
    elif known is not None:
      inside = known[(known >= lo) & (known <= hi)]
      if not inside.size:
        raise MwbxError(f"{flag}: the bank has no world in {lo}..{hi}")
      out.extend(int(i) for i in inside)
    elif hi - lo + 1 > MAX_RANGE_IDS:
      raise MwbxError(f"{flag}: {lo}..{hi} spans {hi - lo + 1:,} ids; at most {MAX_RANGE_IDS:,}")
    else:
      out.extend(range(lo, hi + 1))
  if not out:
    raise MwbxError(f"{flag}: no world ids in {short_repr(text)}")
  return out
