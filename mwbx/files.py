"""Files written whole or not at all.

A reader (another process, or this one after a crash) sees either the old
file or the new one, never a half-written one: the text goes to a temporary
file beside the target, is flushed to disk, and is renamed over it (atomic
on POSIX). A failed write (a full disk) removes the temporary file and is
one :class:`~mwbx.errors.MwbxError` naming the file.
"""

from __future__ import annotations

import errno
import os
import pathlib
import uuid

from mwbx.errors import MwbxError


def fsync_dir(path: str | os.PathLike) -> None:
  """Flushes a directory's entries (a rename in it) to disk."""
  fd = os.open(path, os.O_RDONLY)
  try:
    os.fsync(fd)
  finally:
    os.close(fd)


def why(err: OSError) -> str:
  """A short reason for an OSError, saying so plainly when the disk is full."""
  if err.errno in (errno.ENOSPC, errno.EDQUOT):
    return "no space left on device"
  if err.errno == errno.EFBIG:
    return "file too large (a file size limit was reached)"
  return err.strerror or str(err)


def write_fsynced(path: pathlib.Path, data: bytes) -> None:
  """Writes ``data`` to ``path`` and flushes it to disk (no rename)."""
  with open(path, "wb") as f:
    f.write(data)
    f.flush()
    os.fsync(f.fileno())


def write_atomic(path: str | os.PathLike, data: bytes | str, what: str = "file") -> pathlib.Path:
  """Replaces ``path`` by ``data`` atomically; returns the path.

  Args:
    path: the file (its folder is created).
    data: bytes, or text (written as UTF-8).
    what: what the file is, for the error message (e.g. ``query file``).

  Raises:
    MwbxError: naming the file when it cannot be written; the old file (if
      any) is left as it was and no temporary file stays.
  """
  path = pathlib.Path(path)
  if isinstance(data, str):
    data = data.encode()
  tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:12]}"
  try:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_fsynced(tmp, data)
    os.replace(tmp, path)
    fsync_dir(path.parent)
  except OSError as err:
    remove_quietly(tmp)
    raise MwbxError(f"{path}: cannot write {what} ({why(err)}); the previous file is unchanged") from None
  return path


def remove_quietly(tmp: pathlib.Path) -> None:
  """Removes a temporary file or folder, quietly (it may not exist)."""
  import shutil
  try:
    if tmp.is_dir():
      shutil.rmtree(tmp, ignore_errors=True)
    else:
      tmp.unlink(missing_ok=True)
  except OSError:
    pass
