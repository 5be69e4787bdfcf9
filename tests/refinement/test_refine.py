"""Refinement (paper §5, Figs. 6–7) on the native backend.

Scene (tests/refine_scenes/fig6.xml): a ball ("striker") lands on a round
apex and rolls off left or right; on the right it pushes a resting box
("target"); a third ball ("far") rolls far away. Parents are picked from a
small sampled bank: one where the target was never hit (Fig. 6(a)) and one
where it was (Fig. 6(b)).
"""

from __future__ import annotations

import pathlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx.refinement import RefineRequest, run_refinement
from mwbx.refinement.refine import refine


def refine_run(bank, world, objects=(), *, progress=None, **fields):
  """The refined worlds alone and their stats (through the one entry, :func:`mwbx.run_refinement`)."""
  done = run_refinement(bank, RefineRequest(world, objects, **fields), progress)
  return done.new, done.stats

SCENES = pathlib.Path(__file__).parents[1] / "refine_scenes"
T_MIN = 0.1
N = 8


def _moved(q, cols):
  return float(np.linalg.norm(q[-1, cols] - q[0, cols]))


@pytest.fixture(scope="module")
def bank():
  config = mwbx.load_config(SCENES / "fig6.yaml")
  return mwbx.sample(config, 16, jax.random.key(0), backend="native")


@pytest.fixture(scope="module")
def cols(bank):
  model = bank.model
  adr = lambda name: int(model.jnt_qposadr[model.body(name).jntadr[0]])
  return {name: slice(adr(name), adr(name) + 3) for name in ("striker", "target", "far")}


def _refine(bank, parent, key=1):
  new, stats = refine_run(bank, parent, ["striker"], t_min=T_MIN, n_samples=N, key=jax.random.key(key),
                          backend="native")
  return new, stats


@pytest.fixture(scope="module")
def case_a(bank, cols):
  """Fig. 6(a): parent where the striker went left and never touched the target."""
  parent = next(w for w in range(bank.n_worlds)
                if bank.qpos_frames(w)[-1, 0] < -0.1 and _moved(bank.qpos_frames(w), cols["target"]) < 1e-3)
  new, stats = _refine(bank, parent)
  return parent, new, stats


@pytest.fixture(scope="module")
def case_b(bank, cols):
  """Fig. 6(b): parent where the striker pushed the target; some refined worlds go left."""
  hit = [w for w in range(bank.n_worlds) if _moved(bank.qpos_frames(w), cols["target"]) > 0.02]
  for parent in hit[:4]:
    new, stats = _refine(bank, parent)
    if any(new.qpos_frames(new.world_ids[w])[-1, 0] < -0.1 for w in range(new.n_worlds)):
      return parent, new, stats
  pytest.fail("no hit parent produced a refined world going left")


def test_untouched_object_keeps_its_stored_path_exactly(bank, case_a, case_b, cols):
  far = bank.body_names.index("far")
  for parent, new, _ in (case_a, case_b):
    stored = bank.qpos_frames(parent)
    for w in range(new.n_worlds):
      lineage = new.lineage[str(bank.n_worlds + w)]
      assert "far" not in lineage["active"]
      q = new.qpos_frames(new.world_ids[w])
      assert len(q) == len(stored)
      model = bank.model
      jnt = model.body("far").jntadr[0]
      a = int(model.jnt_qposadr[jnt])
      np.testing.assert_array_equal(q[:, a:a + 7], stored[:, a:a + 7])  # frame by frame, bit for bit
      np.testing.assert_array_equal(new.com[w, :, far], bank.com[parent, :, far])
      np.testing.assert_array_equal(new.metrics[w, far], bank.metrics[parent, far])


def test_fig6a_refined_object_hits_resting_object_which_becomes_active(bank, case_a, cols):
  parent, new, _ = case_a
  assert _moved(bank.qpos_frames(parent), cols["target"]) < 1e-3
  moved = []
  for w in range(new.n_worlds):
    q = new.qpos_frames(new.world_ids[w])
    lineage = new.lineage[str(bank.n_worlds + w)]
    if _moved(q, cols["target"]) > 1e-3:
      # Anything that moved off its stored path was simulated.
      assert "target" in lineage["active"]
      assert lineage["activated_at"]["target"] > T_MIN
      moved.append(w)
      # It moved physically: pushed to +x along the floor, no tunnelling, at rest on it.
      assert q[-1, cols["target"]][0] > q[0, cols["target"]][0] + 0.01
      assert abs(q[-1, cols["target"]][2] - 0.05) < 5e-3
      assert np.all(q[:, cols["striker"]][:, 0] < q[:, cols["target"]][:, 0])
  assert moved, "no refined world hit the resting target"


def test_fig6b_object_no_longer_hit_is_activated_by_the_ghost_and_stays(bank, case_b, cols):
  parent, new, _ = case_b
  stored = bank.qpos_frames(parent)
  assert _moved(stored, cols["target"]) > 0.02
  hit_frame = int(np.argmax(np.linalg.norm(stored[:, cols["target"]] - stored[0, cols["target"]], axis=1) > 1e-4))
  left = [w for w in range(new.n_worlds) if new.qpos_frames(new.world_ids[w])[-1, 0] < -0.1]
  assert left
  for w in left:
    lineage = new.lineage[str(bank.n_worlds + w)]
    assert "target" in lineage["active"]
    # Activated by the striker's ghost, before the original hit.
    assert lineage["activated_at"]["target"] <= hit_frame / bank.record_fps
    q = new.qpos_frames(new.world_ids[w])
    # It does not keep flying as if it had been hit: it stays where it rested.
    assert _moved(q, cols["target"]) < 2e-3


def test_continuity_at_t_min_and_plausibility_bound(bank, case_a, case_b):
  model = bank.model
  e_pos = bank.config["codec"]["e_pos"]
  free = [int(model.jnt_qposadr[j]) for j in range(model.njnt)]
  for parent, new, stats in (case_a, case_b):
    stored = bank.qpos_frames(parent)
    f0 = int(round(T_MIN * bank.record_fps))
    assert np.all(new.refine_time == pytest.approx(f0 / bank.record_fps))
    assert np.all(new.parent_world == parent)
    parent_step = max(np.abs(np.diff(stored[f0 - 2:f0 + 3, a:a + 3], axis=0)).max() for a in free)
    for w in range(new.n_worlds):
      q = new.qpos_frames(new.world_ids[w])
      for a in free:
        # No jump at t_min: the refined world starts on the parent's stored state.
        np.testing.assert_allclose(q[:f0 + 1, a:a + 3], stored[:f0 + 1, a:a + 3], atol=2.5 * e_pos, rtol=0)
        step = np.abs(np.diff(q[f0 - 2:f0 + 3, a:a + 3], axis=0)).max()
        assert step <= 2 * parent_step + 4 * e_pos
    # |perturbation| <= alpha * |dv| in every refined world, never on inactive bodies.
    assert stats.max_perturbation_ratio.shape == (N,)
    assert np.all(stats.max_perturbation_ratio <= 1.0 + 1e-5)
    assert np.all(stats.max_perturbation_ratio > 0)  # the striker did get perturbed
    assert np.all(stats.inactive_perturbations == 0)
    assert np.all(new.perturbations > 0)


def test_refined_worlds_are_ordinary_bank_worlds(bank, case_a, tmp_path):
  parent, new, _ = case_a
  total = bank.append(new)
  assert total.digest == bank.digest and total.n_worlds == bank.n_worlds + N
  row = bank.n_worlds
  lineage = total.lineage[str(row)]
  assert lineage["parent"] == parent and lineage["objects"] == ["striker"]
  assert "striker" in lineage["active"]
  total.save(tmp_path / "bank")
  loaded = mwbx.Bank.load(tmp_path / "bank")
  np.testing.assert_array_equal(loaded.qpos_frames(row), total.qpos_frames(row))
  assert loaded.lineage[str(row)] == lineage
  # Refinable again (here a refined world refined once more, briefly).
  again = refine(loaded, row, "striker", t_min=0.5, n_samples=2, key=jax.random.key(5), backend="native")
  assert again.n_worlds == loaded.n_worlds + 2
  assert again.lineage[str(loaded.n_worlds)]["parent"] == row


def test_frustum_picks_t_min_with_first_entry(bank, case_a):
  from mwbx.queries import Camera, ScreenBox, first_entry
  parent = case_a[0]
  camera = Camera.from_model(bank.model, "front")
  box = ScreenBox(0.0, 0.0, 1.0, 0.62)  # upper part of the image: the striker enters it late in its fall
  frustum = camera.frustum(box)
  t = first_entry(bank, parent, ["striker"], frustum)
  assert t is not None
  new, _ = refine_run(bank, parent, ["striker"], frustum=frustum, n_samples=2, key=jax.random.key(2),
                      backend="native")
  assert new.refine_time[0] == pytest.approx(np.floor(t * bank.record_fps + 1e-6) / bank.record_fps)


@pytest.mark.parametrize("kwargs, message", [
    (dict(world=999, objects="striker", t_min=0.1), "refine: world 999: no world with this id"),
    (dict(world=0, objects="nosuch", t_min=0.1), "nosuch"),
    (dict(world=0, objects="striker", t_min=99.0), "outside"),
    (dict(world=0, objects="striker"), "exactly one"),
])
def test_user_errors_name_the_value(bank, kwargs, message):
  with pytest.raises(mwbx.MwbxError, match=message):
    refine(bank, n_samples=1, key=jax.random.key(0), **kwargs)


def test_unstable_parent_is_refused(bank):
  import dataclasses
  flags = bank.flags.copy()
  flags[3] |= mwbx.FLAG_UNSTABLE
  broken = dataclasses.replace(bank, flags=flags)
  with pytest.raises(mwbx.MwbxError, match="unstable"):
    refine(broken, 3, "striker", t_min=0.1, n_samples=1, key=jax.random.key(0))


def test_step_playback_on_native(bank, case_a, cols):
  """Inactive objects put on the stored path before every physics step."""
  parent = case_a[0]
  new, stats = refine_run(bank, parent, ["striker"], t_min=T_MIN, n_samples=4, key=jax.random.key(1),
                          backend="native", playback="step")
  stored = bank.qpos_frames(parent)
  for w in range(new.n_worlds):
    q = new.qpos_frames(new.world_ids[w])
    lineage = new.lineage[str(bank.n_worlds + w)]
    np.testing.assert_array_equal(q[:, 14:21], stored[:, 14:21])
    if _moved(q, cols["target"]) > 1e-3:
      assert "target" in lineage["active"]
  assert np.all(stats.max_perturbation_ratio <= 1.0 + 1e-5)
  assert np.all(stats.inactive_perturbations == 0)
  # Same perturbation keys: the worlds that went right with frame playback go right here too.
  frame_new = case_a[1]
  for w in range(4):
    assert np.sign(new.qpos_frames(new.world_ids[w])[-1, 0]) == np.sign(frame_new.qpos_frames(frame_new.world_ids[w])[-1, 0])


def test_cli_refine(bank, tmp_path, capsys):
  from mwbx import cli
  path = tmp_path / "bank"
  bank.save(path)
  assert cli.main(["refine", str(path), "--world", "1", "--objects", "striker", "--time", "0.1",
                   "--samples", "2", "--backend", "native"]) == 0
  assert "refined worlds      2 of world 1" in capsys.readouterr().out
  loaded = mwbx.Bank.load(path)
  assert loaded.n_worlds == bank.n_worlds + 2 and loaded.lineage[str(bank.n_worlds)]["parent"] == 1
  assert cli.main(["refine", str(path), "--world", "1", "--objects", "striker", "--box", "0,0,1,1",
                   "--samples", "1"]) == 2
  assert "--camera" in capsys.readouterr().err


def test_refined_worlds_do_not_depend_on_the_batching(bank, case_a):
  parent, new, _ = case_a
  again, _ = refine_run(bank, parent, ["striker"], t_min=T_MIN, n_samples=N, key=jax.random.key(1),
                        backend="native", chunk_size=3)
  for w in range(N):
    np.testing.assert_array_equal(again.qpos_frames(again.world_ids[w]), new.qpos_frames(new.world_ids[w]))
  assert again.lineage == new.lineage


@pytest.mark.parametrize("case", ["case_a", "case_b"])
def test_compiled_loop_matches_the_lockstep_loop(bank, case, request):
  """The compiled per-world loop (the default) against the lockstep rollout
  loop it replaced: the same activations and the same motion; the two differ
  only in how MuJoCo's solver is warm-started at frame starts and in float32
  (jitted) against float64 (compiled) bookkeeping."""
  parent = request.getfixturevalue(case)[0]
  runs = {loop: refine_run(bank, parent, ["striker"], t_min=T_MIN, n_samples=N, key=jax.random.key(1),
                           backend="native", loop=loop) for loop in ("compiled", "lockstep")}
  (compiled, c_stats), (lockstep, l_stats) = runs["compiled"], runs["lockstep"]
  for w in range(N):
    i, j = str(int(compiled.world_ids[w])), str(int(lockstep.world_ids[w]))
    assert compiled.lineage[i]["active"] == lockstep.lineage[j]["active"]
    assert compiled.lineage[i]["activated_at"] == lockstep.lineage[j]["activated_at"]
    a, b = compiled.qpos_frames(int(i)), lockstep.qpos_frames(int(j))
    assert len(a) == len(b)
    np.testing.assert_allclose(a, b, atol=2e-3)  # within the codec's bounds of each other
  np.testing.assert_allclose(compiled.metrics, lockstep.metrics, rtol=1e-3, atol=1e-3)
  assert np.all(c_stats.max_perturbation_ratio <= 1.0 + 1e-5) and np.all(c_stats.inactive_perturbations == 0)
  np.testing.assert_allclose(c_stats.max_perturbation_ratio, l_stats.max_perturbation_ratio, rtol=1e-4)


@pytest.mark.parametrize("case", ["case_a", "case_b"])
def test_inactive_objects_held_asleep_change_nothing(bank, case, request, monkeypatch):
  """The compiled loop holds inactive objects asleep (MuJoCo's island sleep)
  instead of moving them along the stored path: the refined worlds are the
  same bit for bit, also where an object wakes when it is activated (case b:
  the target is hit)."""
  from mwbx.batch_sim import mujoco_c
  if not mujoco_c.can_put_to_sleep():
    pytest.skip("this MuJoCo library does not export mj_updateSleep")
  parent = request.getfixturevalue(case)[0]
  run = lambda: refine_run(bank, parent, ["striker"], t_min=T_MIN, n_samples=N, key=jax.random.key(1),
                           backend="native")
  asleep, a_stats = run()
  monkeypatch.setattr(mujoco_c, "can_put_to_sleep", lambda: False)
  awake, w_stats = run()
  n_objects = len(bank.objects)
  assert np.all(a_stats.asleep_object_frames > 0) and np.all(w_stats.asleep_object_frames == 0)
  # never more than the inactive objects of the frames simulated
  frames = np.array([len(asleep.qpos_frames(i)) for i in asleep.world_ids]) - a_stats.first_frame
  assert np.all(a_stats.asleep_object_frames <= (n_objects - 1) * frames)
  assert asleep.lineage == {k: v for k, v in awake.lineage.items()}
  for w in range(N):
    np.testing.assert_array_equal(asleep.qpos_frames(asleep.world_ids[w]), awake.qpos_frames(awake.world_ids[w]))
  np.testing.assert_array_equal(asleep.metrics, awake.metrics)
  if case == "case_b":
    assert any("target" in v["active"] for v in asleep.lineage.values())


def test_sphere_test_never_activates_fewer_than_an_exact_test(bank, case_a, case_b):
  """The conservative sphere test against MuJoCo's geom distance with the same
  margin (mwbx.refinement.exact_active): never fewer objects."""
  from mwbx.refinement import exact_active
  checked = 0
  for parent, new, _ in (case_a, case_b):
    both = bank.append(new)
    for world in new.world_ids:
      sphere = set(new.lineage[str(int(world))]["active"])
      exact = set(exact_active(both, int(world)))
      assert exact <= sphere, (int(world), exact, sphere)
      assert "striker" in exact
      checked += len(exact) > 1
  assert checked > 0  # the exact test does activate the target in some worlds
