"""The MJX backend: physics against MuJoCo C, and the same sampler as native."""

import pathlib
from typing import NamedTuple

import jax
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from scipy import stats

import mwbx
from mwbx.batch_sim import mjx_collision
from test_sampler import same_world

# MJX runs in float32 against MuJoCo C's float64: over 0.21 s of falling and the
# first contacts with the upper ramp, positions agree to this many metres and
# orientations to this angle (radians; the box tumbling on the ramp is where
# the two solvers part most).
_POSITION_TOLERANCE = 2e-3
_ROTATION_TOLERANCE = 0.03
_HORIZON_STEPS = 100


def test_unperturbed_mjx_step_matches_mujoco_c(quickstart_config):
  scene = mwbx.Scene(quickstart_config)
  model = scene.model
  data = mujoco.MjData(model)
  reference, sensors, contact_steps = [], [], 0
  for _ in range(_HORIZON_STEPS):
    mujoco.mj_step(model, data)
    reference.append(data.qpos.copy())
    sensors.append(data.sensordata.copy())
    contact_steps += data.ncon > 0
  reference = np.array(reference)
  # The horizon must include contacts, or the test would only check free fall.
  assert contact_steps >= 20

  mx = mjx.put_model(model, impl="jax")
  d0 = mjx.make_data(model, impl="jax")

  def rollout(d):
    def step(d, _):
      d = mjx.step(mx, d)
      return d, (d.qpos, d.sensordata)
    return jax.lax.scan(step, d, None, length=_HORIZON_STEPS)[1]

  qpos, sensordata = (np.asarray(x) for x in jax.jit(rollout)(d0))
  free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
  for j in free:
    a = model.jnt_qposadr[j]
    np.testing.assert_allclose(qpos[:, a:a + 3], reference[:, a:a + 3], atol=_POSITION_TOLERANCE)
    q, r = qpos[:, a + 3:a + 7], reference[:, a + 3:a + 7]
    cos_half = np.abs(np.sum(q * r, axis=1)) / np.linalg.norm(q, axis=1) / np.linalg.norm(r, axis=1)
    angle = 2 * np.arccos(np.clip(cos_half, 0, 1))
    assert angle.max() < _ROTATION_TOLERANCE, (j, angle.max())
  # The observation sensors (COM positions of step k) agree as well.
  com = lambda s: s.reshape(_HORIZON_STEPS, -1, 19)[:, :, 0:3]
  np.testing.assert_allclose(com(sensordata), com(np.array(sensors)), atol=_POSITION_TOLERANCE)


@pytest.fixture(scope="module")
def paired_banks(tiny_config):
  key = jax.random.key(11)
  native = mwbx.sample(tiny_config, n_worlds=64, key=key, backend="native")
  with mwbx.Sampler(tiny_config, backend="mjx", chunk_size=8) as sampler:
    from mwbx.batch_sim.backend import Backend
    assert isinstance(sampler.backend, Backend)
    mjx_bank, _ = sampler.run(64, key)
    one, _ = sampler.run(1, key)
    seven, _ = sampler.run(7, key)
  return native, mjx_bank, one, seven


def test_mjx_worlds_do_not_depend_on_batch(paired_banks):
  _, bank64, bank1, bank7 = paired_banks
  same_world(bank1, 0, bank64, 0)
  for i in range(7):
    same_world(bank7, i, bank64, i)


def test_native_and_mjx_sample_the_same_distribution(paired_banks):
  native, mjx_bank, _, _ = paired_banks
  assert native.valid.all() and mjx_bank.valid.all()
  assert mjx_bank.perturbations.sum() > 0
  features = {
      "rest time (max over bodies)": lambda b: b.metric("rest_time").max(axis=1),
      "collisions": lambda b: b.metric("collisions").sum(axis=1),
      "path length": lambda b: b.metric("path_length").sum(axis=1),
      "final cube x": lambda b: np.array([b.com[w, b.com_count[w] - 1, 0, 0] for w in range(b.n_worlds)]),
  }
  for name, feature in features.items():
    a, b = feature(native), feature(mjx_bank)
    result = stats.ks_2samp(a, b)
    assert result.pvalue > 1e-3, f"{name}: native {np.mean(a):.3f} vs mjx {np.mean(b):.3f}, {result}"
  # The same test tells apart a sampler whose worlds differ: perturbations off
  # and no randomization collapse the distribution of final positions.
  fixed = mwbx.sample(native_config_without_noise(native), n_worlds=64, key=jax.random.key(0), backend="native")
  final_x = lambda b: np.array([b.com[w, b.com_count[w] - 1, 0, 0] for w in range(b.n_worlds)])
  assert stats.ks_2samp(final_x(native), final_x(fixed)).pvalue < 1e-3


def native_config_without_noise(bank):
  cfg = dict(bank.config)
  cfg["randomize"] = {}
  cfg["perturb"] = {**cfg["perturb"], "enabled": False}
  return mwbx.config_from_dict({k: v for k, v in cfg.items() if k != "source"}, source=bank.config["source"])


CHAIN = mwbx.load_config(pathlib.Path(__file__).parents[1] / "scenes" / "chain.yaml")


# Across per-device batch shapes XLA may round differently in the last bit and
# contacts amplify it, so there worlds agree over the first frames to this
# (m for positions, unit-quaternion components, rad), and as distributions.
_EARLY_FRAMES = 24
_EARLY_TOLERANCE = 1e-4


def _same_banks(a, b):
  for i in range(a.n_worlds):
    same_world(a, i, b, i)


def test_mjx_batches_fit_the_work():
  for chunk, n_worlds, batch in ((3, 12, 8), (16, 12, 16), (40, 12, 16), (256, 1, 8), (16, 40, 16)):
    with mwbx.Sampler(CHAIN, backend="mjx", chunk_size=chunk) as sampler:
      assert sampler.batch_size(n_worlds) == batch, (chunk, n_worlds)


CHAIN_KEY = 5


class ChainRun(NamedTuple):
  """The articulated scene's 16 worlds of ``CHAIN_KEY`` on mjx:jax in batches
  of 8, world 0 alone padded to a batch of 8, and the sampler's settings."""

  eights: mwbx.Bank
  first: mwbx.Bank
  pack_rows: bool
  backend_label: str
  batched_step: object
  n_devices: int
  batch_of_16: int


@pytest.fixture(scope="module")
def chain_eights():
  # One sampler for the batch-shape, every-row and device tests: each new one
  # traces the MJX step again (a quarter of a minute on 2 cores).
  key = jax.random.key(CHAIN_KEY)
  with mwbx.Sampler(CHAIN, backend="mjx", chunk_size=8) as sampler:
    eights, _ = sampler.run(16, key)
    first, _ = sampler.run(1, key)
    return ChainRun(eights, first, sampler.pack_rows, sampler.backend_label, sampler.backend.batched_step,
                    len(sampler.backend.devices), sampler.batch_size(16))


def test_mjx_worlds_across_batch_shapes(chain_eights):
  """An articulated scene, 16 worlds: bit-identical for the same per-device
  batch (1 world padded to 8 vs 16 in batches of 8); across batch shapes (8
  vs 16) the same over the first frames to a tolerance."""
  eights, first = chain_eights.eights, chain_eights.first
  with mwbx.Sampler(CHAIN, backend="mjx", chunk_size=16) as sampler:
    sixteen, _ = sampler.run(16, jax.random.key(CHAIN_KEY))
  assert eights.perturbations.sum() > 0
  same_world(first, 0, eights, 0)
  for w in range(16):
    np.testing.assert_allclose(sixteen.qpos_frames(w, 0, _EARLY_FRAMES), eights.qpos_frames(w, 0, _EARLY_FRAMES),
                               atol=_EARLY_TOLERANCE, rtol=0)
  for name in ("path_length", "collisions"):
    a, b = eights.metric(name).sum(1), sixteen.metric(name).sum(1)
    assert stats.ks_2samp(a, b).pvalue > 1e-3, name


def test_every_row_from_the_config(chain_eights):
  """``sim.mjx.pack_rows``: by default the sampler's batch solves each world
  over its rows in use (mjx_packed_solve); ``false`` takes MJX's solve over
  every row, and its worlds are the default step's over the first frames to
  the batch-shape tolerance (another summation order)."""
  every_cfg = CHAIN.with_overrides(mjx=CHAIN.sim.mjx.model_copy(update={"pack_rows": False}))
  assert chain_eights.pack_rows and chain_eights.backend_label == "mjx:jax"
  assert chain_eights.batched_step is mjx_collision.batched_step
  with mwbx.Sampler(every_cfg, backend="mjx", chunk_size=8) as sampler:
    assert not sampler.pack_rows and sampler.backend_label == "mjx:jax (every row)"
    every_row, _ = sampler.run(8, jax.random.key(CHAIN_KEY))
  packed = chain_eights.eights  # its first batch of 8 holds these worlds, the same bits (test above)
  assert packed.perturbations.sum() > 0
  for w in range(8):
    np.testing.assert_allclose(packed.qpos_frames(w, 0, _EARLY_FRAMES), every_row.qpos_frames(w, 0, _EARLY_FRAMES),
                               atol=_EARLY_TOLERANCE, rtol=0)


def test_mjx_shards_worlds_over_devices_bit_identically(tmp_path, chain_eights):
  """Two CPU devices (jax_num_cpu_devices = 2, in a child process): each runs
  half of a batch, and the worlds equal a one-device run of the same
  per-device batch (8) bit for bit."""
  import subprocess
  import sys
  code = f"""
import pathlib

import jax
jax.config.update("jax_num_cpu_devices", 2)
import mwbx
cfg = mwbx.load_config({str(CHAIN.source)!r})
with mwbx.Sampler(cfg, backend="mjx", chunk_size=8) as sampler:
  assert len(sampler.backend.devices) == 2 and sampler.batch_size(16) == 16
  bank, _ = sampler.run(16, jax.random.key({CHAIN_KEY}))
bank.save({str(tmp_path / "two")!r})
"""
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1200)
  assert out.returncode == 0, out.stderr[-3000:]
  two = mwbx.Bank.load(tmp_path / "two")
  assert chain_eights.n_devices == 1 and chain_eights.batch_of_16 == 8
  _same_banks(chain_eights.eights, two)


def test_ctrl_c_stops_mjx_sampling_between_blocks_and_keeps_finished_chunks(tmp_path):
  """SIGINT while MJX blocks run: the run stops (blocks last about a second),
  says so, and the finished chunks are a readable bank."""
  import json
  import signal
  import subprocess
  import sys
  import time
  out = tmp_path / "bank"
  tiny = pathlib.Path(__file__).parents[1] / "scenes" / "tiny.yaml"
  proc = subprocess.Popen([sys.executable, "-m", "mwbx.cli", "sample", str(tiny), "--backend", "mjx",
                           "--worlds", "64", "--chunk-size", "8", "--out", str(out)],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          # the suite may run with SIGINT ignored (nohup, background jobs)
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  try:
    deadline = time.monotonic() + 900
    while time.monotonic() < deadline and proc.poll() is None:
      manifest = out / "manifest.json"
      if manifest.exists() and json.loads(manifest.read_text())["shards"]:
        break
      time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
  finally:
    if proc.poll() is None:
      proc.kill()
  assert proc.returncode == 130, err[-2000:]
  assert "interrupted;" in err and "run the same command again to resume" in err
  bank = mwbx.Bank.load(out)
  assert 0 < bank.n_worlds < 64 and bank.n_worlds % 8 == 0
