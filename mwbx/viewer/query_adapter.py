"""Colour classes of worlds from mwbx.queries query objects (filled in once
mwbx.queries lands)."""

from __future__ import annotations

from mwbx.viewer.errors import ViewerError


def evaluate_classes(bank, queries):
  raise ViewerError("queries: mwbx.queries objects are not supported yet; pass "
                    "QueryVolume or (corners, include) pairs")
