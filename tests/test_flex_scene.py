"""A flex (MuJoCo ``<flexcomp>``) is one object named as in the MJCF: a small
cloth dropped over a static sphere beside a free box samples as the objects
``box, cloth``; its vertex bodies are tracked, not perturbed, moved together
by its randomization; rigid scenes keep exactly the objects they had."""

import dataclasses
import pathlib

import jax
import mujoco
import numpy as np
import pytest

import mwbx
from mwbx.errors import MwbxError
from mwbx.refinement import RefineRequest, run_refinement
from mwbx.scene import Scene

SCENES = pathlib.Path(__file__).parent / "scenes"

MJCF = """<mujoco>
  <option timestep="0.0020833333333333333" integrator="implicitfast"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="dome" type="sphere" size="0.12" pos="0 0 0.12"/>
    <body name="box" pos="0.4 0 0.3"><freejoint/><geom type="box" size="0.04 0.04 0.04" mass="0.2"/></body>
    <flexcomp name="cloth" type="grid" dim="2" count="5 5 1" spacing="0.06 0.06 0.06" pos="0 0 0.4"
              radius="0.01" mass="0.1" DOF>
      <edge equality="true" damping="0.01"/>
      <contact condim="3" selfcollide="none"/>
      PIN
    </flexcomp>
  </worldbody>
</mujoco>
"""

CONFIG = """scene: {mjcf: scene.xml}
sim: {end_time: 0.5, chunk_size: 4}
randomize:
  RANDOMIZE
"""

CLOTH_MOVES = """cloth:
    position: {dist: uniform, scale: [0.05, 0.05, 0.02]}
    rotation: {dist: uniform, scale: 0.3}
    linear_velocity: {dist: uniform, scale: 0.2}
    angular_velocity: {dist: uniform, scale: 1.0}
  box: {position: {dist: uniform, scale: [0.02, 0.02, 0.0]}}"""


def flex_config(tmp_path, randomize=CLOTH_MOVES, dof="", pin=""):
  (tmp_path / "scene.xml").write_text(MJCF.replace("DOF", dof).replace("PIN", pin))
  (tmp_path / "config.yaml").write_text(CONFIG.replace("RANDOMIZE", randomize))
  return mwbx.load_config(tmp_path / "config.yaml")


def vertex_bodies(model):
  return [b for b in model.flex_vertbodyid if b > 0 and model.body_dofnum[b] > 0]


def test_a_flex_is_one_object_of_its_vertex_bodies(tmp_path):
  scene = Scene(flex_config(tmp_path))
  cloth = [mujoco.mj_id2name(scene.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in vertex_bodies(scene.model)]
  assert len(cloth) == 25
  assert scene.object_names == ("box", "cloth")  # MJCF order
  assert scene.flex_objects == ("cloth",)
  assert scene.objects == {"box": ("box",), "cloth": tuple(cloth)}
  assert scene.body_names == ("box", *cloth)  # tracked by default
  np.testing.assert_array_equal(scene.select_bodies("cloth"), np.arange(1, 26))
  np.testing.assert_array_equal(scene.select_bodies("object:cloth"), np.arange(1, 26))
  assert scene.objects_of("cloth", "f") == ("cloth",)
  # Vertex bodies are never perturbed one by one; the box is, and the cloth
  # as a whole, weighted by its vertices' masses.
  np.testing.assert_array_equal(scene.perturbable, [True] + [False] * 25)
  mass = scene.model.body_mass[scene.body_ids[1:]]
  np.testing.assert_allclose(scene.flex_weight, [[0.0, *(mass / mass.sum())]], rtol=1e-6)
  np.testing.assert_array_equal(scene.flex_perturbable, [True])
  config = flex_config(tmp_path)
  excluded = Scene(config.model_copy(update={"perturb": config.perturb.model_copy(update={"exclude": ("cloth",)})}))
  np.testing.assert_array_equal(excluded.flex_perturbable, [False])


def test_pinned_vertices_are_not_part_of_it(tmp_path):
  scene = Scene(flex_config(tmp_path, pin='<pin id="0 4"/>'))
  assert scene.object_names == ("box", "cloth")
  assert len(scene.objects["cloth"]) == 23


FLAG = """<mujoco>
  <option timestep="0.0020833333333333333" integrator="implicitfast"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="pole" pos="0 0 0.8">
      <freejoint/>
      <geom type="capsule" size="0.02 0.2" mass="0.5"/>
      <flexcomp name="flag" type="grid" dim="2" count="4 4 1" spacing="0.05 0.05 0.05" pos="0.1 0 0.1"
                radius="0.005" mass="0.05">
        <edge equality="true" damping="0.01"/>
        <pin id="0 1 2 3"/>
      </flexcomp>
    </body>
  </worldbody>
</mujoco>
"""


def test_a_flex_pinned_to_a_moving_body_stays_part_of_that_body(tmp_path):
  # MuJoCo gives the pinned vertices the pole's body id: the pole must stay
  # the pole (its name, its joints, randomized and refined as a rigid body).
  (tmp_path / "flag.xml").write_text(FLAG)
  (tmp_path / "flag.yaml").write_text(
      "scene: {mjcf: flag.xml}\nsim: {end_time: 0.2}\n"
      "randomize: {pole: {angular_velocity: {dist: uniform, scale: 0.5}}}\n")
  scene = Scene(mwbx.load_config(tmp_path / "flag.yaml"))
  model = scene.model
  pole = model.body("pole").id
  assert scene.object_names == ("pole",)
  assert scene.objects["pole"] == ("pole",) + tuple(model.body(b).name for b in range(model.nbody)
                                                   if model.body_parentid[b] == pole)
  assert pole not in mwbx.scene.flex_bodies(model)["flag"]


def test_flex_randomization_moves_every_vertex_together(tmp_path):
  scene = Scene(flex_config(tmp_path))
  m = scene.model
  ids = vertex_bodies(m)
  d = mujoco.MjData(m)
  mujoco.mj_kinematics(m, d)
  before = d.xpos[ids].copy()
  unit = scene.unit_noise(jax.random.key(3))
  qpos, qvel = scene.initial_state_from_noise(unit)
  d.qpos[:] = np.asarray(qpos)
  mujoco.mj_kinematics(m, d)
  after = d.xpos[ids]
  # A rigid motion: every distance kept, the centre moved by the position draw.
  dist = lambda p: np.linalg.norm(p[:, None] - p[None], axis=-1)
  np.testing.assert_allclose(dist(after), dist(before), atol=1e-5)
  slots = {s.field: s for s in scene.noise_slots if s.object == "cloth"}
  pos = slots["position"]
  shift = np.asarray(unit[pos.start:pos.start + 3]) * np.array([0.05, 0.05, 0.02])
  np.testing.assert_allclose(after.mean(0) - before.mean(0), shift, atol=1e-5)
  assert np.abs(after - before - shift).max() > 1e-3  # and turned
  # Velocities: v + w x (p - centre) at every vertex.
  lin, ang = (np.asarray(unit[slots[f].start:slots[f].start + 3]) * s
              for f, s in (("linear_velocity", 0.2), ("angular_velocity", 1.0)))
  d.qvel[:] = np.asarray(qvel)
  vel = np.array([d.qvel[m.body_dofadr[b]:m.body_dofadr[b] + 3] for b in ids])
  np.testing.assert_allclose(vel, lin + np.cross(ang, before - before.mean(0)), atol=1e-5)


def test_flexes_refuse_what_they_cannot_do(tmp_path):
  with pytest.raises(MwbxError, match=r"randomize\.cloth\.joint_noise: object 'cloth' is a flex"):
    Scene(flex_config(tmp_path, "cloth: {joint_noise: {scale: 0.01}}"))
  with pytest.raises(MwbxError, match=r"randomize\.cloth\.position: flex 'cloth': .* not three independent slide"):
    Scene(flex_config(tmp_path, "cloth: {position: {scale: 0.01}}", dof='dof="radial"'))
  # Randomized through a group, the error names the key the user wrote.
  flex_config(tmp_path, "{}", dof='dof="radial"')
  (tmp_path / "group.yaml").write_text("scene: {mjcf: scene.xml, groups: {soft: [cloth]}}\n"
                                       "randomize: {soft: {position: {scale: 0.01}}}\n")
  with pytest.raises(MwbxError, match=r"randomize\.soft\.position: flex 'cloth': .* not three independent slide"):
    Scene(mwbx.load_config(tmp_path / "group.yaml"))
  with pytest.raises(MwbxError, match=r"scene\.objects: 'cloth_3' is not a moving body"):
    Scene(flex_config(tmp_path, "{}").model_copy(
        update={"scene": flex_config(tmp_path, "{}").scene.model_copy(update={"objects": ("cloth_3",)})}))


def test_flex_scene_samples_on_the_native_backend(tmp_path):
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=3, key=jax.random.key(0), backend="native")
  assert bank.n_worlds == 3 and tuple(bank.objects) == ("box", "cloth")
  assert len(bank.objects["cloth"]) == 25
  for w in range(3):
    frames = bank.qpos_frames(w)
    assert frames.shape[0] > 1 and np.isfinite(frames).all()
  assert np.isfinite(bank.com).all() and bank.valid.all()
  # A flex's impacts are its most-struck vertex's, not the sum over 25 vertices.
  assert bank.flex_objects == ("cloth",)
  per_body = bank.metric("collisions")
  cloth = bank.select_bodies("cloth")
  np.testing.assert_array_equal(bank.object_collisions(),
                                per_body[:, bank.select_bodies("box")].sum(-1) + per_body[:, cloth].max(-1))
  assert np.all(per_body[:, cloth].sum(-1) > per_body[:, cloth].max(-1))  # the sum would count each vertex
  from mwbx.cli import _bodies_line
  assert _bodies_line(bank) == "box, cloth_0 … cloth_24 (25 bodies of flex cloth)"
  # The cloth's contacts are the cloth's: MuJoCo reports them by flex, not by geom.
  assert mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "dome")]).all()
  assert not mwbx.evaluate(bank, [mwbx.TouchQuery("cloth", "cloth")]).any()
  # The cloth is perturbed as a whole where it strikes something: the box
  # alone perturbed (the cloth excluded) draws fewer.
  config = flex_config(tmp_path)
  alone = mwbx.sample(config.model_copy(update={"perturb": config.perturb.model_copy(update={"exclude": ("cloth",)})}),
                      n_worlds=3, key=jax.random.key(0), backend="native")
  assert np.all(bank.perturbations > alone.perturbations)
  # Refinement takes the flex as an object, active or replayed, its
  # perturbations within the bound and only on active objects.
  for objects in ("box", "cloth"):
    done = run_refinement(bank, RefineRequest(1, (objects,), t_min=0.2, n_samples=2, key=jax.random.key(1),
                                          backend="native"))
    refined, stats = done.bank, done.stats
    new = refined.world_ids[-2:]
    assert refined.n_worlds == 5 and refined.valid[-2:].all()
    assert all(np.isfinite(refined.qpos_frames(int(i))).all() for i in new)
    assert all(objects in refined.lineage[str(int(i))]["active"] for i in new)
    assert np.all(stats.max_perturbation_ratio <= 1.0 + 1e-5) and np.all(stats.inactive_perturbations == 0)
    if objects == "cloth":
      assert np.all(stats.max_perturbation_ratio > 0)  # the cloth did get perturbed


def test_flex_scene_samples_and_refines_on_mjx_warp(tmp_path):
  """MuJoCo Warp simulates flexes (here on the CPU): the cloth samples, is
  perturbed as a whole, starts where native starts, and refines."""
  pytest.importorskip("warp")
  config = flex_config(tmp_path)
  config = config.model_copy(update={"sim": config.sim.model_copy(update={"mjx_impl": "warp", "end_time": 0.3})})
  bank = mwbx.sample(config, n_worlds=2, key=jax.random.key(0), backend="mjx")
  native = mwbx.sample(config, n_worlds=2, key=jax.random.key(0), backend="native")
  assert bank.valid.all() and np.all(bank.perturbations > 0)
  e_pos = bank.config["codec"]["e_pos"]
  for w in range(2):  # the same initial states: the first frame within the codec's bound of each other
    np.testing.assert_allclose(bank.qpos_frames(w)[0], native.qpos_frames(w)[0], atol=2 * e_pos, rtol=0)
  done = run_refinement(bank, RefineRequest(1, ("cloth",), t_min=0.1, n_samples=2, key=jax.random.key(1),
                                        backend="mjx"))
  assert done.stats.backend == "mjx:warp" and done.new.valid.all()
  assert np.all(done.stats.max_perturbation_ratio <= 1.0 + 1e-5) and np.all(done.stats.inactive_perturbations == 0)


def old_objects(model):
  """The rule before flexes: moving root bodies and their trees."""
  name = lambda i: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i)
  roots = [i for i in range(1, model.nbody) if model.body_parentid[i] == 0 and model.body_dofnum[i] > 0]
  return {name(r): tuple(name(i) for i in range(1, model.nbody) if model.body_rootid[i] == r) for r in roots}


def test_rigid_scenes_keep_their_objects_and_bodies(tiny_config):
  scene = Scene(tiny_config)
  assert scene.object_names == ("cube", "ball") and scene.flex_objects == ()
  assert scene.objects == {"cube": ("cube",), "ball": ("ball",)}
  assert scene.body_names == ("cube", "ball")
  np.testing.assert_array_equal(scene.body_ids, [1, 2])
  assert scene.perturbable.all()
  for path in sorted(SCENES.glob("*.yaml")):
    scene = Scene(mwbx.load_config(path))
    if not scene.config.scene.objects and not scene.config.scene.track:
      assert scene.objects == old_objects(scene.model), path


def test_mjx_says_in_one_line_that_it_cannot_run_a_flex(tmp_path):
  with pytest.raises(MwbxError, match=r"the scene has flexes \(cloth\).*use backend: native") as err:
    mwbx.Sampler(flex_config(tmp_path), backend="mjx")
  assert "\n" not in str(err.value)


def test_the_page_draws_the_cloth_surface_where_its_vertices_are(tmp_path):
  from mwbx.browser import Browser, Session  # the page (viser) loads only for this test
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=2, key=jax.random.key(0), backend="native")
  page = Browser(Session(bank))
  try:
    (cloth,) = page.stage.flexes
    assert cloth.name == "cloth" and cloth.faces.shape == (32, 3)  # a 5x5 grid: 4x4 squares, two triangles each
    world = int(bank.world_ids[1])
    page.play(world)
    page.player.seek(10)
    mesh = page.stage._slots[0][2][-1]
    model = bank.model
    data = mujoco.MjData(model)
    data.qpos[:] = bank.qpos_frames(world)[10]
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(mesh.vertices, data.xpos[cloth.bodies], atol=1e-5)
  finally:
    page.close()


def test_viewers_draw_one_path_per_flex(tmp_path, tiny_native_bank):
  from mwbx.viewer.flex import path_bodies  # viewers load only for this test
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=1, key=jax.random.key(0), backend="native")
  drawn = [bank.body_names[i] for i in path_bodies(bank)]
  assert drawn == ["box", "cloth_12"]  # the box, and the 5x5 cloth's centre vertex
  np.testing.assert_array_equal(path_bodies(tiny_native_bank), np.arange(len(tiny_native_bank.body_names)))


def test_queries_on_a_flex(tmp_path):
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=2, key=jax.random.key(0), backend="native")
  # A COM query with radius auto grows each vertex by the flex's radius (0.01 m), as its collisions do.
  radii = mwbx.queries.body_radii(bank.model, bank.body_ids)
  cloth = [bank.body_names.index(b) for b in bank.objects["cloth"]]
  np.testing.assert_allclose(radii[cloth], 0.01)
  below = mwbx.Query.region((-1, -1, -1), (1, 1, 0.25), bodies="cloth", radius="auto", window=(0.4, None))
  assert mwbx.evaluate(bank, [below]).all()  # the cloth has fallen onto the dome
  with pytest.raises(MwbxError, match="has no orientation") as err:
    mwbx.evaluate(bank, [mwbx.OrientationQuery(bodies="cloth", axis="z", within_deg=10)])
  assert "\n" not in str(err.value)


def test_the_meshcat_viewer_animates_the_cloth_surface(tmp_path):
  import meshcat  # the viewer loads only for this test
  import umsgpack
  from mwbx import viewer
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=1, key=jax.random.key(0), backend="native")
  vis = meshcat.Visualizer(window=viewer.SceneRecorder())
  viewer.draw(vis, bank, worlds=[0], layout="overlay")
  commands = [umsgpack.unpackb(blob) for blob in vis.window.command_blobs()]
  meshes = [c for c in commands if c["type"] == "set_object" and "/flex/cloth/f" in c["path"]]
  shown = len(range(0, int(bank.frame_count[0]), 4))  # recorded at 120 fps, a surface 30 times a second
  assert len(meshes) == shown
  clips = {a["path"]: a["clip"] for c in commands if c["type"] == "set_animation" for a in c["animations"]}
  assert sum("/flex/cloth/f" in path for path in clips) == shown
  # Hidden meshes wait at a tiny scale, never a zero one: meshcat decomposes
  # a node's matrix, and a singular one leaves a NaN rotation (never shown).
  starts = [np.array(c["matrix"]).reshape(4, 4) for c in commands
            if c["type"] == "set_transform" and "/flex/cloth/f" in c["path"]]
  assert len(starts) == shown and all(abs(np.linalg.det(m)) > 0 for m in starts)


@pytest.mark.parametrize("name", ["tablecloth", "soft_steps"])
def test_shipped_flex_scenes_answer_their_query_files(name):
  repo = SCENES.parent.parent
  bank = mwbx.sample(mwbx.load_config(repo / "configs" / f"{name}.yaml"), n_worlds=2, key=jax.random.key(0),
                     backend="native")
  assert bank.valid.all(), bank.flags
  queries = mwbx.load_queries(repo / "configs" / "queries" / f"{name}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  assert each.shape == (2, len(queries.queries)) and each.any()


def test_an_interpolated_flex_is_drawn_where_mujoco_puts_its_vertices():
  """The soft cube of configs/soft_steps.yaml (dof trilinear): its surface's
  vertices from its 8 node bodies' poses, against MuJoCo's own (mj_flex) at
  random states; the viewers draw one path for it, not one per node."""
  from mwbx.viewer import flex as flex_lib
  config = mwbx.load_config(SCENES.parent.parent / "configs" / "soft_steps.yaml")
  model = Scene(config).model
  surface, = flex_lib.flex_surfaces(model)
  assert surface.name == "jelly" and surface.weights is not None and len(surface.bodies) == 8
  assert len(surface.faces) > 0 and surface.faces.max() < model.nflexvert
  data = mujoco.MjData(model)
  rng = np.random.default_rng(0)
  for _ in range(5):
    data.qpos[:] = model.qpos0 + rng.normal(0, 0.05, model.nq)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_flex(model, data)
    got = surface.vertices(data.xpos[surface.bodies], data.xquat[surface.bodies])
    np.testing.assert_allclose(got, data.flexvert_xpos, atol=1e-6)
  bank = mwbx.sample(config.model_copy(update={"sim": config.sim.model_copy(update={"end_time": 0.2})}),
                     n_worlds=1, key=jax.random.key(0), backend="native")
  assert len(flex_lib.path_bodies(bank)) == 1


def test_whole_geometry_queries_on_a_flex_against_its_vertices(tmp_path):
  """shape: geometry on the cloth: its vertices grown by the flex radius,
  against MuJoCo's own vertex positions (flexvert_xpos) at every stored frame."""
  from mwbx.queries import geometry as geometry_lib
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=4, key=jax.random.key(2), backend="native")
  model = bank.model
  data = mujoco.MjData(model)
  radius = float(model.flex_radius[0])
  n_frames = int(bank.frame_count.max())
  verts = np.zeros((bank.n_worlds, n_frames, model.nflexvert, 3))
  for w in range(bank.n_worlds):
    q = bank.qpos_store.row_frames(w)
    for j in range(n_frames):
      data.qpos[:] = q[min(j, len(q) - 1)]
      mujoco.mj_forward(model, data)
      verts[w, j] = data.flexvert_xpos
  every = geometry_lib.build(bank, np.asarray(bank.valid, bool), stride=1)  # the stated margins per stored frame
  assert every.codec.max() > 0  # a coded bank: its bound is part of the margin
  cloth = [bank.body_names.index(b) for b in bank.objects["cloth"]]
  body_of_vert = [bank.body_names.index(model.body(int(b)).name) if model.body(int(b)).name in bank.body_names
                  else -1 for b in model.flex_vertbodyid]
  rng = np.random.default_rng(0)
  hits = 0
  for k in range(12):
    w, j, v = int(rng.integers(bank.n_worlds)), int(rng.integers(n_frames)), int(rng.integers(model.nflexvert))
    centre = verts[w, j, v] + rng.uniform(-0.03, 0.03, 3)
    half = rng.uniform(0.005, 0.02, 3)
    query = mwbx.Query.region(centre - half, centre + half, bodies="cloth", shape="geometry")
    ours = mwbx.evaluate(bank, [query])
    gap = np.linalg.norm(np.maximum(np.abs(verts - centre) - half, 0.0), axis=-1)  # [W, T, V]
    exact = (gap <= radius).any(axis=(1, 2))
    margin = np.zeros(gap.shape)
    for i, b in enumerate(body_of_vert):
      if b in cloth:
        step = every.sweep[b, :, :n_frames - 1]
        margin[:, :-1, i] = step
        margin[:, 1:, i] = np.maximum(margin[:, 1:, i], step)
        margin[:, :, i] += every.codec[b]
      else:
        margin[:, :, i] = -np.inf  # pinned or static: not the cloth's
    loose = (gap <= radius + margin + 1e-6).any(axis=(1, 2))
    assert not (exact & ~ours).any(), f"box {k}: a world whose cloth meets the box is missed"
    assert not (ours & ~loose).any(), f"box {k}: an answer beyond the stated margin"
    hits += int(exact.sum())
  assert hits > 5


ROPE = """<mujoco>
  <option timestep="0.0020833333333333333" integrator="implicitfast"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="crate" type="box" size="0.1 0.1 0.1" pos="0 0 0.1"/>
    <flexcomp name="rope" type="grid" dim="1" count="8 1 1" spacing="0.05 0.05 0.05" pos="0 0 0.4"
              radius="0.01" mass="0.05">
      <edge equality="true" damping="0.01"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def test_a_rope_is_drawn_and_exported_around_its_vertices(tmp_path):
  # A rope (dim 1) has no triangles of its own: it is drawn, and written to
  # USD, as three crossed ribbons a radius either side of each vertex.
  pytest.importorskip("pxr")
  from pxr import Usd, UsdGeom

  from mwbx.viewer.flex import flex_surfaces, path_bodies
  (tmp_path / "rope.xml").write_text(ROPE)
  (tmp_path / "rope.yaml").write_text("scene: {mjcf: rope.xml}\nsim: {end_time: 0.3}\n")
  bank = mwbx.sample(mwbx.load_config(tmp_path / "rope.yaml"), n_worlds=2, key=jax.random.key(0),
                     backend="native")
  model = bank.model
  (rope,) = flex_surfaces(model)
  assert rope.name == "rope" and rope.faces.shape == (7 * 12, 3)  # 7 segments, 3 ribbons, 2 sides, 2 triangles
  assert [bank.body_names[i] for i in path_bodies(bank)] == ["rope_3"]  # one path (a middle vertex), not eight
  world = int(bank.world_ids[1])
  path = mwbx.export_usd(bank, world, tmp_path / "rope.usda")
  stage = Usd.Stage.Open(str(path))  # held: a prim outlives no stage
  mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/flexes/rope"))
  data = mujoco.MjData(model)
  for frame in (0, 20, 36):
    data.qpos[:] = bank.qpos_frames(world)[frame]
    mujoco.mj_kinematics(model, data)
    mujoco.mj_flex(model, data)
    ribbons = np.asarray(mesh.GetPointsAttr().Get(float(frame))).reshape(8, 6, 3)
    np.testing.assert_allclose(ribbons.mean(axis=1), data.flexvert_xpos, atol=1e-6)
    half_width = np.linalg.norm(ribbons - ribbons.mean(axis=1, keepdims=True), axis=-1)
    np.testing.assert_allclose(half_width, 0.01, atol=1e-6)


def test_usd_export_writes_the_cloth_where_mujoco_puts_its_vertices(tmp_path):
  pytest.importorskip("pxr")
  from pxr import Usd, UsdGeom
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=1, key=jax.random.key(0), backend="native")
  world = int(bank.world_ids[0])
  stage = Usd.Stage.Open(str(mwbx.export_usd(bank, world, tmp_path / "cloth.usdc")))
  mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/flexes/cloth"))
  assert len(mesh.GetFaceVertexCountsAttr().Get()) == 32
  model = bank.model
  data = mujoco.MjData(model)
  frame = int(bank.frame_count[0]) - 1
  data.qpos[:] = bank.qpos_frames(world)[frame]
  mujoco.mj_kinematics(model, data)
  mujoco.mj_flex(model, data)
  np.testing.assert_allclose(mesh.GetPointsAttr().Get(float(frame)), data.flexvert_xpos, atol=1e-6)


def test_turning_metrics_leave_a_flex_out_and_refuse_it_by_name(tmp_path):
  bank = mwbx.sample(flex_config(tmp_path), n_worlds=2, key=jax.random.key(0), backend="native")
  for name in ("angular_travel", "orientation_error"):
    np.testing.assert_array_equal(mwbx.queries.metric(bank, name), mwbx.queries.metric(bank, name, ["box"]))
    with pytest.raises(MwbxError, match=rf"metric '{name}': bodies: cloth is a flex's vertices") as err:
      mwbx.queries.metric(bank, name, ["cloth"])
    assert "\n" not in str(err.value)
  assert np.all(mwbx.queries.metric(bank, "path_length", ["cloth"]) > 0)  # a flex's paths are its own
  # A body a flex is pinned to keeps its orientation: queries and metrics on it stand.
  (tmp_path / "flag.xml").write_text(FLAG)
  (tmp_path / "flag.yaml").write_text("scene: {mjcf: flag.xml}\nsim: {end_time: 0.2}\n")
  flag = mwbx.sample(mwbx.load_config(tmp_path / "flag.yaml"), n_worlds=1, key=jax.random.key(0), backend="native")
  assert not flag.flex_body_mask()[list(flag.body_names).index("pole")]
  assert np.isfinite(mwbx.queries.metric(flag, "angular_travel", ["pole"])).all()
  upright = mwbx.OrientationQuery(bodies=("pole",), axis=(0, 0, 1), within_deg=180)
  assert mwbx.evaluate(flag, [upright]).all()


NOT_A_FLEX = """<mujoco>
  <!-- a flex-free scene: no flexcomp here, only the word -->
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="flexible_box" pos="0 0 0.3"><freejoint/><geom name="flex_geom" type="box" size="0.04 0.04 0.04"/></body>
  </worldbody>
</mujoco>
"""

SHEET = """<mujoco>
  <worldbody>
    <flexcomp name="cloth" type="grid" dim="2" count="5 5 1" spacing="0.06 0.06 0.06" pos="0 0 0.4"
              radius="0.01" mass="0.1">
      <edge equality="true" damping="0.01"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""

ATTACHED = """<mujoco>
  <asset><model name="sheet" file="sheet.xml"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="box" pos="0.4 0 0.3"><freejoint/><geom type="box" size="0.04 0.04 0.04" mass="0.2"/></body>
    <frame><attach model="sheet" prefix="s_"/></frame>
  </worldbody>
</mujoco>
"""


def test_a_banks_flexes_are_its_compiled_models_not_its_texts(tmp_path):
  """A bank knows its flexes from its compiled model: the word "flex" in a
  comment or a name makes none, a flex that only an attached ``<model>`` file
  holds (the scene's own MJCF never says "flex") is one, and a model that
  does not build says so rather than claiming no flexes."""
  def bank_of(xml, files=()):
    (tmp_path / "scene.xml").write_text(xml)
    for name, text in files:
      (tmp_path / name).write_text(text)
    (tmp_path / "config.yaml").write_text("scene: {mjcf: scene.xml}\nsim: {end_time: 0.05}\n")
    return mwbx.sample(mwbx.load_config(tmp_path / "config.yaml"), n_worlds=1, key=jax.random.key(0),
                       backend="native")

  rigid = bank_of(NOT_A_FLEX)
  assert rigid.model.nflex == 0 and rigid.flex_objects == () and not rigid.flex_body_mask().any()
  cloth = bank_of(MJCF.replace("DOF", "").replace("PIN", ""))
  assert cloth.flex_objects == ("cloth",)
  np.testing.assert_array_equal(cloth.flex_body_mask(), [False] + [True] * 25)
  attached = bank_of(ATTACHED, [("sheet.xml", SHEET)])
  assert "flex" not in attached.mjcf_text and attached.flex_objects == ("s_cloth",)
  assert attached.flex_body_mask().sum() == 25
  cloth = dataclasses.replace(cloth, mjcf_text="<mujoco><worldbody><flexcomp", _model=None)
  with pytest.raises(MwbxError, match=r"^bank: MJCF failed to load"):
    cloth.flex_objects
