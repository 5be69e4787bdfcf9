"""The one exception type users of mwbx catch."""


class MwbxError(ValueError):
  """A problem the user can fix: bad config, unknown name, corrupt bank.

  The message names the file, field or value at fault.
  """
