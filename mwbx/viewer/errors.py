"""The viewer's error type: mistakes a user can make when asking for a view."""

from __future__ import annotations

try:  # The package-wide base class.
  from mwbx.errors import MwbxError as _Base
except ImportError:  # pragma: no cover - before mwbx/errors.py exists
  _Base = ValueError


class ViewerError(_Base):
  """A bad argument to `view`/`export_html` (unknown world, layout, body, query...).

  The message names the argument and the offending value.
  """
