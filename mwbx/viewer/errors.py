"""The viewer's error type: mistakes a user can make when asking for a view."""

from __future__ import annotations

from mwbx.errors import MwbxError


class ViewerError(MwbxError):
  """A bad argument to `view`/`export_html` (unknown world, layout, body, query...).

  The message names the argument and the offending value.
  """
