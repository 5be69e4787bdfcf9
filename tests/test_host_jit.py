"""mwbx's compiled kernels are kept by package path and source content, so
another clone of the same code on the machine loads them."""

import os
import shutil
import subprocess
import sys

import numba.core.caching as caching

import mwbx
from mwbx import host_jit
from mwbx.batch_sim import host_bookkeeping


def test_kernels_are_kept_outside_the_clone_by_package_path():
  if os.environ.get("NUMBA_CACHE_DIR"):
    return  # numba's own choice then
  locator = caching.CacheImpl._locator_classes[0]
  py_func = host_bookkeeping.fold_in.py_func
  found = locator.from_function(py_func, host_bookkeeping.__file__)
  assert found is not None
  assert found.get_cache_path() == os.path.join(host_jit.CACHE_DIR, "mwbx", "batch_sim")
  assert not found.get_cache_path().startswith(os.path.dirname(mwbx.__file__))
  assert locator.from_function(py_func, caching.__file__) is None  # other packages: numba's own locators


def test_a_copy_of_the_package_elsewhere_loads_the_kept_code(tmp_path):
  """The same source in two folders: the second compiles nothing."""
  home = tmp_path / "home"
  code = ("import numpy as np; from mwbx.batch_sim import host_bookkeeping as h;"
          "h.body_step_uniforms(1, 2, 3, 4, np.zeros(6, np.float32));"
          "print(h.body_step_uniforms.stats.cache_hits)")
  hits = []
  for clone in ("a", "b"):
    shutil.copytree(os.path.dirname(mwbx.__file__), tmp_path / clone / "mwbx",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "HOME": str(home), "PYTHONPATH": str(tmp_path / clone)}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path / clone, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    hits.append(out.stdout.strip())
  assert hits[0] == "Counter()"  # compiled in the first clone
  assert hits[1] != "Counter()"  # loaded in the second
