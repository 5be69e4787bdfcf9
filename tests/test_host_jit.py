"""mwbx's compiled kernels are kept by package path and source content, so
another clone of the same code on the machine loads them."""

import os
import pickle
import shutil
import subprocess
import sys
from typing import NamedTuple

import numba
import numpy as np
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


def test_the_codec_warms_up_in_a_second_process_only_when_not_cached(tmp_path):
  """`mwbx sample` starts `python -m mwbx.bank.warm CONFIG` on a machine without the codec's kernels cached:
  it compresses a few worlds of the scene, leaving them in the cache, after which it is not started again."""
  from mwbx.bank import warm
  home = tmp_path / "home"
  env = {**os.environ, "HOME": str(home)}
  env.pop("NUMBA_CACHE_DIR", None)
  config = os.path.join(os.path.dirname(os.path.dirname(mwbx.__file__)), "configs", "quickstart.yaml")
  check = ("from mwbx.bank import warm; p = warm.start({!r}); print(warm.codec_cached(), p is None)\n"
           "if p is not None:\n  p.kill(); p.wait()").format(config)
  before = subprocess.run([sys.executable, "-c", check], env=env, capture_output=True, text=True, timeout=600)
  assert before.stdout.split() == ["False", "False"], before.stderr  # not cached: started
  done = subprocess.run([sys.executable, "-m", "mwbx.bank.warm", config], env=env, capture_output=True, text=True,
                        timeout=1200)
  assert done.returncode == 0, done.stderr
  assert any(name.endswith(".nbi") for name in os.listdir(home / ".cache" / "mwbx" / "numba" / "mwbx" / "codec"))
  after = subprocess.run([sys.executable, "-c", check], env=env, capture_output=True, text=True, timeout=600)
  assert after.stdout.split() == ["True", "True"], after.stderr
  assert warm.WORLDS >= 2


def test_a_codec_cache_of_other_sources_or_another_numba_is_not_taken_as_warm(tmp_path, monkeypatch):
  """After an upgrade the old indexes are still on disk; numba finds them
  stale and compiles, so the warm-up must run again (indexes written as
  numba writes them: its version, then the pickled (stamp, overloads))."""
  from mwbx.bank import warm
  monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
  monkeypatch.setattr(host_jit, "CACHE_DIR", str(tmp_path))
  folder = tmp_path / "mwbx" / "codec"
  folder.mkdir(parents=True)

  def index(stamp, version=numba.__version__):  # one kept overload, as numba writes it
    with open(folder / "eval_kernels.eval_linear-24.py312.nbi", "wb") as f:
      pickle.dump(version, f)
      f.write(pickle.dumps((stamp, {("(float64,)", "cpu"): "eval_kernels.eval_linear-24.py312.1.nbc"})))

  assert not warm.codec_cached()  # nothing kept
  index(b"the sources of another version")
  assert not warm.codec_cached()
  index(host_jit.package_source_hash(), version="0.0.1")
  assert not warm.codec_cached()
  (folder / "eval_kernels.eval_linear-24.py312.nbi").write_bytes(b"torn")
  assert not warm.codec_cached()
  index(host_jit.package_source_hash())
  assert warm.codec_cached()


def test_a_change_anywhere_in_the_package_recompiles_every_kernel(tmp_path):
  """numba inlines callees from other modules (compiled_world's loop calls
  host_bookkeeping's) and freezes module constants: a kernel's kept code is
  stale when any source of the package changes, not only its own file."""
  clone = tmp_path / "clone"
  shutil.copytree(os.path.dirname(mwbx.__file__), clone / "mwbx", ignore=shutil.ignore_patterns("__pycache__"))
  code = ("import numba.core.caching as c; from mwbx.batch_sim import compiled_world as w;"
          "print(c.CacheImpl._locator_classes[0].from_function(w.run_world.py_func, w.__file__)"
          ".get_source_stamp().hex())")
  env = {**os.environ, "HOME": str(tmp_path / "home"), "PYTHONPATH": str(clone)}
  env.pop("NUMBA_CACHE_DIR", None)
  stamp = lambda: subprocess.run([sys.executable, "-c", code], env=env, cwd=clone, capture_output=True, text=True,
                                 timeout=600, check=True).stdout.strip()
  before = stamp()
  assert before == stamp()  # the same sources: the same stamp
  with open(clone / "mwbx" / "batch_sim" / "host_bookkeeping.py", "a") as f:
    f.write("\n# changed\n")
  assert stamp() != before  # a callee's file changed: the caller's code is recompiled too


class _Nested(NamedTuple):
  values: np.ndarray
  scale: float
  inner: tuple


@numba.njit
def _sum_borrowed(nested):
  view = host_jit.borrowed(nested)  # the same memory, no owner
  view.inner[0][0] = 7.0  # writes reach the caller's array
  total = 0.0
  for i in range(view.values.size):
    total += view.values[i]
  scratch = (np.arange(3.0),)
  (borrowed_scratch,) = host_jit.borrowed(scratch)
  total += borrowed_scratch.sum()
  host_jit.held(scratch)  # scratch freed after this, never before its borrowed view's last use
  return total * view.scale


def test_borrowed_arrays_are_the_callers_memory_and_held_scratch_lives_on():
  """What a kernel reads and writes through borrowed arrays (nested tuples
  included) is the caller's memory; a kernel's own array borrowed and held
  to the end is still there when read (what it saves, the atomic reference
  counting at every call, shows in scripts/bench_sampler.py)."""
  values, inner = np.arange(5.0), np.zeros(2)
  nested = _Nested(values, 2.0, (inner,))
  assert _sum_borrowed(nested) == (10.0 + 3.0) * 2.0
  assert inner[0] == 7.0
