"""The sampling loop on the native backend: determinism, rest, instability, banks."""

import json
import subprocess
import sys
import threading

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.batch_sim import world
from conftest import REPO, TESTS


def same_world(a, i, b, j):
  """Bit-identical recorded world i of bank a and world j of bank b."""
  assert a.world_ids[i] == b.world_ids[j]
  np.testing.assert_array_equal(a.keys[i], b.keys[j])
  assert a.flags[i] == b.flags[j] and a.frame_count[i] == b.frame_count[j]
  np.testing.assert_array_equal(a.qpos_frames(int(a.world_ids[i])), b.qpos_frames(int(b.world_ids[j])))
  np.testing.assert_array_equal(a.com[i], b.com[j])
  np.testing.assert_array_equal(a.metrics[i], b.metrics[j])
  assert a.perturbations[i] == b.perturbations[j]


def _assert_same_sampler(a, b):
  """Banks a and b come from the same sampler: two-sample KS tests on per-world
  metrics, and mean perturbation counts within 25 %."""
  from scipy import stats

  for name in ("rest_time", "collisions", "path_length"):
    pvalue = stats.ks_2samp(a.metric(name).sum(axis=1), b.metric(name).sum(axis=1)).pvalue
    assert pvalue > 1e-3, name
  ratio = a.perturbations.mean() / b.perturbations.mean()
  assert 0.8 < ratio < 1.25


def test_world_depends_only_on_config_key_and_id(tiny_config):
  key = jax.random.key(42)
  banks = {}
  for n in (1, 7, 64):
    banks[n] = mwbx.sample(tiny_config, n_worlds=n, key=key, backend="native", chunk_size=n)
  for i in range(7):
    same_world(banks[7], i, banks[64], i)
  same_world(banks[1], 0, banks[64], 0)
  # Continuing at world 7 reproduces worlds 7.. of the single run.
  rest = mwbx.sample(tiny_config, n_worlds=5, key=key, backend="native", chunk_size=5, first_world=7)
  for i in range(5):
    same_world(rest, i, banks[64], 7 + i)
  # The worlds really differ from each other and were perturbed.
  assert len({bytes(banks[64].qpos_frames(i)[-1]) for i in range(64)}) == 64
  assert banks[64].perturbations.sum() > 0


def test_backends_implement_the_protocol(tiny_native):
  from mwbx.batch_sim.backend import Backend
  assert isinstance(tiny_native.backend, Backend)


def test_bank_contents(tiny_native_bank):
  bank = tiny_native_bank
  cfg = bank.config
  assert bank.n_worlds == 32 and bank.body_names == ("cube", "ball")
  assert bank.metric_names == world.METRIC_NAMES
  end_frame = int(round(cfg["sim"]["end_time"] * cfg["sim"]["record_fps"]))
  assert (bank.frame_count >= 1).all() and (bank.frame_count <= end_frame + 1).all()
  at_rest = bank.at_rest
  assert at_rest.any()
  assert (bank.frame_count[~at_rest] == end_frame + 1).all()  # the others ran to the end time
  stride = int(cfg["sim"]["record_fps"] / cfg["sim"]["query_fps"])
  np.testing.assert_array_equal(bank.com_count, (bank.frame_count - 1) // stride + 1)
  model = bank.model
  for w in (0, 5):
    qpos = bank.qpos_frames(w)
    assert qpos.shape == (bank.frame_count[w], model.nq) and np.isfinite(qpos).all()
    # COM polyline point p is the COM of frame p * stride: check by forward
    # kinematics of the decoded qpos, which the codec keeps within e_pos (the
    # tiny scene's bodies have their COM at the body origin); stored COM
    # points are within e_com of the simulation.
    data = __import__("mujoco").MjData(model)
    for p in (0, bank.com_count[w] - 1):
      data.qpos[:] = qpos[p * stride]
      __import__("mujoco").mj_kinematics(model, data)
      np.testing.assert_allclose(bank.com[w, p], data.xipos[bank.body_ids],
                                 atol=(cfg["codec"]["e_pos"] + cfg["codec"]["e_com"]) * 1.001)
    tail = bank.com[w, bank.com_count[w]:]
    assert (tail == bank.com[w, bank.com_count[w] - 1]).all()
  metrics = bank.metrics
  assert (metrics[..., 0] > 0).all()                     # everything rotates on the way down
  assert (metrics[..., 4] > 0.05).all()                  # and travels
  # Everything starts at rest and falls: the highest point is the first one
  # (the metric is of the simulation, the stored point on the COM grid).
  np.testing.assert_allclose(metrics[..., 5], bank.com[:, 0, :, 2], atol=cfg["codec"]["e_com"] * 1.001)
  rest_time = bank.metric("rest_time")
  assert (rest_time <= (bank.frame_count[:, None] - 1) / 120 + 1e-6).all()


def test_unstable_worlds_are_flagged_and_kept_finite(tiny_config):
  # "Absurd velocity": a speed limit every falling world crosses.
  cfg = tiny_config.with_overrides(max_speed=1.0)
  bank = mwbx.sample(cfg, n_worlds=4, key=jax.random.key(0), backend="native")
  assert (~bank.valid).all()
  assert (bank.frame_count < 40).all()  # cut at the instability, ~0.2 s into the fall
  for w in range(4):
    assert np.isfinite(bank.qpos_frames(w)).all()
  assert np.isfinite(bank.com).all() and np.isfinite(bank.metrics).all()


def test_nan_world_does_not_disturb_the_batch(tiny_native):
  sampler = tiny_native
  ids = np.arange(4)
  _, init_keys, step_keys = mwbx.batch_sim.sampler.world_keys(jax.random.key(1), ids)
  qpos0, qvel0 = (np.asarray(x) for x in sampler._init(init_keys))
  clean = sampler.backend.run_chunk(sampler.scene, sampler.params, qpos0, qvel0, step_keys,
                                    np.ones(4, bool), sampler.n_frames)
  qvel0 = qvel0.copy()
  qvel0[2, 0] = np.nan
  dirty = sampler.backend.run_chunk(sampler.scene, sampler.params, qpos0, qvel0, step_keys,
                                    np.ones(4, bool), sampler.n_frames)
  assert dirty.status[2] == world.UNSTABLE and dirty.frame_count[2] == 0
  for w in (0, 1, 3):
    assert dirty.status[w] == clean.status[w]
    np.testing.assert_array_equal(dirty.qpos[w], clean.qpos[w])


def test_worlds_compressed_as_they_finish_are_stored_as_in_one_pass(tiny_config, monkeypatch):
  """The native backend hands worlds that finished to the codec while others
  still step: the bank is, bit for bit and in world order, the one that
  compressing the whole chunk at its end gives."""
  from mwbx.batch_sim import native_backend
  from mwbx.batch_sim import sampler as sampler_lib

  threads = []
  add = sampler_lib._ChunkStore.add

  def recording_add(self, worlds):
    threads.append(threading.current_thread().name)
    return add(self, worlds)

  monkeypatch.setattr(sampler_lib._ChunkStore, "add", recording_add)
  key = jax.random.key(3)
  with mwbx.Sampler(tiny_config, backend="native", chunk_size=64) as sampler:
    overlapped, _ = sampler.run(64, key)
    run_chunk = native_backend.NativeBackend.run_chunk
    monkeypatch.setattr(native_backend.NativeBackend, "run_chunk",
                        lambda self, *args, finished=None, **kwargs: run_chunk(self, *args, **kwargs))
    at_the_end, _ = sampler.run(64, key)
  assert "mwbx-finished" in threads  # batches went to the codec while the chunk ran
  a, b = overlapped.qpos_store.state()[0], at_the_end.qpos_store.state()[0]
  for name in a:
    np.testing.assert_array_equal(a[name], b[name], err_msg=name)
  for i in range(64):
    same_world(overlapped, i, at_the_end, i)


def test_a_failing_handover_stops_the_chunk_with_its_error(tiny_native, monkeypatch):
  from mwbx.batch_sim import sampler as sampler_lib

  def broken(self, worlds):
    raise RuntimeError("codec broke")

  monkeypatch.setattr(sampler_lib._ChunkStore, "add", broken)
  with pytest.raises(RuntimeError, match="codec broke"):
    tiny_native.run(64, jax.random.key(0))


def test_save_load_append(tmp_path, tiny_native_bank, tiny_config):
  bank = tiny_native_bank
  path = tmp_path / "bank"
  bank.save(path)
  loaded = mwbx.Bank.load(path)
  for i in (0, 31):
    same_world(bank, i, loaded, i)
  assert loaded.config == bank.config and loaded.digest == bank.digest
  assert json.loads((path / "config.resolved.json").read_text()) == bank.config
  more = mwbx.sample(tiny_config, n_worlds=3, key=jax.random.key(0), backend="native",
                     first_world=bank.next_world_id)
  both = loaded.append(more)
  both.save(path)
  again = mwbx.Bank.load(path)
  assert again.n_worlds == 35 and list(again.world_ids[-3:]) == [32, 33, 34]
  same_world(again, 33, more, 1)
  same_world(again, 3, bank, 3)


def test_corrupt_bank_gives_a_clear_error(tmp_path, tiny_native_bank):
  path = tmp_path / "bank"
  tiny_native_bank.save(path)
  with pytest.raises(mwbx.MwbxError, match="no bank here"):
    mwbx.Bank.load(tmp_path / "missing")
  for f in sorted(path.rglob("*")):
    if f.is_file() and f.stat().st_size > 1000 and "bank" in str(f.parent):
      f.write_bytes(b"\0garbage" * 10)
  with pytest.raises(mwbx.MwbxError, match=str(path)):
    mwbx.Bank.load(path)


def run_cli(*args):
  return subprocess.run([sys.executable, "-m", "mwbx.cli", *args], capture_output=True, text=True,
                        cwd=REPO, timeout=600)


def test_cli_sample_continue_and_info(tmp_path):
  out = tmp_path / "bank"
  config = str(TESTS / "scenes" / "tiny.yaml")
  first = run_cli("sample", config, "--worlds", "6", "--out", str(out), "--seed", "3")
  assert first.returncode == 0, first.stderr
  for needle in ("worlds sampled      6", "worlds at rest", "perturbations", "world-steps/s", str(out)):
    assert needle in first.stdout
  second = run_cli("sample", config, "--worlds", "4", "--out", str(out))
  assert second.returncode == 0, second.stderr
  info = run_cli("info", str(out), "--json")
  assert info.returncode == 0, info.stderr
  summary = json.loads(info.stdout)
  assert summary["worlds"] == 10 and summary["run"]["seed"] == 3
  assert summary["run"]["sleep"]["enabled"] is False  # auto: a scene of few bodies stays awake
  bank = mwbx.Bank.load(out)
  assert list(bank.world_ids) == list(range(10))
  direct = mwbx.sample(mwbx.load_config(config), n_worlds=10, key=jax.random.key(3), backend="native")
  same_world(bank, 8, direct, 8)
  text = run_cli("info", str(out))
  assert "worlds              10" in text.stdout and "mean collisions" in text.stdout


def test_cli_errors_are_one_line(tmp_path):
  bad = tmp_path / "bad.yaml"
  bad.write_text("scene: {mjcf: tiny.xml}\nsim: {chunk: 3}\n")
  result = run_cli("sample", str(bad), "--out", str(tmp_path / "o"))
  assert result.returncode == 2
  assert result.stderr.strip().splitlines() == [f"mwbx: error: {bad}: sim.chunk: unknown key"]
  result = run_cli("info", str(tmp_path / "nothing"))
  assert result.returncode == 2 and "no bank here" in result.stderr and "Traceback" not in result.stderr


def test_articulated_scene_samples_through_sensors():
  """An articulated object keeps MuJoCo's sensors (no free-body observation);
  the sampler runs on that path and perturbs at impacts."""
  from mwbx.batch_sim import free_bodies

  cfg = mwbx.config_from_dict(
      {"scene": {"mjcf": str(TESTS / "scenes" / "chain.xml")},
       "randomize": {"root": {"rotation": {"dist": "normal", "scale": 0.3}}},
       "sim": {"end_time": 1.5}},
      source=str(TESTS / "scenes" / "chain.yaml"))
  scene = mwbx.Scene(cfg)
  assert free_bodies.free_bodies(scene.model, scene.body_ids) is None  # link1 hangs off a hinge
  bank = mwbx.sample(scene, n_worlds=8, key=jax.random.key(0), backend="native")
  assert bank.valid.all()
  assert bank.perturbations.sum() > 0  # the chain and the puck hit the floor
  assert np.isfinite(bank.metrics).all()
  # Dropped from half a metre, each body hits the floor a few times: impacts
  # are counted at contacts, not at every step of the sensor path.
  collisions = bank.metric("collisions")
  assert (collisions >= 1).any() and (collisions <= 5).all()


def test_state_observation_samples_like_the_sensors(tiny_config, monkeypatch):
  """Free bodies observed from states and from MuJoCo's sensors give the same
  sampler (the two differ only in rounding, so worlds diverge, not their
  distribution)."""
  from mwbx.batch_sim import free_bodies, native_backend

  scene = mwbx.Scene(tiny_config)
  assert free_bodies.free_bodies(scene.model, scene.body_ids) is not None
  key = jax.random.key(4)
  from_states = mwbx.sample(tiny_config, n_worlds=64, key=key, backend="native")
  monkeypatch.setattr(native_backend.free_bodies_lib, "free_bodies", lambda model, ids: None)
  from_sensors = mwbx.sample(tiny_config, n_worlds=64, key=key, backend="native")
  _assert_same_sampler(from_states, from_sensors)


def _reference_chunk(sampler, qpos0, qvel0, step_keys):
  """Worlds one after another through ``mujoco.mj_step`` and the host loops,
  the slow and obvious form of the compiled per-world loop (compiled_world)."""
  from mwbx import controls
  from mwbx.batch_sim import free_bodies, host_bookkeeping, host_loops

  backend, scene, params = sampler.backend, sampler.scene, sampler.params
  ctrl = controls.scene_table(scene, sampler.n_frames * params.steps_per_frame)
  m = backend.model
  fb = free_bodies.free_bodies(m, scene.body_ids)
  model = backend.quiet_model if fb is not None else m
  c, spf, n_frames = len(qpos0), params.steps_per_frame, sampler.n_frames
  spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
  initial = backend.initial_states(qpos0, qvel0)
  sensordata = np.zeros((c, spf, m.nsensordata), np.float32)
  qpos_buf = np.zeros((c, n_frames, m.nq), np.float32)
  com_buf = np.zeros((c, n_frames, len(scene.body_ids), 3), np.float32)
  wrench_full = np.zeros((c, spf, m.nbody, 6))
  carry = host_bookkeeping.init_carry(len(scene.body_ids), np.ones(c, bool))
  running = np.ones(c, bool)
  key_data = np.asarray(jax.random.key_data(step_keys), np.uint32)
  p = host_bookkeeping.host_params(params)
  tracked = np.asarray(scene.body_ids, np.int64)
  nstate = initial.shape[1]
  buffers = host_bookkeeping.ChunkBuffers(
      params=p, key_data=key_data, tracked_ids=tracked, states=np.zeros((c, nstate)), warmstart=np.zeros((c, m.nv)),
      sensordata=sensordata, wrench_full=wrench_full, qpos_buf=qpos_buf, com_buf=com_buf, carry=carry)
  for r in range(c):
    d = mujoco.MjData(model)
    mujoco.mj_setState(model, d, initial[r], spec)
    frame = 0
    while running[r]:
      before = np.empty((1, nstate))
      after = np.empty((1, spf, nstate))
      sensors = np.zeros((1, spf, 0 if fb is not None else m.nsensordata))
      mujoco.mj_getState(model, d, before[0], spec)
      for s in range(spf):
        d.xfrc_applied[:] = wrench_full[r, s]
        if ctrl.shape[1]:
          d.ctrl[:] = ctrl[frame * spf + s]
        mujoco.mj_step(model, d)
        mujoco.mj_getState(model, d, after[0, s], spec)
        if fb is None:
          sensors[0, s] = d.sensordata
      rows = np.array([r])
      host_loops.absorb_rows(rows, before, after, sensors, m.opt.timestep, 1 + m.nq, sensordata,
                             np.zeros((c, m.nv)), np.zeros((c, nstate)))
      if fb is not None:
        host_loops.observe_free_bodies(rows, before, after, m.opt.timestep,
                                       np.asarray(m.opt.gravity), 1, 1 + m.nq, fb, sensordata)
      host_bookkeeping.frame_update(rows, buffers, before, 1, frame, running)
      frame += 1
  return carry, qpos_buf


def test_compiled_world_loop_matches_mj_step_one_world_at_a_time(tiny_native):
  from mwbx.batch_sim import mujoco_c

  assert mujoco_c.available()
  sampler = tiny_native
  _, init_keys, step_keys = mwbx.batch_sim.sampler.world_keys(jax.random.key(3), np.arange(6))
  qpos0, qvel0 = (np.asarray(x) for x in sampler._init(init_keys))
  result = sampler.backend.run_chunk(sampler.scene, sampler.params, qpos0, qvel0, step_keys,
                                     np.ones(6, bool), sampler.n_frames)
  carry, qpos_buf = _reference_chunk(sampler, qpos0, qvel0, step_keys)
  assert carry.perturbations.sum() > 0
  np.testing.assert_array_equal(result.frame_count, carry.frame_count)
  np.testing.assert_array_equal(result.steps, carry.step)
  np.testing.assert_array_equal(result.perturbations, carry.perturbations)
  np.testing.assert_array_equal(result.status, carry.status)
  for w in range(6):
    n = result.frame_count[w]
    np.testing.assert_array_equal(result.qpos[w, :n], qpos_buf[w, :n])


def test_compiled_world_loop_samples_like_lockstep_rollout(tiny_config, monkeypatch):
  """The per-world compiled loop and the lockstep rollout loop give the same
  sampler (rollout restarts the solver's warm start from the last step's
  accelerations at every frame, so worlds diverge, not their distribution)."""
  from mwbx.batch_sim import mujoco_c

  key = jax.random.key(5)
  compiled = mwbx.sample(tiny_config, n_worlds=64, key=key, backend="native")
  monkeypatch.setattr(mujoco_c, "available", lambda: False)
  lockstep = mwbx.sample(tiny_config, n_worlds=64, key=key, backend="native")
  _assert_same_sampler(compiled, lockstep)


def test_flipped_bits_are_caught_or_harmless(tmp_path, tiny_native_bank):
  """A flipped bit anywhere in a bank's data files either fails the load (or,
  for the arrays a lazy bank reads on demand, their first read) with one line
  naming the bank (and, past the storage layer, the array) or leaves every
  array as saved: never a silently changed answer."""
  import shutil
  bank = tiny_native_bank
  clean = tmp_path / "clean"
  bank.save(clean)
  files = sorted(f for f in (clean / "shards").rglob("*") if f.is_file())
  rng = np.random.default_rng(0)
  caught = 0
  for f in files:
    for _ in range(3):
      work = tmp_path / "work"
      shutil.rmtree(work, ignore_errors=True)
      shutil.copytree(clean, work)
      target = work / f.relative_to(clean)
      data = bytearray(target.read_bytes())
      if not data:
        continue
      data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
      target.write_bytes(bytes(data))
      try:
        loaded = mwbx.Bank.load(work)
        arrays = {name: np.asarray(getattr(loaded, name)) for name in mwbx.Bank.ROW_ARRAYS}
        data = loaded.qpos_store.data
      except mwbx.MwbxError as err:
        text = str(err)
        assert str(work) in text and "\n" not in text and len(text) < 400
        caught += 1
        continue
      for name in mwbx.Bank.ROW_ARRAYS:
        np.testing.assert_array_equal(arrays[name], getattr(bank, name))
      np.testing.assert_array_equal(data, bank.qpos_store.data)
  assert caught > 0


def test_checksum_names_the_changed_array(tmp_path, tiny_native_bank):
  path = tmp_path / "bank"
  tiny_native_bank.save(path)
  shard = path / "shards" / "00000"
  metrics = np.load(shard / "metrics.npy")
  metrics[0, 0, 0] += 1.0  # a valid file with other numbers: only the checksum can tell
  np.save(shard / "metrics.npy", metrics)
  with pytest.raises(mwbx.MwbxError, match=r"shards/00000: corrupt bank: checksum mismatch in metrics \("):
    mwbx.Bank.load(path)
