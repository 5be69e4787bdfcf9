"""Closed intervals with optional open ends, as query fields spell them.

A query's ``window`` (seconds) and a joint query's ``turn`` (radians or
metres) are ``[lo, hi]`` pairs where ``None`` (YAML ``null``) leaves that end
open; both are checked here, with messages naming the query and the field.
"""

from __future__ import annotations

import math

from mwbx.errors import MwbxError


def checked_interval(label: str, field: str, value, ends: tuple[str, str] = ("lo", "hi"),
                     unit: str = "") -> tuple[float | None, float | None]:
  """``value`` as ``(lo, hi)`` floats (None for an open end).

  Args:
    label: the query, for messages (``query 'name'``).
    field: the field's name (``window``).
    value: a pair of numbers or None.
    ends: how messages call the two ends (``("t0", "t1")``).
    unit: the unit, for messages (``"seconds"``; empty for none).

  Raises:
    MwbxError: not a pair of numbers, NaN, or lo > hi.
  """
  a, b = ends
  try:
    lo, hi = value
    lo = None if lo is None else float(lo)
    hi = None if hi is None else float(hi)
  except (TypeError, ValueError):
    unit_in = f" in {unit}" if unit else ""
    raise MwbxError(f"{label}: {field} must be [{a}, {b}]{unit_in} (null for open), got {value!r}") from None
  if any(v is not None and math.isnan(v) for v in (lo, hi)):
    raise MwbxError(f"{label}: {field} must not be NaN, got {value!r}")
  if lo is not None and hi is not None and lo > hi:
    raise MwbxError(f"{label}: {field} is empty, {a} {lo} > {b} {hi}{' ' + unit if unit else ''}")
  return lo, hi
