"""Where an export writes: a new file, or a regular file replaced whole.

Every export writes a temporary file beside its target and renames it over
the target (``os.replace``): a reader sees the old file or the new one, never
half of one. The target must be a new name or an existing regular file: a
symlink, FIFO, device, socket or directory there is refused (a rename would
replace the special file itself, e.g. ``/dev/null``), and is checked again
with ``os.lstat`` right before the rename.

Temporary files are named ``.<name>.mwbx-tmp-<host>-<pid>-<random><suffix>``
(the suffix kept: ffmpeg and USD choose the format by it). One left by a
writer that was killed (its pid no longer alive on this host) is removed by
the next export to the same target.
"""

from __future__ import annotations

import errno
import os
import pathlib
import re
import socket
import stat
import uuid

from mwbx.errors import MwbxError
from mwbx.files import fsync_dir, remove_quietly, why

# File name suffixes each writer produces (Sdf cannot export a .usdz layer).
SUFFIXES = {"npz": (".npz",), "usd": (".usd", ".usda", ".usdc"), "mp4": (".mp4",)}
_WHAT = {"npz": "an npz file", "usd": "a USD file", "mp4": "an mp4 file"}
_TMP_TAG = ".mwbx-tmp-"
# O_NOFOLLOW where the platform has it: a temp name never opens a symlink.
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)


def _host() -> str:
  """This machine's name as temp names carry it (pids are only alive on one host)."""
  return re.sub(r"[^A-Za-z0-9]", "", socket.gethostname())[:32] or "host"


def _kind_of(mode: int) -> str:
  """What a non-regular file is, for an error message."""
  for test, name in ((stat.S_ISLNK, "a symlink"), (stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                     (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                     (stat.S_ISSOCK, "a socket")):
    if test(mode):
      return name
  return "not a regular file"


def _label(path: pathlib.Path, flag: str | None) -> str:
  return f"{flag}: {path}" if flag else str(path)


def refuse_special(path: pathlib.Path, flag: str | None = None) -> None:
  """MwbxError unless ``path`` is missing or a regular file (a symlink is not followed)."""
  try:
    mode = os.lstat(path).st_mode
  except (FileNotFoundError, NotADirectoryError):
    return  # nothing there; a parent that is no folder is check_folder's to name
  except OSError as err:
    raise MwbxError(f"{_label(path, flag)}: cannot check the target ({why(err)})") from None
  if not stat.S_ISREG(mode):
    raise MwbxError(f"{_label(path, flag)}: is {_kind_of(mode)}; an export writes a new file or replaces "
                    "a regular file only")


def check_target(path: str | os.PathLike, kind: str, flag: str | None = None) -> pathlib.Path:
  """Checks that export ``kind`` (npz, usd, mp4) may write ``path``; returns it.

  Nothing is created: the file name's suffix must match the format and what
  is at ``path`` must be nothing or a regular file.

  Args:
    path: the target file.
    kind: ``npz``, ``usd`` or ``mp4``.
    flag: the command-line flag that named it, for the error message.

  Raises:
    MwbxError: one line naming the flag or file at fault.
  """
  path = pathlib.Path(path)
  suffixes = SUFFIXES[kind]
  if path.suffix.lower() not in suffixes:
    raise MwbxError(f"{_label(path, flag)}: {_WHAT[kind]} name ends in {', '.join(suffixes)}")
  refuse_special(path, flag)
  return path


def _alive(pid: int) -> bool:
  """Whether process ``pid`` runs on this host (another user's counts)."""
  try:
    os.kill(pid, 0)
  except ProcessLookupError:
    return False
  except (PermissionError, OverflowError, ValueError):
    return pid > 0  # someone else's process, or a pid no kill takes
  return True


def _tmp_pattern(path: pathlib.Path) -> re.Pattern:
  return re.compile(rf"\.{re.escape(path.name)}{re.escape(_TMP_TAG)}{re.escape(_host())}-(\d+)-[0-9a-f]{{8}}"
                    rf"{re.escape(path.suffix)}")


def remove_stale_temps(path: pathlib.Path) -> None:
  """Removes temporary files of ``path`` that writers on this host left when
  they were killed (their pid no longer alive); regular files only."""
  pattern = _tmp_pattern(path)
  try:
    names = os.listdir(path.parent)
  except OSError:
    return
  for name in names:
    match = pattern.fullmatch(name)
    if match is None or _alive(int(match.group(1))):
      continue
    stale = path.parent / name
    try:
      if stat.S_ISREG(os.lstat(stale).st_mode):
        os.unlink(stale)
    except OSError:
      pass  # another export removed it first, or the folder is read-only: harmless


def check_folder(path: str | os.PathLike, flag: str | None = None) -> None:
  """Checks, creating nothing that stays, that a file can be made at ``path``:
  its folder, or the nearest of its parents that exists (the export makes the
  rest), is a folder that takes a new file.

  Raises:
    MwbxError: one line naming the flag and the folder at fault.
  """
  path = pathlib.Path(path)
  folder = path.parent
  while not os.path.lexists(folder) and folder != folder.parent:
    folder = folder.parent
  if not folder.is_dir():
    raise MwbxError(f"{_label(path, flag)}: {folder} is not a folder")
  # A file made and removed at once: os.access answers yes to root, even on a read-only folder.
  probe = folder / f".mwbx-probe-{_host()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
  _create_new(probe, 0o600, path, flag)
  remove_quietly(probe)


def _create_new(file: pathlib.Path, mode: int, path: pathlib.Path, flag: str | None) -> None:
  """Creates the empty new ``file`` (never through a link), or raises one line
  naming ``path``'s flag and the folder that would not take it."""
  try:
    os.close(os.open(file, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, mode))
  except OSError as err:
    reason = "it takes no new files" if err.errno == errno.ENOENT else why(err)  # ENOENT: e.g. under /proc
    raise MwbxError(f"{_label(path, flag)}: cannot write in the folder {file.parent} ({reason})") from None


def reserve_temp(path: pathlib.Path, flag: str | None = None) -> pathlib.Path:
  """Creates an empty temporary file beside ``path`` and returns its path.

  Run before any work: it makes ``path``'s folder (and parents) if missing,
  proves the folder writable, and removes stale temps of ``path``.

  Raises:
    MwbxError: naming the folder when it cannot be made or written in.
  """
  folder = path.parent
  check_folder(path, flag)
  try:
    folder.mkdir(parents=True, exist_ok=True)
  except OSError as err:
    raise MwbxError(f"{_label(path, flag)}: cannot make the folder {folder} ({why(err)})") from None
  remove_stale_temps(path)
  tmp = folder / f".{path.name}{_TMP_TAG}{_host()}-{os.getpid()}-{uuid.uuid4().hex[:8]}{path.suffix}"
  _create_new(tmp, 0o666, path, flag)
  return tmp


def replace(tmp: pathlib.Path, path: pathlib.Path, what: str) -> None:
  """Renames the finished ``tmp`` over ``path`` after checking, with lstat,
  that ``path`` is still nothing or a regular file; ``tmp`` goes either way.

  Raises:
    MwbxError: naming the file when the target turned special or the rename fails.
  """
  try:
    refuse_special(path)
    os.replace(tmp, path)
  except MwbxError:
    remove_quietly(tmp)
    raise
  except OSError as err:
    remove_quietly(tmp)
    raise MwbxError(f"{path}: cannot write {what} ({why(err)})") from None
  try:
    fsync_dir(path.parent)
  except OSError:
    pass  # the rename happened; a folder that cannot be fsynced (some network mounts) keeps it


def write_bytes(path: str | os.PathLike, data: bytes, kind: str, what: str) -> pathlib.Path:
  """Writes ``data`` to ``path`` whole or not at all (checked as :func:`check_target`).

  Raises:
    MwbxError: one line naming the file or folder.
  """
  path = check_target(path, kind)
  tmp = reserve_temp(path)
  try:
    fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC | _NOFOLLOW)
    with os.fdopen(fd, "wb") as f:
      f.write(data)
      f.flush()
      os.fsync(f.fileno())
  except OSError as err:
    remove_quietly(tmp)
    raise MwbxError(f"{path}: cannot write {what} ({why(err)}); the previous file is unchanged") from None
  replace(tmp, path, what)
  return path
