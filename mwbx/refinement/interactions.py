"""Which objects a refined world must simulate (paper §5, Fig. 7).

Three object sets per world, kept as one boolean mask ``active: bool[O]``:
*active* objects are simulated; *inactive* ones replay their stored motion;
every active object has a *ghost* that replays its original motion. Before
each frame, an inactive object that may touch an active object or a ghost
during the frame becomes active (and gets a ghost) from then on; activation
spreads until nothing changes (a newly activated object may reach a third).

Interactions are tested conservatively with bounding spheres about each
tracked body's centre of mass (covering its geoms and those of untracked
descendants), inflated by how far the body can move before the next test, a
contact margin, and for ghosts the codec's error bound (the decoded path is
within it of the original motion). MuJoCo contacts between two geoms imply
overlap of these spheres, so the test catches every contact either backend
could report; activating too many objects is safe, too few would not be.
Both backends use this same test, so they agree on activation.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import scene as scene_lib

from mwbx.codec import CodecBounds
from mwbx.errors import MwbxError
from mwbx.host_jit import host_jit
from mwbx.joints import JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE


class InteractionParams(NamedTuple):
  """Scene constants of the interaction test.

  Attributes:
    body_object: f32[B, O] one-hot object of each tracked body.
    radius: f32[B] bounding-sphere radius about the body's COM, m.
    ghost_slack: f32[B] codec error bound at the body's geoms, m.
    margin: contact margin added to every pair, m.
    horizon: s until the next test (one frame plus one step).
    speed_factor: bound on speed growth within a frame (1 + 2α).
    gravity: |g|, m/s².
  """

  body_object: jax.Array
  radius: jax.Array
  ghost_slack: jax.Array
  margin: float
  horizon: float
  speed_factor: float
  gravity: float


def object_reach_radii(model: mujoco.MjModel, body_ids: np.ndarray, objects: dict, body_names) -> np.ndarray:
  """f32[B] how far each tracked body's object reaches from the body's COM,
  metres, whatever its untracked joints do (unlike
  :func:`mwbx.queries.body_radii`, which covers the body's own geoms only).

  Covers every geom of the body and of its untracked descendants inside the
  same object: for the body itself ``|geom_pos − ipos| + rbound + margin``
  (rigid), for descendants the chain of joint offsets (plus slide ranges) as
  an upper bound on the distance whatever the joint angles.
  """
  tracked = {int(b): i for i, b in enumerate(body_ids)}
  radius = np.zeros(len(body_ids))
  ours = scene_lib.object_body_mask(model, objects).any(axis=0)
  for b in range(1, model.nbody):
    if not ours[b]:
      continue
    root = int(model.body_rootid[b])
    anchor, reach = b, 0.0
    while anchor not in tracked:
      reach += float(np.linalg.norm(model.body_pos[anchor]))
      for j in range(model.body_jntadr[anchor], model.body_jntadr[anchor] + model.body_jntnum[anchor]):
        if int(model.jnt_type[j]) == JNT_SLIDE:
          reach += float(np.abs(model.jnt_range[j]).max()) if model.jnt_limited[j] else 1.0
      if anchor == root:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, root)
        raise MwbxError(f"refine: object {name!r} has geoms on bodies with no tracked ancestor;"
                        " track its root body (scene.track)")
      anchor = int(model.body_parentid[anchor])
    i = tracked[anchor]
    for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b]):
      extent = float(model.geom_rbound[g] + max(model.geom_margin[g], 0.0))
      if b == anchor:
        dist = float(np.linalg.norm(model.geom_pos[g] - model.body_ipos[b]))
      else:
        dist = float(np.linalg.norm(model.body_ipos[anchor])) + reach + float(np.linalg.norm(model.geom_pos[g]))
      radius[i] = max(radius[i], dist + extent)
  return radius.astype(np.float32)


def ghost_slack(model: mujoco.MjModel, body_ids: np.ndarray, radius: np.ndarray,
                codec_bounds: CodecBounds) -> np.ndarray:
  """f64[B] how far a tracked body's geoms can lie from where its decoded
  (stored) pose puts them, given the codec's bounds (``e_pos`` m, ``e_rot``
  rad, ``e_scalar`` rad or m; :meth:`mwbx.config.CodecSection.bounds`): a
  ghost is the original motion, the stored path is within this of it.

  Each joint from the object's root down to the body moves the body's geoms
  by at most its bound times its lever arm: a free joint ``√3·e_pos`` (an ℓ∞
  bound per axis) plus ``e_rot`` times its reach; a ball joint ``e_rot``, a
  hinge ``e_scalar`` (rad) times the reach; a slide ``e_scalar`` (m). The
  reach from a joint on body k to any geom point of body b is at most the
  joint's offset in k, the chain of body offsets from k down to b, b's COM
  offset and b's radius (whatever the joint angles). Joints of untracked
  descendants (whose geoms the radius covers) add their bound times twice
  the radius.
  """
  e_pos, e_rot, e_scalar = codec_bounds.e_pos, codec_bounds.e_rot, codec_bounds.e_scalar
  tracked = {int(b) for b in body_ids}
  slack = np.zeros(len(body_ids))
  for i, b in enumerate(np.asarray(body_ids)):
    b = int(b)
    reach_b = float(np.linalg.norm(model.body_ipos[b])) + float(radius[i])
    chain, k = 0.0, b
    while k != 0:
      for j in range(model.body_jntadr[k], model.body_jntadr[k] + model.body_jntnum[k]):
        kind = int(model.jnt_type[j])
        lever = float(np.linalg.norm(model.jnt_pos[j])) + chain + reach_b
        if kind == JNT_FREE:
          slack[i] += np.sqrt(3.0) * e_pos + e_rot * (chain + reach_b)
        elif kind == JNT_BALL:
          slack[i] += e_rot * lever
        elif kind == JNT_HINGE:
          slack[i] += e_scalar * lever
        else:
          slack[i] += e_scalar
      chain += float(np.linalg.norm(model.body_pos[k]))
      k = int(model.body_parentid[k])
    # Untracked descendants that the body's radius covers.
    for d in range(b + 1, model.nbody):
      a = d
      while a not in tracked and a != 0:
        a = int(model.body_parentid[a])
      if a != b or d == b:
        continue
      for j in range(model.body_jntadr[d], model.body_jntadr[d] + model.body_jntnum[d]):
        kind = int(model.jnt_type[j])
        slack[i] += e_scalar if kind == JNT_SLIDE else max(e_rot, e_scalar) * 2.0 * float(radius[i])
  return slack


def interaction_params(model, body_ids, body_names, objects: dict, object_names, codec_bounds: CodecBounds,
                       margin: float, horizon: float, alpha: float) -> InteractionParams:
  """Builds :class:`InteractionParams` for a scene (host, once)."""
  radius = object_reach_radii(model, body_ids, objects, body_names)
  onehot = np.zeros((len(body_names), len(object_names)), np.float32)
  for o, name in enumerate(object_names):
    for b in objects[name]:
      onehot[body_names.index(b), o] = 1.0
  slack = ghost_slack(model, body_ids, radius, codec_bounds)
  return InteractionParams(
      body_object=jnp.asarray(onehot), radius=jnp.asarray(radius), ghost_slack=jnp.asarray(slack, jnp.float32),
      margin=float(margin), horizon=float(horizon), speed_factor=1.0 + 2.0 * float(alpha),
      gravity=float(np.linalg.norm(model.opt.gravity)))


def near_pairs(center: jax.Array, extent: jax.Array) -> jax.Array:
  """bool[B, B]: spheres (center f32[B, 3], radius f32[B]) overlap."""
  d = jnp.linalg.norm(center[:, None, :] - center[None, :, :], axis=-1)
  return d <= extent[:, None] + extent[None, :]


def activate(active: jax.Array, com_sim: jax.Array, speed_sim: jax.Array, com_now: jax.Array,
             com_next: jax.Array, p: InteractionParams) -> jax.Array:
  """The active set of ONE world for the coming frame.

  Args:
    active: bool[O] objects simulated so far.
    com_sim: f32[B, 3] simulated COM of the bodies (used for active ones), m.
    speed_sim: f32[B] their speed, m/s.
    com_now: f32[B, 3] stored COM at this frame; com_next: at the next, m.
    p: scene constants.

  Returns:
    bool[O] ``active`` plus every inactive object an active object or a ghost
    may touch before the next test (transitively).
  """
  body_active = (p.body_object @ active.astype(jnp.float32)) > 0.5
  # Stored motion over the frame: the chord's midpoint, half its length.
  mid = 0.5 * (com_now + com_next)
  half = 0.5 * jnp.linalg.norm(com_next - com_now, axis=-1)
  h = p.horizon
  vmax = jnp.max(jnp.where(body_active, speed_sim, 0.0))
  reach = (jnp.maximum(speed_sim, vmax) * p.speed_factor + p.gravity * h) * h
  center = jnp.where(body_active[:, None], com_sim, mid)
  extent = p.radius + jnp.where(body_active, reach, half) + 0.5 * p.margin
  near_now = near_pairs(center, extent)
  ghost_extent = p.radius + half + 0.5 * p.margin + p.ghost_slack
  # Ghosts and inactive bodies are both on their stored chords.
  d_ghost = jnp.linalg.norm(mid[:, None, :] - mid[None, :, :], axis=-1)
  near_ghost = d_ghost <= ghost_extent[:, None] + (p.radius + half + 0.5 * p.margin)[None, :]
  # near_ghost[i, j]: ghost of body i near stored body j; near_now is symmetric.
  to_obj = lambda m: (p.body_object.T @ m.astype(jnp.float32) @ p.body_object) > 0.5
  reach_now, reach_ghost = to_obj(near_now), to_obj(near_ghost)

  # Transitive closure of "source may touch target" by repeated squaring
  # (static, ceil(log2 O) products), then everything reachable from `active`.
  n_objects = active.shape[0]
  closure = (jnp.eye(n_objects, dtype=bool) | reach_now | reach_ghost).astype(jnp.float32)
  for _ in range(max(1, math.ceil(math.log2(max(n_objects, 2))))):
    closure = ((closure @ closure) > 0.5).astype(jnp.float32)
  return (active.astype(jnp.float32) @ closure) > 0.5


class HostInteraction(NamedTuple):
  """:class:`InteractionParams` as the plain arrays and floats of :func:`activate_host`.

  Attributes:
    body_object: i64[B] object of each tracked body.
    radius: f64[B] bounding-sphere radius about the body's COM, m.
    ghost_slack: f64[B] codec error bound at the body's geoms, m.
    margin: contact margin added to every pair, m.
    horizon: s until the next test.
    speed_factor: bound on speed growth within a frame.
    gravity: |g|, m/s².
  """

  body_object: np.ndarray
  radius: np.ndarray
  ghost_slack: np.ndarray
  margin: float
  horizon: float
  speed_factor: float
  gravity: float


def host_interaction(p: InteractionParams) -> HostInteraction:
  """``p`` as the plain arrays and floats :func:`activate_host` takes."""
  f64 = lambda x: np.ascontiguousarray(np.asarray(x, np.float64))
  return HostInteraction(np.asarray(p.body_object).argmax(axis=1).astype(np.int64), f64(p.radius),
                         f64(p.ghost_slack), float(p.margin), float(p.horizon), float(p.speed_factor),
                         float(p.gravity))


@host_jit
def activate_host(active, com_sim, speed_sim, com_now, com_next, inter, out):
  """:func:`activate` for ONE world, compiled for the host's per-world
  refinement loop (its numba twin, in float64; tests/refinement/test_refine_kernels.py
  compares the two and :func:`activate_reference`).

  Args:
    active: bool[O]; com_sim: f[B, 3]; speed_sim: f[B]; com_now, com_next:
      f[B, 3] (as :func:`activate`).
    inter: :class:`HostInteraction` (:func:`host_interaction` of the scene's
      :class:`InteractionParams`).
    out: bool[O] out: the active set for the coming frame.
  """
  body_object, radius, ghost_slack, margin = inter.body_object, inter.radius, inter.ghost_slack, inter.margin
  horizon, speed_factor, gravity = inter.horizon, inter.speed_factor, inter.gravity
  n_bodies = body_object.size
  mid = np.empty((n_bodies, 3))
  center = np.empty((n_bodies, 3))
  extent = np.empty(n_bodies)
  stored_extent = np.empty(n_bodies)
  vmax = 0.0
  for b in range(n_bodies):
    if active[body_object[b]]:
      vmax = max(vmax, speed_sim[b])
  for b in range(n_bodies):
    half = 0.0
    for a in range(3):
      mid[b, a] = 0.5 * (float(com_now[b, a]) + float(com_next[b, a]))
      half += (float(com_next[b, a]) - float(com_now[b, a])) ** 2
    half = 0.5 * np.sqrt(half)
    stored_extent[b] = radius[b] + half + 0.5 * margin
    if active[body_object[b]]:
      reach = (max(speed_sim[b], vmax) * speed_factor + gravity * horizon) * horizon
      for a in range(3):
        center[b, a] = com_sim[b, a]
      extent[b] = radius[b] + reach + 0.5 * margin
    else:
      for a in range(3):
        center[b, a] = mid[b, a]
      extent[b] = stored_extent[b]
  for o in range(out.size):
    out[o] = active[o]
  changed = True
  while changed:
    changed = False
    for i in range(n_bodies):
      if not out[body_object[i]]:
        continue
      for j in range(n_bodies):
        if out[body_object[j]]:
          continue
        d_now = np.sqrt((center[i, 0] - center[j, 0]) ** 2 + (center[i, 1] - center[j, 1]) ** 2
                        + (center[i, 2] - center[j, 2]) ** 2)
        d_ghost = np.sqrt((mid[i, 0] - mid[j, 0]) ** 2 + (mid[i, 1] - mid[j, 1]) ** 2 + (mid[i, 2] - mid[j, 2]) ** 2)
        if d_now <= extent[i] + extent[j] or d_ghost <= stored_extent[i] + ghost_slack[i] + stored_extent[j]:
          out[body_object[j]] = True
          changed = True


def activate_reference(active, com_sim, speed_sim, com_now, com_next, p: InteractionParams) -> np.ndarray:
  """Plain-loop version of :func:`activate` (tests)."""
  onehot = np.asarray(p.body_object)
  body_obj = onehot.argmax(axis=1)
  radius, slack = np.asarray(p.radius), np.asarray(p.ghost_slack)
  active = np.array(active, bool)
  n_bodies = len(body_obj)
  body_active = active[body_obj]
  vmax = max([speed_sim[b] for b in range(n_bodies) if body_active[b]], default=0.0)
  h = p.horizon
  center, ext, g_ext = [], [], []
  for b in range(n_bodies):
    mid = 0.5 * (com_now[b] + com_next[b])
    half = 0.5 * np.linalg.norm(com_next[b] - com_now[b])
    reach = (max(speed_sim[b], vmax) * p.speed_factor + p.gravity * h) * h
    center.append(com_sim[b] if body_active[b] else mid)
    ext.append(radius[b] + (reach if body_active[b] else half) + 0.5 * p.margin)
    g_ext.append((mid, radius[b] + half + 0.5 * p.margin))
  changed = True
  while changed:
    changed = False
    for i in range(n_bodies):
      for j in range(n_bodies):
        oi, oj = body_obj[i], body_obj[j]
        if not active[oi] or active[oj]:
          continue
        touch = np.linalg.norm(center[i] - center[j]) <= ext[i] + ext[j]
        ghost = np.linalg.norm(g_ext[i][0] - g_ext[j][0]) <= g_ext[i][1] + slack[i] + g_ext[j][1]
        if touch or ghost:
          active[oj] = True
          changed = True
  return active
