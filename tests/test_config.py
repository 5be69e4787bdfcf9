"""Configs: defaults, validation, and one clear message per user mistake."""

import pathlib
import textwrap

import numpy as np
import pytest

import mwbx

SCENES = pathlib.Path(__file__).parent / "scenes"


def write(tmp_path, text, name="cfg.yaml"):
  path = tmp_path / name
  path.write_text(textwrap.dedent(text))
  return path


def test_shipped_configs_load_with_defaults(quickstart_config):
  cfg = quickstart_config
  assert cfg.sim.record_fps == 120 and cfg.sim.query_fps == 30
  assert cfg.perturb.alpha == 0.1
  scene = mwbx.Scene(cfg)
  assert scene.object_names == ("box_a", "ball", "capsule", "box_b")
  assert scene.groups["round"] == ("ball", "capsule")
  pachinko = mwbx.Scene(mwbx.load_config(pathlib.Path(__file__).parents[1] / "configs" / "pachinko.yaml"))
  assert len(pachinko.object_names) == 8


def test_packaged_assets_resolve_without_the_repo(tmp_path):
  # A config anywhere naming a shipped scene finds the packaged MJCF.
  path = write(tmp_path, "scene: {mjcf: quickstart.xml}\n")
  assert mwbx.load_config(path).mjcf_path().parent.name == "assets"
  assert mwbx.load_config("quickstart").scene.mjcf == "quickstart.xml"


@pytest.mark.parametrize("body, field, message", [
    ("scene: {mjcf: tiny.xml, colour: red}\n", "scene.colour", "unknown key"),
    ("scene: {mjcf: tiny.xml}\nsim: {end_time: fast}\n", "sim.end_time", "valid number"),
    ("scene: {mjcf: tiny.xml}\nsim: {end_time: -1}\n", "sim.end_time", "greater than 0"),
    ("scene: {mjcf: tiny.xml}\nperturb: {alpha: 2}\n", "perturb.alpha", "less than or equal"),
    ("scene: {mjcf: tiny.xml}\nsim: {backend: gpu}\n", "sim.backend", "auto"),
    ("sim: {end_time: 1}\n", "scene", "Field required"),
    ("scene: {mjcf: tiny.xml}\ncodec: {e_rot_deg: 45}\n", "codec.e_rot_deg", "less than 28.6"),
    ("scene: {mjcf: tiny.xml}\nrandomize: {cube: {position: {dist: cauchy}}}\n",
     "randomize.cube.position.dist", "uniform"),
])
def test_bad_values_name_file_and_field(tmp_path, body, field, message):
  path = write(tmp_path, body)
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  text = str(err.value)
  assert str(path) in text and field in text and message in text


def test_malformed_yaml(tmp_path):
  path = write(tmp_path, "scene: {mjcf: tiny.xml\n")
  with pytest.raises(mwbx.MwbxError, match="malformed YAML") as err:
    mwbx.load_config(path)
  assert str(path) in str(err.value)
  # One line: where and what, not PyYAML's snippet, caret and "<unicode string>".
  assert "\n" not in str(err.value) and "unicode string" not in str(err.value)
  assert "line 2, column 1" in str(err.value), err.value


def test_missing_config_file(tmp_path):
  with pytest.raises(mwbx.MwbxError, match="cannot read config"):
    mwbx.load_config(tmp_path / "nope.yaml")


def scene_error(tmp_path, body, mjcf_text=None):
  if mjcf_text is not None:
    (tmp_path / "model.xml").write_text(mjcf_text)
  else:
    (tmp_path / "tiny.xml").write_text((SCENES / "tiny.xml").read_text())
  path = write(tmp_path, body)
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.Scene(mwbx.load_config(path))
  return str(err.value), path


@pytest.mark.parametrize("body, field, needle", [
    ("scene: {mjcf: tiny.xml, objects: [cube, crate]}\n", "scene.objects", "'crate'"),
    ("scene: {mjcf: tiny.xml, track: [cube, wheel]}\n", "scene.track", "'wheel'"),
    ("scene: {mjcf: tiny.xml, groups: {g: [cube, ghost]}}\n", "scene.groups.g", "'ghost'"),
    ("scene: {mjcf: tiny.xml, groups: {g: [cube, h], h: [g]}}\n", "scene.groups", "contains itself"),
    ("scene: {mjcf: tiny.xml}\nrandomize: {crate: {position: {scale: 0.1}}}\n", "randomize.crate", "'crate'"),
    ("scene: {mjcf: tiny.xml}\nperturb: {exclude: [anvil]}\n", "perturb.exclude", "'anvil'"),
    ("scene: {mjcf: tiny.xml}\nrandomize: {cube: {position: {scale: [1, 2]}}}\n",
     "randomize.cube.position.scale", "expected 1 or 3"),
    ("scene: {mjcf: tiny.xml}\nrandomize: {cube: {joint_noise: {scale: 0.1}}}\n",
     "randomize.cube.joint_noise", "no hinge or slide"),
])
def test_unknown_names_name_file_and_field(tmp_path, body, field, needle):
  text, path = scene_error(tmp_path, body)
  assert str(path) in text and field in text and needle in text


@pytest.mark.parametrize("mjcf", [
    "<mujoco><worldbody><body><geom type='sphere'/></worldbody></mujoco>",
    "<mujoco>\n  <worldbody>\n    <body name='a'><freejoint/><geom size='0.1' typo='3'/></body>\n"
    "  </worldbody>\n</mujoco>",
    "<mujoco><worldbody><body name='a'><freejoint/><geom type='mesh' mesh='nope'/></body></worldbody></mujoco>",
])
def test_mjcf_that_fails_to_load(tmp_path, mjcf):
  text, path = scene_error(tmp_path, "scene: {mjcf: model.xml}\n", mjcf)
  assert str(path) in text and "scene.mjcf" in text and "MJCF failed to load" in text
  assert "\n" not in text, text  # MuJoCo's element and line on the same line


@pytest.mark.parametrize("body, field", [
    ("sim: {end_time: true}\n", "sim.end_time"),
    ("perturb: {alpha: false}\n", "perturb.alpha"),
    ("randomize: {cube: {position: {scale: [true, 0, 0]}}}\n", "randomize.cube.position.scale"),
])
def test_booleans_are_not_numbers(tmp_path, body, field):
  path = write(tmp_path, "scene: {mjcf: tiny.xml}\n" + body)
  with pytest.raises(mwbx.MwbxError, match="true/false are not numbers") as err:
    mwbx.load_config(path)
  assert str(path) in str(err.value) and field in str(err.value)


def test_mjcf_without_moving_bodies(tmp_path):
  text, path = scene_error(tmp_path, "scene: {mjcf: model.xml}\n",
                           "<mujoco><worldbody><geom type='plane' size='1 1 1'/></worldbody></mujoco>")
  assert str(path) in text and "scene.mjcf: no moving bodies" in text


def test_missing_mjcf(tmp_path):
  path = write(tmp_path, "scene: {mjcf: nowhere.xml}\n")
  with pytest.raises(mwbx.MwbxError, match="scene.mjcf: no file"):
    mwbx.Scene(mwbx.load_config(path))


def test_timestep_must_divide_frame_time(tmp_path):
  (tmp_path / "tiny.xml").write_text((SCENES / "tiny.xml").read_text())
  path = write(tmp_path, "scene: {mjcf: tiny.xml}\nsim: {timestep: 0.003, record_fps: 120}\n")
  with pytest.raises(mwbx.MwbxError, match="sim.timestep"):
    mwbx.Sampler(mwbx.load_config(path), backend="native")


def test_articulated_objects_and_groups():
  cfg = mwbx.config_from_dict(
      {"scene": {"mjcf": str(SCENES / "chain.xml"), "groups": {"g": ["root"], "gg": ["g", "puck"]}}},
      source=str(SCENES / "chain.yaml"))
  scene = mwbx.Scene(cfg)
  assert scene.objects == {"root": ("root", "link1"), "puck": ("puck",)}
  assert scene.groups["gg"] == ("root", "puck")
  assert list(scene.select_bodies("gg")) == [0, 1, 2]
  assert list(scene.select_bodies(["link1", "puck"])) == [1, 2]


def test_joint_types_match_mujoco():
  import mujoco
  from mwbx import joints
  for name in ("FREE", "BALL", "SLIDE", "HINGE"):
    assert getattr(joints, f"JNT_{name}") == int(getattr(mujoco.mjtJoint, f"mjJNT_{name}"))


def test_joint_noise_varies_a_hinged_objects_angles():
  import jax
  cfg = mwbx.config_from_dict(
      {"scene": {"mjcf": str(SCENES / "chain.xml")},
       "randomize": {"root": {"joint_noise": {"dist": "uniform", "scale": 0.3}}}},
      source=str(SCENES / "chain.yaml"))
  scene = mwbx.Scene(cfg)
  hinge = scene.model.jnt_qposadr[scene.model.joint("hinge1").id]
  keys = jax.random.split(jax.random.key(0), 8)
  qpos = np.stack([np.asarray(scene.initial_state(k)[0]) for k in keys])
  angles = qpos[:, hinge]
  assert np.all(np.abs(angles - scene.model.qpos0[hinge]) <= 0.3 + 1e-6)
  assert np.unique(angles).size == 8 and np.ptp(angles) > 0.1  # varies across worlds
  others = np.delete(qpos, hinge, axis=1)
  np.testing.assert_array_equal(others, np.broadcast_to(others[0], others.shape))  # nothing else moves


def test_body_and_object_spellings_when_an_object_shares_its_root_bodys_name():
  cfg = mwbx.config_from_dict({"scene": {"mjcf": str(SCENES / "chain.xml"), "groups": {"g": ["root"]}}},
                              source=str(SCENES / "chain.yaml"))
  scene = mwbx.Scene(cfg)
  assert list(scene.select_bodies("root")) == [0, 1]  # bare: the object (today's meaning)
  assert list(scene.select_bodies("object:root")) == [0, 1]
  assert list(scene.select_bodies("body:root")) == [0]  # the root body alone
  assert list(scene.select_bodies(["body:link1", "group:g"])) == [1, 0]
  assert scene.objects_of("object:puck", "f") == ("puck",)
  with pytest.raises(mwbx.MwbxError, match="unknown body 'body:ghost'"):
    scene.select_bodies("body:ghost")
  with pytest.raises(mwbx.MwbxError, match="unknown group 'group:root'"):
    scene.select_bodies("group:root")
  with pytest.raises(mwbx.MwbxError, match="bodies are not objects"):
    scene.objects_of("body:link1", "randomize.body:link1")


@pytest.mark.parametrize("name", ["quickstart.yaml", "pachinko.yaml"])
def test_configs_copies_match_the_packaged_assets(name):
  """configs/quickstart.yaml and configs/pachinko.yaml are the packaged configs,
  shown where users look first; an edit to one must be made to the other."""
  repo = pathlib.Path(__file__).parent.parent
  assert (repo / "configs" / name).read_bytes() == (repo / "mwbx" / "assets" / name).read_bytes()

