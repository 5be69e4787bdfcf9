"""The files a bank's MJCF names (meshes, textures, height fields, skins,
``<model>`` files), stored in the bank: its model is built from the MJCF text
and files it stores alone, wherever it is opened.

::

  BANK/assets/<sha256>     each stored file, named by the SHA-256 of its bytes
  BANK/manifest.json       scene.mjcf_assets: {name the MJCF finds it by: sha256}

A name in the table is only a key (``meshes/tet.obj``, see
:class:`mwbx.scene.FileReference`): the file read is always
``assets/<sha256>`` in the bank's own folder, opened without following a
symbolic link (a crafted bank could point one anywhere) and checked against
its hash.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import re
import stat
from typing import Iterator, Mapping

from mwbx import files
from mwbx.errors import MwbxError
from mwbx.yaml_input import short_repr

ASSETS = "assets"
_SHA256 = re.compile(r"[0-9a-f]{64}")


def table(assets: Mapping[str, bytes]) -> dict[str, str]:
  """name -> sha256 (hex) of each file."""
  known = getattr(assets, "table", None)
  if isinstance(known, dict):  # stored already: no need to read them
    return dict(known)
  return {name: hashlib.sha256(data).hexdigest() for name, data in assets.items()}


def write(path: pathlib.Path, assets: Mapping[str, bytes]) -> dict[str, str]:
  """Stores ``assets`` in bank directory ``path`` (those it holds already
  are not written again); returns their table for the manifest."""
  out = table(assets)
  folder = pathlib.Path(path) / ASSETS
  for name, digest in out.items():
    target = folder / digest
    try:
      if stat.S_ISREG(os.lstat(target).st_mode):
        continue  # the same bytes (checked when read)
    except FileNotFoundError:
      pass
    except OSError as err:
      raise MwbxError(f"{target}: cannot store the MJCF's file {name!r} ({files.why(err)})") from None
    files.write_atomic(target, assets[name], f"the MJCF's file {name!r}")
  return out


class StoredAssets(Mapping):
  """A bank directory's stored files: name -> bytes, each read (and its hash
  checked) when first used.

  Args:
    path: the bank directory.
    table: name -> sha256, as :func:`stored` checked it.
  """

  def __init__(self, path: pathlib.Path, table: dict[str, str]):
    self.path = pathlib.Path(path)
    self.table = dict(table)
    self._read: dict[str, bytes] = {}

  def __getitem__(self, name: str) -> bytes:
    digest = self.table[name]
    if name not in self._read:
      self._read[name] = read(self.path, digest, name)
    return self._read[name]

  def __iter__(self) -> Iterator[str]:
    return iter(self.table)

  def __len__(self) -> int:
    return len(self.table)

  def __repr__(self) -> str:
    return f"StoredAssets({self.path}, {len(self)} files)"


def stored(path: pathlib.Path, raw) -> StoredAssets:
  """The files a bank directory's manifest lists (``scene.mjcf_assets``),
  read when used.

  Raises:
    MwbxError: naming the manifest's entry where it is not a name and a sha256.
  """
  raw = {} if raw is None else raw
  where = pathlib.Path(path) / "manifest.json"
  if not isinstance(raw, dict):
    raise MwbxError(f"{where}: scene.mjcf_assets: expected a mapping of file names to sha256 hashes")
  for name, digest in raw.items():
    if not name or not isinstance(digest, str) or not _SHA256.fullmatch(digest):
      raise MwbxError(f"{where}: scene.mjcf_assets[{short_repr(name)}]: {short_repr(digest)} is not a sha256"
                      f" (64 lower-case hex digits; never a path)")
  return StoredAssets(path, raw)


def read(path: pathlib.Path, digest: str, name: str) -> bytes:
  """The bytes of stored file ``assets/<digest>`` of bank directory ``path``.

  Raises:
    MwbxError: a file that is missing, not a regular file (a symbolic link,
      a FIFO), or whose bytes do not match ``digest``, naming it.
  """
  folder = pathlib.Path(path) / ASSETS
  where = folder / digest
  try:
    directory = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:  # never through a link: the bytes come from the bank's own folder
      fd = os.open(digest, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK, dir_fd=directory)
    finally:
      os.close(directory)
    with os.fdopen(fd, "rb") as f:
      if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
        raise MwbxError(f"{where}: the bank's copy of the MJCF's file {name!r} is not a regular file")
      data = f.read()
  except OSError as err:
    raise MwbxError(f"{where}: the bank's copy of the MJCF's file {name!r} cannot be read ({files.why(err)})") from None
  if hashlib.sha256(data).hexdigest() != digest:
    raise MwbxError(f"{where}: corrupt bank: the MJCF's file {name!r} does not match its checksum")
  return data


def verify(path: pathlib.Path, raw) -> list[str]:
  """One line per stored file that is missing or corrupt."""
  problems = []
  try:
    assets = stored(path, raw)
  except MwbxError as err:
    return [str(err)]
  for name in assets:
    try:
      assets[name]
    except MwbxError as err:
      problems.append(str(err))
  return problems
