"""Shared fixtures: tiny scenes and samplers compiled once per test session."""

import atexit
import importlib.util
import os
import pathlib
import shutil
import tempfile

# XLA compiles the suite's programs with its optimizations mostly off: most
# of the suite's CPU time is compiling MJX steps that then run a few hundred
# steps (the MJX events test: 89 s against 66 s). Set before jax reads it, so
# that the `mwbx` commands the tests start inherit it too; a module whose
# programs run long, or whose checks depend on the shipped code's rounding,
# asks for `xla_optimized`.
os.environ.setdefault("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")

import jax  # noqa: E402
import pytest  # noqa: E402

import mwbx  # noqa: E402

# One on-disk compilation cache for this test session, shared with the `mwbx`
# commands the CLI tests start and the session's workers (they read
# MWBX_CACHE_DIR), apart from the user's own cache; the process that made it
# removes it when it exits.
if "MWBX_CACHE_DIR" not in os.environ:
  os.environ["MWBX_CACHE_DIR"] = tempfile.mkdtemp(prefix="mwbx-test-jax-cache-")
  atexit.register(shutil.rmtree, os.environ["MWBX_CACHE_DIR"], ignore_errors=True)
jax.config.update("jax_compilation_cache_dir", os.environ["MWBX_CACHE_DIR"])

TESTS = pathlib.Path(__file__).parent
REPO = TESTS.parent


def load_script(name: str):
  """``scripts/<name>.py`` as a module (the scripts are not a package)."""
  spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


@pytest.fixture(scope="module")
def xla_optimized():
  """XLA's full optimizations, as users run, for one module's compiles."""
  before = jax.config.read("jax_disable_most_optimizations")
  jax.config.update("jax_disable_most_optimizations", False)
  yield
  jax.config.update("jax_disable_most_optimizations", before)


@pytest.fixture(scope="session")
def tiny_config():
  return mwbx.load_config(TESTS / "scenes" / "tiny.yaml")


@pytest.fixture(scope="session")
def quickstart_config():
  return mwbx.load_config(REPO / "configs" / "quickstart.yaml")


@pytest.fixture(scope="session")
def tiny_native(tiny_config):
  with mwbx.Sampler(tiny_config, backend="native") as sampler:
    yield sampler


@pytest.fixture(scope="session")
def tiny_native_bank(tiny_native):
  bank, _ = tiny_native.run(32, jax.random.key(0))
  return bank


@pytest.fixture(scope="session")
def browser():
  """Skips a real-browser test, saying why, where Chromium or Playwright is missing."""
  import sys
  from mwbx.testing.headless import chromium_unavailable_reason
  reason = chromium_unavailable_reason()
  if reason is not None:
    print(f"skipping a real-browser test: {reason}", file=sys.stderr)
    pytest.skip(reason)
