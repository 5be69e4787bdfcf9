"""Checksums of saved arrays and one-line errors from storage libraries."""

from __future__ import annotations

import zlib

import numpy as np

from mwbx.errors import MwbxError


def crc32(array) -> int:
  """CRC32 of an array's bytes (C order)."""
  return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1))


def mismatched(arrays: dict, checksums: dict) -> list[str]:
  """Names of the arrays whose bytes differ from ``checksums`` (or are missing)."""
  return sorted(name for name, crc in checksums.items()
                if name not in arrays or crc32(np.asarray(arrays[name])) != int(crc))


def verify(where, arrays: dict, checksums: dict | None) -> None:
  """MwbxError naming every array of ``where`` whose bytes changed since saved
  (no checksums: nothing to check)."""
  if not checksums:
    return
  bad = mismatched(arrays, checksums)
  if bad:
    raise MwbxError(f"{where}: corrupt bank: checksum mismatch in {', '.join(bad)}"
                    f" (the saved data changed since it was written)")


def first_line(err: Exception, limit: int = 200) -> str:
  """The gist of a library's error: its first line, without the spec dumps
  tensorstore appends, cut to ``limit`` characters."""
  text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
  for cut in (" [source locations", " {\"", " {'"):
    text = text.split(cut)[0]
  return text if len(text) <= limit else text[:limit - 1] + "…"
