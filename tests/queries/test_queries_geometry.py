"""Whole-geometry queries against slow references: dense surface points at
every stored frame (never missed) and the stated bound (never exceeded): the
codec's error at a stored frame in the window."""

import mujoco
import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.codec import CompressedQposStore
from mwbx.codec.layout import CodecBounds
from mwbx.errors import MwbxError
from mwbx.queries import convex
from mwbx.queries import geometry as geometry_lib
from mwbx.queries.geometry_query import geometry_hits

import geometry_reference as ref

SPACING = 0.004  # m between the reference's surface points


@pytest.fixture(scope="module")
def bank():
  return ref.shapes_bank(n_worlds=10, n_frames=41, seed=1)


def test_geometry_hits_between_brute_force_and_the_stated_bound(bank):
  index = geometry_lib.geometry_index(bank)
  assert index.stride > 1  # kept frames are every few stored ones
  # The stated bound: at some stored frame in the window, within the codec's bound
  # (an index of every stored frame adds no motion between them).
  every = geometry_lib.build(bank, np.asarray(bank.valid, bool), stride=1)
  rng = np.random.default_rng(0)
  mask = np.ones(len(bank.body_names), bool)
  found = extra = loose = 0
  for k, frustum in enumerate(ref.random_frustums(rng, 9)):
    window = [None, (0.1, 0.25), (0.0, 0.05), (0.3, None)][k % 4]
    ours = geometry_hits(index, frustum, mask, window)
    brute = ref.brute_geometry_hits(bank, frustum, mask, window, SPACING)
    bound = ref.bound_geometry_hits(bank, every, frustum, mask, window, SPACING)
    assert not (brute & ~ours).any(), f"frustum {k}: a hit the brute force finds is missed"
    assert not (ours & ~bound).any(), f"frustum {k}: a hit beyond the stated bound"
    kept_bound = ref.bound_geometry_hits(bank, index, frustum, mask, window, SPACING)
    found += int(brute.sum())
    extra += int((ours & ~brute).sum())
    loose += int((kept_bound & ~brute).sum())
  assert found > 20  # the cases are not empty
  assert extra < loose  # tighter than the kept frames' margins alone


def test_a_corner_enters_where_the_com_misses():
  """A crate turning a quarter turn about y in place: its COM stays below
  the box, the end of its long side rises into it after about a third of
  the motion."""
  model = mujoco.MjModel.from_xml_string(ref.SHAPES_XML)
  qpos = np.tile(model.qpos0, (2, 41, 1))
  adr = model.jnt_qposadr[model.body("crate").jntadr[0]]
  angle = np.linspace(0, np.pi / 2, 41)
  qpos[:, :, adr:adr + 3] = (0.0, 0.0, 1.0)
  qpos[0, :, adr + 3:adr + 7] = np.stack([np.cos(angle / 2), 0 * angle, np.sin(angle / 2), 0 * angle], 1)
  qpos[1, :, adr + 3:adr + 7] = (1.0, 0.0, 0.0, 0.0)  # world 1 does not turn
  bank = ref.bank_from_qpos(qpos)
  lo, hi = (-0.5, -0.5, 1.1), (0.5, 0.5, 1.5)
  com = mq.Query.region(lo, hi, bodies="crate")
  geometry = mq.Query.region(lo, hi, bodies="crate", shape="geometry")
  early = mq.Query.region(lo, hi, bodies="crate", shape="geometry", window=(0.0, 0.05))
  late = mq.Query.region(lo, hi, bodies="crate", shape="geometry", window=(0.2, None))
  assert bank.com[:, :, 0, 2].max() < 1.05  # the COM stays well below the box
  each = mwbx.evaluate_each(bank, [com, geometry, early, late])
  np.testing.assert_array_equal(each, [[False, True, False, True], [False, False, False, False]])
  mask = np.zeros(len(bank.body_names), bool)
  mask[0] = True
  brute = ref.brute_geometry_hits(bank, geometry.frustum, mask, None, SPACING)[:, 0]
  np.testing.assert_array_equal(brute, [True, False])
  # Exclude: the COM query lets the turning crate pass, the geometry query does not.
  excl = [mq.Query.region(lo, hi, bodies="crate", sign="exclude", shape=s) for s in ("com", "geometry")]
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, excl), [[True, False], [True, True]])
  # The gap is 0 exactly where met and grades the misses.
  gaps = mq.query_gaps(bank, [geometry, excl[1]])
  assert gaps[0, 0] == 0 and gaps[1, 0] > 0 and gaps[0, 1] > 0 and gaps[1, 1] == 0


def test_sweep_margins_bound_every_stored_frame(bank):
  """Every stored frame between two kept frames, and the motion between
  stored frames, stays within the interval's margin of a kept frame."""
  model = bank.model
  data = mujoco.MjData(model)
  index = geometry_lib.geometry_index(bank)
  stride = int(index.frames[1] - index.frames[0])
  surf = {b: ref.body_surface(model, int(bank.body_ids[b]), 0.01) for b in range(len(bank.body_names))}

  def points(q):
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    return {b: np.concatenate([ref.world_points(data, g, p) for g, p in geoms]) for b, geoms in surf.items()}

  worst = 0.0
  for row in range(0, bank.n_worlds, 3):
    q = bank.qpos_store.row_frames(row)
    q = np.concatenate([q, np.repeat(q[-1:], index.frames[-1] + 1 - len(q), axis=0)])
    for i in range(len(index.frames) - 1):
      a, b = points(q[index.frames[i]]), points(q[index.frames[i + 1]])
      for j in range(index.frames[i], index.frames[i + 1] + 1):
        here = points(q[j])
        for body in surf:
          moved = np.minimum(np.linalg.norm(here[body] - a[body], axis=1),
                             np.linalg.norm(here[body] - b[body], axis=1)).max()
          assert moved <= index.sweep[body, row, i] + 1e-6
          worst = max(worst, moved / index.sweep[body, row, i])
      assert index.frames[i + 1] - index.frames[i] == stride
  assert worst > 0.3  # the margins are not vacuous


def test_codec_bound_covers_the_simulated_motion():
  """On a bank coded under loose bounds, every hit of the qpos before coding
  (what was simulated) is still found."""
  model = mujoco.MjModel.from_xml_string(ref.SHAPES_XML)
  raw = ref.shapes_bank(n_worlds=6, n_frames=25, seed=4)
  coded = ref.shapes_bank(n_worlds=6, n_frames=25, seed=4, store=CompressedQposStore.from_model(
      model, CodecBounds(e_pos=5e-3, e_rot=0.03, e_scalar=0.01)))
  index = geometry_lib.geometry_index(coded)
  assert (index.codec > 5e-3).all()
  rng = np.random.default_rng(5)
  mask = np.ones(len(raw.body_names), bool)
  for frustum in ref.random_frustums(rng, 6):
    truth = ref.brute_geometry_hits(raw, frustum, mask, None, SPACING)
    assert not (truth & ~geometry_hits(index, frustum, mask, None)).any()


def test_exact_test_on_random_convex_pairs():
  """convex.separated is exact: apart exactly where a fine sampling of both
  shapes puts them farther than the grown distance (up to its spacing)."""
  from scipy.spatial import cKDTree
  rng = np.random.default_rng(7)
  cam = mq.Camera.look_at((0.2, -2.0, 0.4), (0.0, 0.0, 0.1), fovy=50)
  frustum = cam.frustum(mq.ScreenBox(0.35, 0.4, 0.6, 0.55), 1.7, 2.3)
  volume = convex.clipped(frustum, (-3, -3, -3), (3, 3, 3))
  assert len(volume.vertices) == 8 and len(volume.edge_dirs) == 12
  lo, hi = volume.vertices.min(axis=0), volume.vertices.max(axis=0)
  dense = rng.uniform(lo, hi, (400_000, 3))
  dense = dense[frustum.contains(dense)]
  tree = cKDTree(np.concatenate([dense, volume.vertices]))
  half = np.array([0.1, 0.05, 0.02])
  signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
  edges = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(signs[i] != signs[j]) == 1])
  solid = np.stack(np.meshgrid(*[np.linspace(-1, 1, 11)] * 3, indexing="ij"), -1).reshape(-1, 3) * half
  n = 80
  rot = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(n)])
  rot *= np.sign(np.linalg.det(rot))[:, None, None]
  centre = rng.uniform(lo - 0.15, hi + 0.15, (n, 3))
  grow = rng.uniform(0, 0.05, n)
  points = centre[:, None] + np.einsum("nij,vj->nvi", rot, signs * half)
  apart = convex.separated(points, rot, np.eye(3), np.eye(3), edges, grow, volume)
  # How much the samplings can overstate a distance: the solid grid's cell
  # half-diagonal plus (generously) the volume's largest gap between samples.
  spacing = 0.012 + 2 * float(np.max(tree.query(dense[:2000], k=2)[0][:, 1]))
  decided = 0
  for k in range(n):
    d = float(tree.query(centre[k] + solid @ rot[k].T)[0].min())  # >= the true distance
    if d <= grow[k]:
      assert not apart[k], k  # truly within: never apart
      decided += 1
    elif d > grow[k] + spacing:
      assert apart[k], k  # truly apart: found apart (exact, not only conservative)
      decided += 1
  assert decided > n // 2 and 0 < apart.sum() < n


def test_geometry_queries_validate_and_round_trip(bank, tmp_path):
  q = mq.Query.region((-1, -1, 0.5), (1, 1, 1.5), bodies=["crate", "arm"], shape="geometry", sign="exclude",
                      window=(0.1, None), name="clear")
  again = mwbx.load_queries(mq.QuerySet((q,)).save(tmp_path / "q.yaml"), bank=bank).queries[0]
  assert again.shape == "geometry" and again.bodies == ("crate", "arm") and again.window == (0.1, None)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, [again]), mwbx.evaluate_each(bank, [q]))
  with pytest.raises(MwbxError, match="radius must be 0"):
    mq.Query.region((0, 0, 0), (1, 1, 1), shape="geometry", radius=0.1)
  with pytest.raises(MwbxError, match="shape must be one of"):
    mq.Query.region((0, 0, 0), (1, 1, 1), shape="hull")
  path = tmp_path / "bad.yaml"
  path.write_text("queries:\n  - {region: {min: [0, 0, 0], max: [1, 1, 1]}, shape: hull}\n")
  with pytest.raises(MwbxError, match=r"bad.yaml: queries\[0\].shape"):
    mwbx.load_queries(path, bank=bank)
