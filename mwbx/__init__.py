"""mwbx: Many-Worlds Browsing on JAX and MuJoCo.

Sample thousands of plausible variations of a multibody scene, keep them in a
bank, find the world you want with queries and metrics, refine it, view it.

Example::

  import jax, mwbx
  scene = mwbx.load_config("configs/quickstart.yaml")
  bank = mwbx.sample(scene, n_worlds=1024, key=jax.random.key(0))
  bank = bank.save("out/quick")  # the bank as stored; mwbx.Bank.load("out/quick") reads it back
"""

import gc as _gc

# Importing jax, MuJoCo and numba makes millions of objects that live as long as
# the process; the collector's passes over them while they are made are a fifth of
# the import (1.5 -> 1.2 s on 2 cores), so it waits until the imports are done.
_collecting = _gc.isenabled()
_gc.disable()
try:
  # First: it tells numba where to keep compiled kernels before any is decorated.
  from mwbx import host_jit as _host_jit  # noqa: F401
  # Before anything imports mujoco: MUJOCO_GL is read when rendering, not at import.
  from mwbx import mujoco_gl as _mujoco_gl  # noqa: F401
  from mwbx.bank import Bank
  from mwbx.bank import FLAG_AT_REST
  from mwbx.bank import FLAG_CONTACT_OVERFLOW
  from mwbx.bank import FLAG_FINISHED
  from mwbx.bank import FLAG_SIM_ERROR
  from mwbx.bank import FLAG_UNSTABLE
  from mwbx.batch_sim import METRIC_NAMES
  from mwbx.batch_sim import SampleStats
  from mwbx.batch_sim import Sampler
  from mwbx.batch_sim import Hosts
  from mwbx.batch_sim import SamplingRun
  from mwbx.batch_sim import sample
  from mwbx.batch_sim import sample_run
  from mwbx.refinement import refine
  from mwbx.codec import CodecBounds
  from mwbx.codec import CodecError
  from mwbx.config import Config
  from mwbx.config import config_from_dict
  from mwbx.config import load_config
  from mwbx.errors import MwbxError
  from mwbx.queries import Camera
  from mwbx.queries import Frustum
  from mwbx.queries import JointQuery
  from mwbx.queries import OrderQuery
  from mwbx.queries import OrientationQuery
  from mwbx.queries import Query
  from mwbx.queries import QuerySet
  from mwbx.queries import ScreenBox
  from mwbx.queries import TouchQuery
  from mwbx.queries import VolumeQuery
  from mwbx.queries import constraints_satisfied
  from mwbx.queries import evaluate
  from mwbx.queries import evaluate_each
  from mwbx.queries import first_entry
  from mwbx.queries import load_queries
  from mwbx.queries import orientation_error
  from mwbx.queries import rank
  from mwbx.scene import Scene
  from mwbx.qpos_store import QposStore
  from mwbx.qpos_store import RawQposStore
  from mwbx.refinement import RefineRequest
  from mwbx.refinement import RefineStats
  from mwbx.refinement import Refinement
  from mwbx.refinement import run_refinement
finally:
  if _collecting:
    _gc.enable()

__version__ = "0.1.0"

# The viewer (meshcat), the page (viser), search (optax) and the exports (USD,
# mp4, npz; usd-core and imageio-ffmpeg on first call) load on first use:
# `import mwbx` and every CLI command that needs none of them stay fast.
_LAZY = {
    "SolveOptions": ("mwbx.search", "SolveOptions"),
    "browse": ("mwbx.browser", "browse"),
    "export_html": ("mwbx.viewer", "export_html"),
    "export_npz": ("mwbx.export", "export_npz"),
    "export_usd": ("mwbx.export", "export_usd"),
    "render_video": ("mwbx.export", "render_video"),
    "search": ("mwbx.search", None),
    "solve": ("mwbx.search", "solve"),
    "view": ("mwbx.viewer", "view"),
}


def __getattr__(name: str):
  if name not in _LAZY:
    raise AttributeError(f"module 'mwbx' has no attribute {name!r}")
  import importlib  # pylint: disable=g-import-not-at-top
  module_name, attribute = _LAZY[name]
  module = importlib.import_module(module_name)
  value = module if attribute is None else getattr(module, attribute)
  globals()[name] = value
  return value


def __dir__() -> list[str]:
  return sorted(set(globals()) | set(_LAZY))

__all__ = [
    "Bank",
    "Camera",
    "CodecBounds",
    "CodecError",
    "Config",
    "FLAG_AT_REST",
    "FLAG_CONTACT_OVERFLOW",
    "FLAG_FINISHED",
    "FLAG_SIM_ERROR",
    "FLAG_UNSTABLE",
    "Hosts",
    "Frustum",
    "JointQuery",
    "OrderQuery",
    "OrientationQuery",
    "METRIC_NAMES",
    "MwbxError",
    "QposStore",
    "Query",
    "QuerySet",
    "RawQposStore",
    "RefineRequest",
    "RefineStats",
    "Refinement",
    "SampleStats",
    "SamplingRun",
    "Sampler",
    "Scene",
    "ScreenBox",
    "SolveOptions",
    "TouchQuery",
    "VolumeQuery",
    "browse",
    "config_from_dict",
    "constraints_satisfied",
    "evaluate",
    "evaluate_each",
    "export_html",
    "export_npz",
    "export_usd",
    "first_entry",
    "load_config",
    "load_queries",
    "orientation_error",
    "rank",
    "refine",
    "render_video",
    "run_refinement",
    "sample",
    "sample_run",
    "search",
    "solve",
    "view",
]
