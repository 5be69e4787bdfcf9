"""The numerical pieces of refinement against slow, obvious references."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from mwbx.refinement import interactions, stored_motion

ARM = """
<mujoco>
  <worldbody>
    <geom type="plane" size="3 3 0.1"/>
    <body name="ball" pos="0 0 1"><freejoint/><geom type="sphere" size="0.05" pos="0.01 0 0"/></body>
    <body name="arm" pos="1 0 1"><freejoint/>
      <geom type="box" size="0.1 0.02 0.02" pos="0.1 0 0"/>
      <body name="fore" pos="0.2 0 0"><joint type="hinge" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03"/>
        <body name="hand" pos="0.25 0 0"><joint type="slide" axis="1 0 0" range="0 0.1"/>
          <geom type="sphere" size="0.04"/></body></body></body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def arm():
  return mujoco.MjModel.from_xml_string(ARM)


def test_object_reach_radii_cover_every_geom_in_any_pose(arm):
  tracked = ("ball", "arm")  # fore and hand are untracked: covered by arm's sphere
  ids = np.array([arm.body(n).id for n in tracked])
  objects = {"ball": ("ball",), "arm": ("arm",)}
  radius = interactions.object_reach_radii(arm, ids, objects, tracked)
  data = mujoco.MjData(arm)
  rng = np.random.default_rng(0)
  for _ in range(50):
    data.qpos[:] = arm.qpos0
    data.qpos[7:11] = rng.normal(size=4)
    data.qpos[14] = rng.uniform(-np.pi, np.pi)
    data.qpos[15] = rng.uniform(0, 0.1)
    mujoco.mj_kinematics(arm, data)
    for g in range(1, arm.ngeom):
      root = arm.body_rootid[arm.geom_bodyid[g]]
      i = tracked.index(mujoco.mj_id2name(arm, mujoco.mjtObj.mjOBJ_BODY, root))
      reach = np.linalg.norm(data.geom_xpos[g] - data.xipos[ids[i]]) + arm.geom_rbound[g]
      assert reach <= radius[i] + 1e-6


def _params(n_bodies, n_objects, rng):
  body_object = np.zeros((n_bodies, n_objects), np.float32)
  body_object[np.arange(n_bodies), np.concatenate([np.arange(n_objects), rng.integers(0, n_objects, n_bodies - n_objects)])] = 1
  return interactions.InteractionParams(
      body_object=jnp.asarray(body_object), radius=jnp.asarray(rng.uniform(0.02, 0.1, n_bodies), jnp.float32),
      ghost_slack=jnp.asarray(rng.uniform(0, 0.01, n_bodies), jnp.float32), margin=0.01, horizon=0.01,
      speed_factor=1.2, gravity=9.81)


def test_activate_matches_the_loop_reference():
  rng = np.random.default_rng(1)
  fn = jax.jit(interactions.activate)
  checked = 0
  for case in range(40):
    p = _params(7, 5, rng)
    active = rng.random(5) < 0.3
    com_sim = rng.uniform(-0.4, 0.4, (7, 3)).astype(np.float32)
    com_now = rng.uniform(-0.4, 0.4, (7, 3)).astype(np.float32)
    com_next = (com_now + rng.normal(0, 0.02, (7, 3))).astype(np.float32)
    speed = rng.uniform(0, 3, 7).astype(np.float32)
    got = np.asarray(fn(jnp.asarray(active), com_sim, speed, com_now, com_next, p))
    want = interactions.activate_reference(active, com_sim, speed, com_now, com_next, p)
    np.testing.assert_array_equal(got, want)
    host = np.zeros(5, bool)  # the numba twin of the compiled refinement loop
    interactions.activate_host(active, com_sim.astype(np.float64), speed.astype(np.float64), com_now, com_next,
                               interactions.host_interaction(p), host)
    np.testing.assert_array_equal(host, want)
    assert np.all(got[active])  # never deactivates
    checked += int(np.any(got != active))
  assert checked > 5  # the cases do activate objects


def test_activate_catches_a_ghost_and_spreads():
  # Objects 0 (active), 1 and 2 inactive; 1 sits on 0's stored path, 2 touches 1.
  p = interactions.InteractionParams(
      body_object=jnp.eye(3), radius=jnp.full(3, 0.05), ghost_slack=jnp.zeros(3), margin=0.0,
      horizon=0.01, speed_factor=1.0, gravity=0.0)
  stored = np.array([[0.0, 0, 0], [0.08, 0, 0], [0.17, 0, 0]], np.float32)
  sim = np.array([[-5.0, 0, 0], [0, 0, 0], [0, 0, 0]], np.float32)  # the active one went elsewhere
  got = interactions.activate(jnp.array([True, False, False]), sim, jnp.zeros(3), stored, stored, p)
  np.testing.assert_array_equal(np.asarray(got), [True, True, True])
  far = stored + np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32)
  got = interactions.activate(jnp.array([True, False, False]), sim, jnp.zeros(3), far, far, p)
  np.testing.assert_array_equal(np.asarray(got), [True, False, False])


def _free_path(n=6, seed=2):
  rng = np.random.default_rng(seed)
  model = mujoco.MjModel.from_xml_string(
      '<mujoco><worldbody><body name="b"><freejoint/><geom type="box" size=".1 .05 .02"/></body></worldbody></mujoco>')
  x = np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0)
  rot = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.2, (n, 3)), axis=0))
  quat = rot.as_quat()[:, [3, 0, 1, 2]]
  return model, np.concatenate([x, quat], axis=1).astype(np.float32), rot, x


def test_step_targets_interpolate_between_frames_like_lerp_and_slerp():
  model, frames, rot, x = _free_path()
  h, spf = 1 / 120, 4
  path = stored_motion.stored_path(model, frames, np.array([1]), len(frames), h)
  targets = stored_motion.step_targets(model, path, spf, h / spf)
  np.testing.assert_array_equal(targets[::spf], path.qpos)  # exactly on every frame
  slerp = Slerp(np.arange(len(frames)), rot)
  for k in range((len(frames) - 1) * spf):
    t = k / spf
    f, a = int(t), t - int(t)
    np.testing.assert_allclose(targets[k, :3], (1 - a) * x[f] + a * x[f + 1], atol=1e-6)
    q = slerp([t]).as_quat()[0][[3, 0, 1, 2]]
    assert abs(abs(np.dot(q, targets[k, 3:])) - 1) < 1e-6
  # Chord velocity: the finite difference (translation), held to zero past the end.
  np.testing.assert_allclose(path.qvel[:-1, :3], np.diff(x, axis=0) / h, rtol=1e-4, atol=1e-5)
  np.testing.assert_array_equal(path.qvel[-1], 0)
  v = stored_motion.central_velocity(model, path, 2, h)
  np.testing.assert_allclose(v[:3], (x[3] - x[1]) / (2 * h), rtol=1e-4, atol=1e-5)


def test_contact_free_models_switch_off_only_the_inactive_objects(arm):
  models = stored_motion.ContactFreeModels(arm, ("ball", "arm"))
  assert models.enabled
  inactive = np.array([[False, False], [True, False], [False, True], [True, False]])
  out = models(inactive)
  assert out[0] is arm and out[1] is out[3] and out[1] is not arm
  ball = arm.body_rootid[arm.geom_bodyid] == arm.body("ball").id
  limbs = arm.body_rootid[arm.geom_bodyid] == arm.body("arm").id  # box, forearm and hand
  assert ball.sum() == 1 and limbs.sum() == 3
  for model, off in ((out[1], ball), (out[2], limbs)):
    np.testing.assert_array_equal(model.geom_contype == 0, off)
    np.testing.assert_array_equal(model.geom_conaffinity == 0, off)
    np.testing.assert_array_equal(model.geom_size, arm.geom_size)  # a copy: nothing else differs
  assert np.all(arm.geom_contype == 1) and np.all(arm.geom_conaffinity == 1)  # the scene's model untouched
  # The arm moves and is no object of this refinement: it could touch an
  # inactive ball, so the ball keeps its contacts.
  only_ball = stored_motion.ContactFreeModels(arm, ("ball",))
  assert not only_ball.enabled and only_ball(np.array([[True]]))[0] is arm


def test_prefix_metrics_match_plain_loops():
  model, frames, rot, x = _free_path(n=30, seed=3)
  h = 1 / 120
  path = stored_motion.stored_path(model, frames, np.array([1]), 30, h)
  f = 20
  m = stored_motion.prefix_metrics(path, f, h, h / 4, np.array([0, 0, -9.81]), 0.02, 0.1, 100.0, 1)
  length = sum(np.linalg.norm(path.com[i + 1, 0] - path.com[i, 0]) for i in range(f))
  angle = sum((rot[i].inv() * rot[i + 1]).magnitude() for i in range(f))
  assert m[0, 4] == pytest.approx(length, rel=1e-5)
  assert m[0, 0] == pytest.approx(angle, rel=1e-3)
  assert m[0, 5] == pytest.approx(max(path.com[i, 0, 2] for i in range(f + 1)), rel=1e-6)
  assert m[0, 1] == pytest.approx((f - 1) * h)  # moving on every frame up to f


@pytest.mark.parametrize("child_frames", [40, 31, 52])
def test_splice_keeps_parent_channels_bit_for_bit(child_frames):
  from mwbx.codec import CodecBounds, CompressedQposStore
  from mwbx.testing.codec_data import boxes_model, record
  model = boxes_model(3)
  store = CompressedQposStore.from_model(model, CodecBounds(), 120.0)
  parent = record(model, 40, seed=1)
  child = record(model, child_frames, seed=2)
  store.append(np.stack([parent]), np.array([40]))
  keep = np.zeros(model.nq, bool)
  keep[7:14] = True  # the second box, translation and rotation channels
  out = store.refined(child[None], 0, np.array([child_frames]), 0, store.row_frames(0), keep[None])
  got = out.row_frames(0)
  assert got.shape == (child_frames, model.nq)
  stored = store.row_frames(0)
  n = min(child_frames, 40)
  if child_frames >= 40:
    np.testing.assert_array_equal(got[:n, 7:14], stored[:n, 7:14])  # the parent's frames, bit for bit
  else:  # cut short (an unstable refined world): raw columns, quaternions renormalized on decode
    np.testing.assert_array_equal(got[:n, 7:10], stored[:n, 7:10])
    np.testing.assert_allclose(got[:n, 10:14], stored[:n, 10:14], atol=1.2e-7, rtol=0)
  # Held past the parent's end (within a fraction of the bound).
  np.testing.assert_allclose(got[n:, 7:10], np.broadcast_to(stored[-1, 7:10], got[n:, 7:10].shape), atol=1e-3)
  np.testing.assert_allclose(np.abs(np.sum(got[n:, 10:14] * stored[-1, 10:14], axis=1)), 1.0, atol=1e-5)
  plain = CompressedQposStore.from_model(model, CodecBounds(), 120.0)
  plain.append(child[None], np.array([child_frames]))
  np.testing.assert_array_equal(got[:, ~keep], plain.row_frames(0)[:, ~keep])


def test_stored_motion_and_audit_against_loops():
  from mwbx import perturb
  from mwbx.batch_sim import world
  from mwbx.refinement import loop as refine_loop
  rng = np.random.default_rng(4)
  w, s, b, f = 3, 4, 5, 6
  p = _params(b, 4, rng)
  params = world.WorldParams(
      gravity=jnp.array([0.0, 0.0, -9.81]), mass=jnp.ones(b), inertia=jnp.ones((b, 3)), perturbable=jnp.ones(b, bool),
      flex_weight=jnp.zeros((0, b)), flex_perturbable=jnp.zeros(0, bool),
      perturb=perturb.PerturbParams(alpha=0.1), enabled=True, dt=1 / 480, rest_linear_speed=0.02,
      rest_angular_speed=0.1, rest_steps=10, max_speed=100.0, collision_gap_steps=1, steps_per_frame=s,
      end_frame=100)
  r = lambda *shape: jnp.asarray(rng.normal(size=shape), jnp.float32)
  obs = world.Observation(r(w, s, b, 3), r(w, s, b, 4), r(w, s, b, 3), r(w, s, b, 3), r(w, s, b, 3), r(w, s, b, 3))
  stored = (r(f, b, 3), r(f, b, 4), r(f, b, 3), r(f, b, 3))
  active = jnp.asarray(rng.random((w, 4)) < 0.5)
  got = refine_loop._with_stored_motion(obs, active, 2, stored, params, p)
  obj = np.asarray(p.body_object).argmax(axis=1)
  for i in range(w):
    for j in range(s):
      for k in range(b):
        if bool(active[i, obj[k]]):
          np.testing.assert_array_equal(got.com_pos[i, j, k], obs.com_pos[i, j, k])
        else:
          chord = stored[0][2, k] + (j / s) * (stored[0][3, k] - stored[0][2, k])
          np.testing.assert_allclose(got.com_pos[i, j, k], chord, atol=1e-6)
          np.testing.assert_array_equal(got.lin_vel[i, j, k], stored[2][2, k])
          np.testing.assert_array_equal(got.lin_acc[i, j, k], params.gravity)
  # Audit: largest |dv| / (alpha |delta_v|) and perturbations on inactive bodies.
  dv = jnp.where(rng.random((w, s, b, 1)) < 0.3, r(w, s, b, 3) * 0.01, 0.0)
  out = world.FrameOutput(wrench=None, record=None, running=None, dv=dv, dw=jnp.zeros_like(dv),
                          linear_impact=None, angular_impact=None)
  worst, stray = refine_loop._audit(obs, out, active, params, p)
  for i in range(w):
    ratios, n_stray = [0.0], 0
    for j in range(s):
      for k in range(b):
        d = np.asarray(dv[i, j, k])
        if np.any(d != 0):
          delta = (1 / 480) * (np.asarray(obs.lin_acc[i, j, k]) - np.array([0, 0, -9.81]))
          ratios.append(np.linalg.norm(d) / (0.1 * np.linalg.norm(delta)))
          n_stray += int(not bool(active[i, obj[k]]))
    assert float(worst[i]) == pytest.approx(max(ratios), rel=1e-4)
    assert int(stray[i]) == n_stray
