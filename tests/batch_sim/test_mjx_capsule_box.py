"""mwbx's capsule-box contacts for MJX against MuJoCo C's, pose by pose.

A capsule lying along y (SIGGRAPH's pegs) and a box near it: axis-aligned
(the capsule parallel to box edges, where MJX's own function misses contacts
MuJoCo C finds), turned about y (the letters between their walls) and turned
a little about every axis. Poses are kept where MuJoCo C's deepest contact
penetrates by up to PENETRATION_MAX, or where the geoms are within MARGIN
of touching (so a contact where C has none is seen too).

Where C gives one point and ours two (a capsule along a face: C puts its
second point on the first) or C gives one point twice, the counts differ;
the test holds ours to C's depth everywhere and to C's points where C gives
two distinct ones."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import mesh
from mujoco.mjx._src.collision_types import GeomInfo

from mwbx.batch_sim.mjx_capsule_box import capsule_box_contacts

RADIUS, HALF_LENGTH = 0.012, 0.04
HALF_SIZES = [(0.03, 0.018, 0.007), (0.007, 0.018, 0.042), (0.0446, 0.018, 0.007)]
PENETRATION_MAX = 0.004  # m
MARGIN = 0.001  # m: poses this close to touching are kept, and a contact this shallow may be in one set only
DEPTH_TOLERANCE = 2e-5  # m: deepest penetration, ours against C's (float32 against float64)
POINT_TOLERANCE = 0.002  # m: each contact's position, ours against C's
TWO_POINTS_APART = 0.005  # m: C's two contacts this far apart are two points, not one twice
MIN_SHARE = 0.99  # of the poses that agree with C's on depth, and on two-point contacts

XML = """
<mujoco>
  <worldbody>
    <geom name="peg" type="capsule" size="{r} {h}" euler="90 0 0"/>
    <body name="block"><freejoint/><geom name="box" type="box" size="{x} {y} {z}"/></body>
  </worldbody>
</mujoco>
"""


def _poses(half, n, rng):
  """Box poses (centre, quaternion) around the capsule: a third axis-aligned,
  a third turned about y only, a third turned a little about every axis."""
  kind = np.arange(n) % 3
  angle_y = np.where(kind == 0, 0.0, rng.uniform(-0.6, 0.6, n))
  tilt = np.where(kind[:, None] == 2, rng.uniform(-0.05, 0.05, (n, 2)), 0.0)
  reach = np.array([half[0] + RADIUS, half[1] + HALF_LENGTH, half[2] + RADIUS]) + 0.01
  centre = rng.uniform(-reach, reach, (n, 3))
  quats = []
  for ay, (ax, az) in zip(angle_y, tilt):
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.array([ax, ay, az]), "xyz")
    quats.append(q)
  return centre, np.array(quats)


def _c_contacts(model, data, centre, quat):
  data.qpos[:3], data.qpos[3:7] = centre, quat
  mujoco.mj_kinematics(model, data)
  mujoco.mj_collision(model, data)
  return [(c.dist, c.pos.copy()) for c in data.contact[:data.ncon]]


def test_capsule_box_contacts_match_mujoco_c():
  rng = np.random.default_rng(0)
  checked = 0
  for half in HALF_SIZES:
    model = mujoco.MjModel.from_xml_string(XML.format(r=RADIUS, h=HALF_LENGTH, x=half[0], y=half[1], z=half[2]))
    model.geom_margin[:] = MARGIN  # C reports pairs this close: the near misses
    data = mujoco.MjData(model)
    centre, quat = _poses(half, 6000, rng)
    poses, reference = [], []
    for c, q in zip(centre, quat):
      contacts = _c_contacts(model, data, c, q)
      if contacts and min(d for d, _ in contacts) > -PENETRATION_MAX:
        poses.append((data.geom_xpos.copy(), data.geom_xmat.copy()))
        reference.append(contacts)
    xpos = jnp.asarray(np.array([p for p, _ in poses]), jnp.float32)
    xmat = jnp.asarray(np.array([m for _, m in poses]).reshape(-1, 2, 3, 3), jnp.float32)
    size = jnp.asarray(model.geom_size, jnp.float32)

    @jax.jit
    @jax.vmap
    def ours(xpos, xmat):
      cap = GeomInfo(xpos[0], xmat[0], size[0])
      box = mesh.box(GeomInfo(xpos[1][None], xmat[1][None], size[1][None]))
      box = jax.tree_util.tree_map(lambda x: x[0] if x.ndim and x.shape[0] == 1 else x, box)
      dist, pos, _ = capsule_box_contacts(cap, box)
      return dist, pos

    dist, pos = map(np.asarray, ours(xpos, xmat))
    touching = as_deep = two = two_match = 0
    for ref, d, p in zip(reference, dist, pos):
      ref_min = min(dd for dd, _ in ref)
      if ref_min < -MARGIN:  # C penetrates beyond the margin: ours as deep
        touching += 1
        as_deep += abs(d.min() - ref_min) < DEPTH_TOLERANCE
      else:  # C: no contact deeper than the margin; ours has none either
        assert d.min() > -MARGIN - DEPTH_TOLERANCE, (half, ref, d)
      ref_pts = [pp for dd, pp in ref if dd < 0]
      if len(ref_pts) == 2 and np.linalg.norm(ref_pts[0] - ref_pts[1]) > TWO_POINTS_APART:
        two += 1  # the capsule along an edge or a face: the same two points
        pts = [pp for dd, pp in zip(d, p) if dd < 0]
        two_match += len(pts) == 2 and min(
            max(np.linalg.norm(ref_pts[0] - pts[0]), np.linalg.norm(ref_pts[1] - pts[1])),
            max(np.linalg.norm(ref_pts[0] - pts[1]), np.linalg.norm(ref_pts[1] - pts[0]))) < POINT_TOLERANCE
    # The poses reach the cases that matter; MJX's own function misses 15 % of
    # these contacts and matches 76 % of the two-point ones (measured).
    assert touching >= 100 and two >= 100, (half, touching, two)
    assert as_deep >= MIN_SHARE * touching, (half, as_deep, touching)
    assert two_match >= MIN_SHARE * two, (half, two_match, two)
    checked += len(reference)
  assert checked >= 600
