"""Compile the codec's kernels in a second process while the first compiles its own.

On a machine that never ran mwbx, a first ``mwbx sample`` compiles the native
loop (about 10 s on 2 cores) and then, at its first compression, the codec's
kernels (about 10 s more), one after the other. Numba compiles holding the
GIL, so a thread would not overlap them; a second process does: it
compresses and decodes a few short worlds of the same scene (stepped from
its initial state with small random velocities, so every channel moves),
which compiles the codec's kernels for the signatures sampling uses into
numba's on-disk cache (:mod:`mwbx.host_jit`), where the sampling process then
finds them. Started only while the codec's kernels are not in that cache.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys

import mujoco
import numpy as np
from numba.core import caching

from mwbx import host_jit
from mwbx.bank.stores import store_for

WORLDS, FRAMES = 2, 24


def codec_cached() -> bool:
  """Whether the codec's kernels are in mwbx's numba cache for these sources
  and this numba (or numba keeps them elsewhere): an index written by another
  version of the package is stale, and numba would compile again."""
  if os.environ.get("NUMBA_CACHE_DIR"):
    return True
  stamp = host_jit.package_source_hash()
  return any(_index_is_fresh(path, stamp)
             for path in glob.glob(os.path.join(host_jit.CACHE_DIR, "mwbx", "codec", "*.nbi")))


def _index_is_fresh(path: str, stamp: bytes) -> bool:
  """Whether numba would load kernels from the cache index ``path``
  (``.nbi``) for sources of ``stamp``: numba's own reader, which finds
  nothing in an index of another numba or other sources."""
  folder, name = os.path.split(path)
  try:
    return bool(caching.IndexDataCacheFile(folder, name[:-len(".nbi")], stamp)._load_index())
  except Exception:  # a torn file, or numba's internals moved: not warm (the warm-up runs)
    return False


def start(config_path: str | os.PathLike) -> subprocess.Popen | None:
  """Compiles the codec's kernels for the scene of ``config_path`` in a
  background process, unless they are cached; returns it (or None)."""
  if codec_cached():
    return None
  try:
    return subprocess.Popen([sys.executable, "-m", "mwbx.bank.warm", os.fspath(config_path)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
  except OSError:
    return None


def compress_a_few_worlds(scene) -> None:
  """Compresses and decodes WORLDS short worlds of ``scene`` (compiling the codec)."""
  model = scene.model
  data = mujoco.MjData(model)
  rng = np.random.default_rng(0)
  qpos = np.zeros((WORLDS, FRAMES, model.nq), np.float32)
  for w in range(WORLDS):
    mujoco.mj_resetData(model, data)
    data.qvel[:] = rng.normal(0.0, 0.3, model.nv)
    for t in range(FRAMES):
      qpos[w, t] = data.qpos
      mujoco.mj_step(model, data)
  store = store_for(scene)
  store.append(qpos, np.full(WORLDS, FRAMES, np.int32))
  store.row_frames(0)


def main(argv: list[str]) -> int:
  from mwbx.config import load_config  # lazy: only the background process needs these two
  from mwbx.scene import Scene  # lazy: as above
  compress_a_few_worlds(Scene(load_config(argv[0])))
  return 0


if __name__ == "__main__":
  sys.exit(main(sys.argv[1:]))
