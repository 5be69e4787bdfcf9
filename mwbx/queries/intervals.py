"""Closed intervals with optional open ends, as query fields spell them.

A query's ``window`` (seconds) and a joint query's ``turn`` (radians or
metres) are ``[lo, hi]`` pairs where ``None`` (YAML ``null``) leaves that end
open; both are checked here, with messages naming the query and the field.
A window is also bounded (:func:`checked_window`): every query kind reads it
through that one check, so a time that no frame index can hold (``.inf``,
``1e300``, a negative one) is refused where it enters, not deep inside an
evaluation.
"""

from __future__ import annotations

import math

from mwbx.errors import MwbxError
from mwbx.yaml_input import short_repr

# Largest time a query window may name, seconds (about 31 years): far past any
# world's end, and small enough that a time times any frame rate stays an
# exact frame index.
MAX_SECONDS = 1e9


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


def checked_window(label: str, value) -> tuple[float | None, float | None] | None:
  """A query's ``window`` as ``(t0, t1)`` seconds, or None (the whole world).

  Every query kind checks its window here (screen and world boxes, joint,
  orientation, touch and order queries), from files and from Python alike.

  Args:
    label: the query, for messages (``query 'name'``).
    value: None, or a pair of times in seconds, either one None (open).

  Raises:
    MwbxError: one line naming the field and the value: not a pair of
      numbers, an end that is not a finite number from 0 to
      :data:`MAX_SECONDS`, or t0 > t1.
  """
  if value is None:
    return None
  lo, hi = checked_interval(label, "window", value, ("t0", "t1"), "seconds")
  for end, t in (("t0", lo), ("t1", hi)):
    if t is not None and not (math.isfinite(t) and 0.0 <= t <= MAX_SECONDS):
      raise MwbxError(f"{label}: window {end} must be a finite time from 0 to {MAX_SECONDS:g} seconds"
                      f" (null for open), got {short_repr(value, 80)}")
  return lo, hi
