"""Island sleep in the native engine: ``sim.sleep`` parsing, what ``auto``
turns on, and sampling with sleep on: a world whose every tree sleeps stops
at rest, bit-identical whatever the batching, and gets no more perturbations."""

import textwrap

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.batch_sim import native_backend
from mwbx.batch_sim import sleep as sleep_lib
from mwbx.bank import FLAG_AT_REST

SLEEP_BIT = int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def write_config(tmp_path, body, name="cfg.yaml"):
  path = tmp_path / name
  path.write_text(textwrap.dedent(body))
  return path


def boxes_mjcf(n, option="", extra=""):
  """``n`` small free boxes resting on a plane, a row of 8 per line."""
  bodies = "".join(f'<body name="box{i}" pos="{0.2 * (i % 8):.2f} {0.2 * (i // 8):.2f} 0.05"><freejoint/>'
                   f'<geom type="box" size="0.04 0.04 0.04" mass="0.1"/></body>' for i in range(n))
  return (f'<mujoco><option timestep="0.0020833333333333333">{option}</option><worldbody>'
          f'<geom name="floor" type="plane" size="5 5 0.1"/>{bodies}{extra}</worldbody></mujoco>')


# -- config ------------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [
    ("sleep: on", True), ("sleep: off", False), ('sleep: "on"', True), ('sleep: "Off"', False),
    ("sleep: true", True), ("sleep: false", False), ("sleep: yes", True), ("sleep: auto", "auto"),
    ("end_time: 1", "auto"),
])
def test_sleep_words(tmp_path, text, expected):
  """YAML 1.1 reads bare on/off/yes as booleans; quoted words mean the same;
  a config without the field gets ``auto``."""
  cfg = mwbx.load_config(write_config(tmp_path, f"scene: {{mjcf: tiny.xml}}\nsim: {{{text}}}\n"))
  assert cfg.sim.sleep == expected and type(cfg.sim.sleep) is type(expected)
  assert cfg.sim.sleep_tolerance is None


@pytest.mark.parametrize("text, field", [
    ("sleep: 3", "sim.sleep"), ("sleep: maybe", "sim.sleep"), ("sleep: null", "sim.sleep"),
    ("sleep: [on]", "sim.sleep"), ("sleep_tolerance: 0", "sim.sleep_tolerance"),
    ("sleep_tolerance: 2", "sim.sleep_tolerance"),
])
def test_bad_sleep_values_are_one_error_naming_the_field(tmp_path, text, field):
  """A bad value is one line naming the file and the field, not a traceback
  per union branch."""
  path = write_config(tmp_path, f"scene: {{mjcf: tiny.xml}}\nsim: {{{text}}}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  message = str(err.value)
  assert f"{path}: {field}:" in message and "\n" not in message, message


def test_sleep_tolerance_and_digest(tmp_path):
  """``sleep_tolerance`` is read; ``sleep: auto`` written out keeps the digest
  of a config without the field (banks from before keep theirs), other
  values change it."""
  def digest(sim):
    return mwbx.load_config(write_config(tmp_path, f"scene: {{mjcf: tiny.xml}}\nsim: {{{sim}}}\n")).digest("<x/>")
  assert mwbx.load_config(write_config(
      tmp_path, "scene: {mjcf: tiny.xml}\nsim: {sleep_tolerance: 0.01}\n")).sim.sleep_tolerance == 0.01
  base = digest("end_time: 1")
  assert digest("end_time: 1, sleep: auto") == base
  assert digest("end_time: 1, sleep: on") != base
  assert digest("end_time: 1, sleep_tolerance: 0.01") != base


# -- resolve -------------------------------------------------------------------------


def test_auto_is_off_for_a_few_trees(quickstart_config):
  """The quickstart scene (four objects) keeps the physics it was tuned with."""
  model = mwbx.Scene(quickstart_config).model
  settings = sleep_lib.resolve(model, "auto")
  assert not settings.enabled and "auto" in settings.reason
  assert settings.tolerance == model.opt.sleep_tolerance


def test_auto_counts_trees_that_may_sleep():
  """``auto`` turns sleep on from AUTO_MIN_TREES trees (one below stays off)."""
  n = sleep_lib.AUTO_MIN_TREES
  assert n == 32
  few = mujoco.MjModel.from_xml_string(boxes_mjcf(n - 1))
  many = mujoco.MjModel.from_xml_string(boxes_mjcf(n))
  forty = mujoco.MjModel.from_xml_string(boxes_mjcf(40))
  assert sleep_lib.sleepy_trees(few) == n - 1 and sleep_lib.sleepy_trees(forty) == 40
  assert not sleep_lib.resolve(few, "auto").enabled
  assert sleep_lib.resolve(many, "auto").enabled
  on = sleep_lib.resolve(forty, "auto")
  assert on.enabled and "40 trees" in on.reason


def test_auto_follows_the_mjcf_and_leaves_flexes_awake():
  """An MJCF enabling sleep gets it under ``auto`` even with two bodies; a
  scene with a flex stays awake however many trees it has."""
  enabled = mujoco.MjModel.from_xml_string(boxes_mjcf(2, '<flag sleep="enable"/>'))
  assert enabled.opt.enableflags & SLEEP_BIT
  assert sleep_lib.resolve(enabled, "auto").enabled
  cloth = ('<flexcomp name="cloth" type="grid" dim="2" count="3 3 1" spacing="0.05 0.05 0.05"'
           ' pos="0 0 1" radius="0.01" mass="0.1"><edge equality="true"/></flexcomp>')
  flexed = mujoco.MjModel.from_xml_string(boxes_mjcf(40, extra=cloth))
  assert flexed.nflex == 1 and sleep_lib.sleepy_trees(flexed) >= 40
  settings = sleep_lib.resolve(flexed, "auto")
  assert not settings.enabled and "flex" in settings.reason


def test_forced_values_and_tolerance():
  """true/false override ``auto``'s rule both ways; a tolerance given
  overrides the model's, None keeps it; the copy sets the flag and the
  tolerance and leaves the scene's model alone."""
  few = mujoco.MjModel.from_xml_string(boxes_mjcf(2, ""))
  model = mujoco.MjModel.from_xml_string(boxes_mjcf(40, ""))
  model.opt.sleep_tolerance = 0.004
  assert sleep_lib.resolve(few, True).enabled
  assert not sleep_lib.resolve(model, False).enabled
  assert sleep_lib.resolve(model, "auto").tolerance == pytest.approx(0.004)
  settings = sleep_lib.resolve(few, True, 0.02)
  assert settings.tolerance == 0.02
  assert sleep_lib.SleepSettings.from_record(settings.as_record()) == settings
  copy = sleep_lib.sleeping_copy(few, settings)
  assert copy.opt.enableflags & SLEEP_BIT and copy.opt.sleep_tolerance == 0.02
  assert not few.opt.enableflags & SLEEP_BIT and few.opt.sleep_tolerance != 0.02
  enabled = mujoco.MjModel.from_xml_string(boxes_mjcf(2, '<flag sleep="enable"/>'))
  off = sleep_lib.sleeping_copy(enabled, sleep_lib.resolve(enabled, False))
  assert not off.opt.enableflags & SLEEP_BIT and enabled.opt.enableflags & SLEEP_BIT


def test_all_asleep():
  """A world is asleep when every tree is (>= 0), never with no trees."""

  def all_asleep(tree_asleep):  # the compiled loop's rest rule
    return sleep_lib.every_tree(sleep_lib.asleep_count(tree_asleep), tree_asleep.size)

  assert all_asleep(np.array([0, 1, 1], np.int32))
  assert not all_asleep(np.array([0, -1, 1], np.int32))
  assert not all_asleep(np.zeros(0, np.int32))


def test_mjx_warp_sleeps_only_when_asked_or_the_mjcf_says():
  """On mjx:warp (MuJoCo Warp sleeps under Newton only; not measured on a
  GPU) ``auto`` stays off where native would turn sleep on; true, false and
  an MJCF's own flag are as on native."""
  forty = mujoco.MjModel.from_xml_string(boxes_mjcf(40))
  assert sleep_lib.resolve(forty, "auto").enabled
  settings = sleep_lib.resolve_warp(forty, "auto")
  assert not settings.enabled and "mjx:warp" in settings.reason and "40 trees" in settings.reason
  assert sleep_lib.resolve_warp(forty, True).enabled and not sleep_lib.resolve_warp(forty, False).enabled
  enabled = mujoco.MjModel.from_xml_string(boxes_mjcf(2, '<flag sleep="enable"/>'))
  assert sleep_lib.resolve_warp(enabled, "auto").enabled


def test_only_trees_that_start_asleep_keep_the_mjcfs_exact_pose():
  """A float32 initial qpos equal to the MJCF's pose rounded becomes the
  MJCF's exact value in the trees with sleep policy init (else MuJoCo would
  see a changed pose and wake them); a randomized value there, and every
  value of the other trees, stays the float32 one (their worlds as before)."""
  extra = ('<body name="resting" pos="0.3 0.7 0.1" euler="0 0 17" sleep="init"><freejoint/>'
           '<geom type="box" size="0.04 0.04 0.04" mass="0.1"/></body>')
  model = mujoco.MjModel.from_xml_string(boxes_mjcf(2, extra=extra))
  init = sleep_lib.starts_asleep(model)
  resting = int(model.jnt_qposadr[model.body("resting").jntadr[0]])
  assert init.sum() == 7 and init[resting:resting + 7].all()
  qpos = np.tile(model.qpos0.astype(np.float32), (2, 1))
  qpos[1, resting] += 0.01  # randomized in world 1
  exact = native_backend.exact_pose(qpos, model)
  assert exact.dtype == np.float64
  np.testing.assert_array_equal(exact[0, init], model.qpos0[init])
  assert exact[1, resting] == np.float64(qpos[1, resting])
  np.testing.assert_array_equal(exact[:, ~init], qpos[:, ~init].astype(np.float64))
  assert (exact[0, ~init] != model.qpos0[~init]).any()  # the other trees keep float32's rounding


# -- sampling ----------------------------------------------------------------------

DROP_MJCF = """<mujoco>
  <option timestep="0.0020833333333333333"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    BODIES
    EXTRA
  </worldbody>
</mujoco>
"""

# Boxes dropped 20 cm, tumbling; the rest speeds are 0 so that nothing but
# sleep stops a world early.
DROP_CONFIG = """scene:
  mjcf: drop.xml
  groups: {boxes: ["box*"]}
randomize:
  boxes:
    position: {dist: uniform, scale: [0.02, 0.02, 0.02]}
    rotation: {dist: normal, scale: 0.5}
    angular_velocity: {dist: normal, scale: [2, 2, 2]}
sim: {end_time: END, sleep: SLEEP, chunk_size: 6}
rest: {linear_speed: 0, angular_speed: 0}
"""

PENDULUM = """<body name="arm" pos="1 1 0.6"><joint name="swing" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.1"/></body>"""


def drop_config(tmp_path, sleep, end_time=2.0, extra=""):
  boxes = "\n    ".join(f'<body name="box{i}" pos="{0.2 * i - 0.3:.2f} 0 0.25"><freejoint/>'
                        f'<geom type="box" size="0.05 0.05 0.05" mass="0.2"/></body>' for i in range(4))
  (tmp_path / "drop.xml").write_text(DROP_MJCF.replace("BODIES", boxes).replace("EXTRA", extra))
  text = DROP_CONFIG.replace("END", str(end_time)).replace("SLEEP", sleep)
  return mwbx.load_config(write_config(tmp_path, text, f"drop_{sleep}_{end_time}.yaml"))


def sample(config, n, chunk_size, first_world=0, seed=0):
  return mwbx.sample(config, n, jax.random.key(seed), backend="native", chunk_size=chunk_size,
                     first_world=first_world)


def n_frames(config):
  return int(round(config.sim.end_time * config.sim.record_fps)) + 1


def assert_same_worlds(a, rows_a, b, rows_b):
  """Bit-identical worlds: stored qpos frames, metrics, frame and perturbation counts."""
  np.testing.assert_array_equal(a.world_ids[rows_a], b.world_ids[rows_b])
  np.testing.assert_array_equal(a.flags[rows_a], b.flags[rows_b])
  np.testing.assert_array_equal(a.frame_count[rows_a], b.frame_count[rows_b])
  np.testing.assert_array_equal(a.perturbations[rows_a], b.perturbations[rows_b])
  np.testing.assert_array_equal(a.steps[rows_a], b.steps[rows_b])
  np.testing.assert_array_equal(a.metrics[rows_a], b.metrics[rows_b])
  for qa, qb in zip(a.qpos_store.frames_of_rows(rows_a), b.qpos_store.frames_of_rows(rows_b)):
    np.testing.assert_array_equal(qa, qb)


@pytest.fixture(scope="module")
def drop_dir(tmp_path_factory):
  return tmp_path_factory.mktemp("drop")


@pytest.fixture(scope="module")
def asleep_bank(drop_dir):
  """Worlds 0..5 of the dropped boxes with sleep on, in one chunk."""
  return sample(drop_config(drop_dir, "true"), 6, chunk_size=6)


def test_resting_worlds_stop_when_every_tree_sleeps(drop_dir, asleep_bank):
  """With sleep on, every world comes to rest (status AT_REST) well before
  the end time, its boxes perturbed on landing and still once stored."""
  bank = asleep_bank
  full = n_frames(drop_config(drop_dir, "true"))
  assert bank.run["sleep"]["enabled"] is True and bank.run["sleep"]["reason"] == "sim.sleep: true"
  assert ((bank.flags & FLAG_AT_REST) != 0).all(), bank.flags
  assert (bank.frame_count < full // 2).all() and (bank.frame_count > 10).all(), bank.frame_count
  assert bank.perturbations.sum() > 0
  # The last recorded frames show the boxes still on the floor: on a face (z
  # 0.05) or, where one fell asleep balanced on an edge, up to 0.05·√2.
  for q in bank.qpos_store.frames_of_rows(None):
    z = q[-1, [7 * i + 2 for i in range(4)]]
    assert ((z > 0.045) & (z < 0.0725)).all(), z
    np.testing.assert_allclose(q[-1], q[-2], atol=2e-3)


def test_sleeping_worlds_do_not_depend_on_the_batching(drop_dir, asleep_bank):
  """Worlds 0..5 in chunks of 2 and worlds 3..5 started at first_world=3 are
  bit for bit those of the single chunk of 6."""
  config = drop_config(drop_dir, "true")
  pairs = sample(config, 6, chunk_size=2)
  assert_same_worlds(asleep_bank, np.arange(6), pairs, np.arange(6))
  tail = sample(config, 3, chunk_size=3, first_world=3)
  np.testing.assert_array_equal(tail.world_ids, [3, 4, 5])
  assert_same_worlds(asleep_bank, np.arange(3, 6), tail, np.arange(3))


def test_sleep_off_runs_to_the_end_time(drop_dir, asleep_bank):
  """The same worlds with sleep off never rest (the rest speeds are 0) and
  record every frame; the bank's run record says sleep was off."""
  config = drop_config(drop_dir, "false")
  bank = sample(config, 6, chunk_size=6)
  assert bank.run["sleep"]["enabled"] is False
  np.testing.assert_array_equal(bank.frame_count, n_frames(config))
  assert ((bank.flags & FLAG_AT_REST) == 0).all(), bank.flags
  assert (bank.frame_count > asleep_bank.frame_count).all()


def test_perturbations_stop_once_asleep(drop_dir, asleep_bank):
  """A world at rest from sleep has the same perturbations, frames and
  metrics whether it could have run 2 s or 4 s: nothing more happens to it
  after its boxes fall asleep."""
  longer = sample(drop_config(drop_dir, "true", end_time=4.0), 6, chunk_size=6)
  assert ((longer.flags & FLAG_AT_REST) != 0).all()
  assert_same_worlds(asleep_bank, np.arange(6), longer, np.arange(6))


def test_a_tree_that_never_sleeps_keeps_the_world_running(tmp_path):
  """With a swinging pendulum beside the boxes not every tree sleeps: the
  world runs to the end time; the sleeping boxes stay where they came to
  rest, and the world gets no perturbation while they sleep (the same count
  at 1.5 s as at 2 s)."""
  config = drop_config(tmp_path, "true", extra=PENDULUM)
  scene = mwbx.Scene(config)
  assert "arm" in scene.body_names
  with mwbx.Sampler(config, backend="native", chunk_size=3) as sampler:
    assert sampler.sleep.enabled
    assert sampler.backend.model.opt.enableflags & SLEEP_BIT
    assert not scene.model.opt.enableflags & SLEEP_BIT  # the scene's own model is left as it was
    bank, _ = sampler.run(3, jax.random.key(0))
  np.testing.assert_array_equal(bank.frame_count, n_frames(config))
  assert ((bank.flags & FLAG_AT_REST) == 0).all()
  model = scene.model
  swing = int(model.jnt_qposadr[model.joint("swing").id])
  boxes = np.concatenate([np.arange(7) + int(model.jnt_qposadr[model.body(f"box{i}").jntadr[0]])
                          for i in range(4)])
  shorter = sample(drop_config(tmp_path, "true", end_time=1.5, extra=PENDULUM), 3, chunk_size=3)
  for w, q in enumerate(bank.qpos_store.frames_of_rows(None)):
    assert np.ptp(q[-60:, swing]) > 0.5  # the pendulum still swings
    np.testing.assert_allclose(q[-60:, boxes], np.broadcast_to(q[-60, boxes], (60, len(boxes))), atol=2e-3)
    assert bank.perturbations[w] == shorter.perturbations[w]


def test_sampler_takes_the_settings_a_bank_recorded(drop_dir):
  """``Sampler(sleep=record)`` steps with the recorded settings (refinement
  replays a bank's), overriding the config; the config's sleep_tolerance
  reaches the model that steps."""
  config = drop_config(drop_dir, "false")
  record = sleep_lib.SleepSettings(True, 0.003, "recorded").as_record()
  with mwbx.Sampler(config, backend="native", sleep=record) as sampler:
    assert sampler.sleep == sleep_lib.SleepSettings(True, 0.003, "recorded")
    assert sampler.backend.model.opt.enableflags & SLEEP_BIT
    assert sampler.backend.model.opt.sleep_tolerance == 0.003
    assert sampler.run_record()["sleep"] == record
  tolerant = config.model_copy(update={"sim": config.sim.model_copy(update={"sleep": True, "sleep_tolerance": 0.02})})
  with mwbx.Sampler(tolerant, backend="native") as sampler:
    assert sampler.sleep.enabled and sampler.sleep.tolerance == 0.02
    assert sampler.backend.model.opt.sleep_tolerance == 0.02


# Three boxes standing on the floor; a ball thrown (randomized) into the first.
STANDING_MJCF = """<mujoco>
  <option timestep="0.0020833333333333333"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    BOXES
    <body name="ball" pos="-0.4 0 0.05"><freejoint/><geom type="sphere" size="0.04" mass="0.3"/></body>
  </worldbody>
</mujoco>
"""


def standing_config(tmp_path, policy):
  boxes = "\n    ".join(f'<body name="box{i}" pos="{0.4 * i:.1f} 0 0.05" {policy}><freejoint/>'
                        f'<geom type="box" size="0.05 0.05 0.05" mass="0.2"/></body>' for i in range(3))
  name = "init" if policy else "auto"
  (tmp_path / f"standing_{name}.xml").write_text(STANDING_MJCF.replace("BOXES", boxes))
  return mwbx.load_config(write_config(tmp_path, f"""\
      scene: {{mjcf: standing_{name}.xml}}
      randomize:
        ball:
          linear_velocity: {{dist: uniform, mean: [2.0, 0.0, 0.0], scale: [0.2, 0.02, 0.0]}}
      sim: {{end_time: 1.0, sleep: on, chunk_size: 2}}
      """, f"standing_{name}.yaml"))


def test_trees_that_start_asleep_stay_asleep_until_hit(tmp_path):
  """Boxes with MuJoCo's sleep policy ``init`` start asleep: the two the ball
  never reaches do not move at all (path length exactly 0; awake, the same
  boxes settle into the floor by a little), though the sampler stores
  every pose in float32; the box the ball hits wakes and moves."""
  path = list(mwbx.METRIC_NAMES).index("path_length")
  for policy in ('sleep="init"', ""):
    bank = sample(standing_config(tmp_path, policy), 4, chunk_size=2)
    names = list(bank.body_names)
    travelled = {b: bank.metrics[:, names.index(b), path] for b in ("box0", "box1", "box2")}
    assert (travelled["box0"] > 0.02).all(), travelled  # struck, awake or asleep at the start
    if policy:
      np.testing.assert_array_equal(travelled["box1"], 0.0)
      np.testing.assert_array_equal(travelled["box2"], 0.0)
    else:
      assert (travelled["box2"] > 0).all(), travelled


def test_info_says_what_sleep_skipped(tmp_path, capsys):
  """A sampling run records the tree-frames its worlds slept (the boxes,
  once landed; never the swinging pendulum) against all of them, and
  ``mwbx info`` states the share; a run with sleep off records nothing and
  info says nothing of it."""
  from mwbx import cli
  from mwbx.bank import shards
  config = drop_config(tmp_path, "true", extra=PENDULUM)
  run = mwbx.sample_run(config, tmp_path / "on", n_worlds=3, seed=0, backend="native")
  bank = mwbx.Bank.load(run.out)
  np.testing.assert_array_equal(bank.frame_count, n_frames(config))  # the pendulum keeps every world running
  asleep, total = shards.read_manifest(run.out)["runs"][0]["tree_frames"]
  assert total == 5 * int(bank.frame_count.sum())  # 4 boxes and the pendulum, every frame stepped
  assert 0.3 * total < asleep <= 0.8 * total, (asleep, total)  # the pendulum never sleeps: 4 of 5 at most
  assert run.summary.stats.asleep_share == asleep / total
  capsys.readouterr()
  assert cli.main(["info", str(run.out)]) == 0
  line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("sleep"))
  assert f"asleep {asleep / total:.1%} of the tree-frames sampled" in line and f"{total:,}" in line
  off = mwbx.sample_run(drop_config(tmp_path, "false"), tmp_path / "off", n_worlds=2, seed=0, backend="native")
  assert "tree_frames" not in shards.read_manifest(off.out)["runs"][0]
  assert off.summary.stats.asleep_share is None
  assert cli.main(["info", str(off.out)]) == 0
  assert "asleep" not in capsys.readouterr().out
