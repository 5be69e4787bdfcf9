"""A scene whose MJCF names a mesh file by a relative path, and one that
``<include>``s its robot file (the Menagerie ``scene.xml`` -> ``robot.xml``
convention) with meshes in ``assets/``: banks sampled from them rebuild their
model, save/load, and refine, from any working directory."""

import os

import jax
import numpy as np

import mwbx

MESH = """v 0 0 0
v 0.1 0 0
v 0 0.1 0
v 0 0 0.1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
"""

MJCF = """<mujoco>
  <option timestep="0.0020833333333333333"/>
  <asset><mesh name="tet" file="meshes/tet.obj"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="piece" pos="0 0 0.3"><freejoint/><geom type="mesh" mesh="tet"/></body>
    <body name="ball" pos="0.3 0 0.3"><freejoint/><geom type="sphere" size="0.04"/></body>
  </worldbody>
</mujoco>
"""

CONFIG = """scene: {mjcf: scene.xml}
sim: {end_time: 0.4, chunk_size: 4}
randomize:
  piece: {position: {dist: uniform, scale: [0.02, 0.02, 0.0]}}
"""


def write_scene(scene_dir, files: dict) -> None:
  """Writes {relative path: text} under scene_dir, folders included."""
  for name, text in files.items():
    (scene_dir / name).parent.mkdir(parents=True, exist_ok=True)
    (scene_dir / name).write_text(text)


def test_relative_mesh_paths_survive_save_load_and_refine(tmp_path, monkeypatch):
  scene_dir = tmp_path / "scene"
  write_scene(scene_dir, {"meshes/tet.obj": MESH, "scene.xml": MJCF, "config.yaml": CONFIG})
  bank = mwbx.sample(mwbx.load_config(scene_dir / "config.yaml"), n_worlds=4,
                     key=jax.random.key(0), backend="native")
  bank.save(tmp_path / "bank")
  elsewhere = tmp_path / "elsewhere"
  elsewhere.mkdir()
  monkeypatch.chdir(elsewhere)
  loaded = mwbx.Bank.load(tmp_path / "bank")
  assert loaded.mjcf_dir() == str(scene_dir.resolve())
  model = loaded.model
  assert model.nmesh == 1 and model.nq == 14
  refined = mwbx.refine(loaded, 0, ["ball"], t_min=0.1, n_samples=2, key=jax.random.key(1),
                        backend="native")
  assert refined.n_worlds == loaded.n_worlds + 2
  assert np.isfinite(refined.qpos_frames(refined.n_worlds - 1)).all()
  assert os.getcwd() == str(elsewhere)


SCENE_WITH_INCLUDE = """<mujoco model="scene">
  <compiler meshdir="assets"/>
  <option timestep="0.0020833333333333333"/>
  <include file="robot.xml"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="ball" pos="0.3 0 0.3"><freejoint/><geom type="sphere" size="0.04"/></body>
  </worldbody>
</mujoco>
"""

ROBOT = """<mujoco model="robot">
  <asset><mesh name="tet" file="tet.obj"/></asset>
  <worldbody>
    <body name="piece" pos="0 0 0.3"><freejoint/><geom type="mesh" mesh="tet"/></body>
  </worldbody>
</mujoco>
"""


def test_scene_that_includes_its_robot_file(tmp_path, monkeypatch):
  scene_dir = tmp_path / "menagerie_style"
  write_scene(scene_dir, {"assets/tet.obj": MESH, "scene.xml": SCENE_WITH_INCLUDE, "robot.xml": ROBOT,
                          "config.yaml": CONFIG})
  monkeypatch.chdir(tmp_path)  # not the scene's folder: includes resolve against the MJCF
  cfg = mwbx.load_config(scene_dir / "config.yaml")
  scene = mwbx.Scene(cfg)
  assert scene.object_names == ("piece", "ball") and scene.model.nmesh == 1
  assert set(scene.mjcf_includes) == {"robot.xml"}
  bank = mwbx.sample(cfg, n_worlds=2, key=jax.random.key(0), backend="native")
  bank.save(tmp_path / "bank")
  (scene_dir / "robot.xml").unlink()  # the bank keeps the included file's text
  loaded = mwbx.Bank.load(tmp_path / "bank")
  assert loaded.model.nmesh == 1 and loaded.digest == bank.digest
  first = int(loaded.world_ids[0])
  refined = mwbx.refine(loaded, first, ["ball"], t_min=0.1, n_samples=2, key=jax.random.key(1),
                        backend="native")
  assert refined.n_worlds == 4
  np.testing.assert_array_equal(refined.qpos_frames(first), bank.qpos_frames(first))
