"""A shard's ``.npy`` files, read in one system call each.

A bank opens by reading a dozen small arrays of every shard (ids, flags,
metrics, events, ...): thousands of files for a large bank, where
``np.load``'s several reads per file and its header parsing (``ast``) cost
more than the bytes. :func:`read` reads the whole file into one buffer and
parses the header numpy writes (format 1.0, C order, a number or bool dtype)
with a pattern; any other file, or one whose size disagrees with its header,
goes to ``np.load(allow_pickle=False)``, which reads it or raises as before.
"""

from __future__ import annotations

import math
import os
import re

import numpy as np

MAGIC = b"\x93NUMPY\x01\x00"  # format 1.0: a 2-byte header length follows
HEADER = re.compile(r"\{'descr': '([<>|][biufc][0-9]+)', 'fortran_order': False, 'shape': \(((?:[0-9]+, ?)*[0-9]*)\), \} *\n")


def read(path: str | os.PathLike) -> np.ndarray:
  """The array of the ``.npy`` file ``path``, as ``np.load(path, allow_pickle=False)``
  returns it (writable, its own memory).

  Example:
    >>> ids = read("out/quick/shards/000000/world_ids.npy")
  """
  with open(path, "rb") as f:
    buf = bytearray(os.fstat(f.fileno()).st_size)
    complete = f.readinto(buf) == len(buf)
  if complete and buf[:len(MAGIC)] == MAGIC and len(buf) >= len(MAGIC) + 2:
    start = len(MAGIC) + 2 + int.from_bytes(buf[len(MAGIC):len(MAGIC) + 2], "little")
    match = HEADER.fullmatch(buf[len(MAGIC) + 2:start].decode("latin-1"))
    if match:
      dtype = np.dtype(match.group(1))
      shape = tuple(int(n) for n in match.group(2).replace(" ", "").split(",") if n)
      count = math.prod(shape)
      if start + count * dtype.itemsize == len(buf):
        return np.frombuffer(buf, dtype, count, start).reshape(shape)
  return np.load(path, allow_pickle=False)
