"""A bank's model is built from the MJCF text and files stored in it alone
(mwbx/scene.py parse_mjcf, mwbx/bank/assets.py): a crafted manifest whose
MJCF names a file outside the bank (an include, a <model>, a mesh, texture,
height field or skin, through a compiler folder or ``..``) is refused in one
line naming the reference, and the file is never read; banks of scenes with
such files store them and load anywhere after the scene's folder is gone."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import struct
import zlib

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.bank import assets as assets_lib
from mwbx.errors import MwbxError

TET = "v 0 0 0\nv {s} 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def _tet(size: float) -> bytes:
  return TET.format(s=size).encode()


def _png(width: int, height: int, shade: int = 100) -> bytes:
  """An RGB PNG of one colour."""
  raw = b"".join(b"\x00" + bytes([shade]) * (3 * width) for _ in range(height))

  def chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

  return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
          + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _height_field(rows: int, cols: int) -> bytes:
  """MuJoCo's binary height field: rows, columns, then float32 heights."""
  return struct.pack("ii", rows, cols) + np.linspace(0, 1, rows * cols, dtype=np.float32).tobytes()


SUB_MODEL = """<mujoco model="part">
  <compiler meshdir="shapes"/>
  <asset><mesh name="wedge" file="tet.obj"/></asset>
  <worldbody><body name="block"><freejoint/><geom type="mesh" mesh="wedge"/></body></worldbody>
</mujoco>
"""

# Every kind of file a bank stores: meshes found through meshdir (two of one
# base name), a height field (through meshdir too), a 2D texture and a cube
# texture's six files through texturedir, and a <model> with a mesh of its own.
FILES_SCENE = """<mujoco model="files">
  <compiler meshdir="meshes" texturedir="textures"/>
  <option timestep="0.0020833333333333333"/>
  <asset>
    <mesh name="tet" file="tet.obj"/>
    <mesh name="spike" file="parts/tet.obj"/>
    <hfield name="bumps" file="bumps.bin" size="1 1 0.05 0.05"/>
    <texture name="grid" type="2d" file="grid.png"/>
    <texture name="sky" type="skybox" fileright="sky/r.png" fileleft="sky/l.png" fileup="sky/u.png"
             filedown="sky/d.png" filefront="sky/f.png" fileback="sky/b.png"/>
    <material name="grid" texture="grid"/>
    <model name="part" file="parts/part.xml"/>
  </asset>
  <worldbody>
    <geom name="floor" type="hfield" hfield="bumps" material="grid"/>
    <body name="piece" pos="0 0 0.4"><freejoint/><geom type="mesh" mesh="tet"/></body>
    <body name="spike" pos="0.3 0 0.4"><freejoint/><geom type="mesh" mesh="spike"/></body>
    <frame pos="-0.3 0 0.4"><attach model="part" prefix="part-"/></frame>
  </worldbody>
</mujoco>
"""
FILES = {
    "meshes/tet.obj": _tet(0.1), "meshes/parts/tet.obj": _tet(0.3), "parts/shapes/tet.obj": _tet(0.2),
    "meshes/bumps.bin": _height_field(3, 4), "textures/grid.png": _png(4, 4),
    **{f"textures/sky/{side}.png": _png(2, 2, 40 * k) for k, side in enumerate("rludfb")},
    "parts/part.xml": SUB_MODEL.encode(),
}
CONFIG = "scene: {mjcf: scene.xml}\nsim: {end_time: 0.2, chunk_size: 2, backend: native}\n"


def _write_scene(folder: pathlib.Path) -> pathlib.Path:
  """The scene with every kind of file; its config's path."""
  for name, data in {**FILES, "scene.xml": FILES_SCENE.encode(), "cfg.yaml": CONFIG.encode()}.items():
    (folder / name).parent.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)
  return folder / "cfg.yaml"


def _same_files(model, reference) -> None:
  """Each mesh, height field and texture from the same bytes as ``reference``'s."""
  for field in ("mesh_vert", "mesh_vertnum", "hfield_data", "hfield_nrow", "tex_data", "tex_width"):
    np.testing.assert_array_equal(getattr(model, field), getattr(reference, field), err_msg=field)


@pytest.fixture
def files_bank(tmp_path):
  """(bank directory, the Scene's model) of the scene with every kind of
  file, sampled (2 worlds) from a folder that no longer exists."""
  scene_dir = tmp_path / "scene"
  cfg = mwbx.load_config(_write_scene(scene_dir))
  reference = mwbx.Scene(cfg).model
  assert reference.nmesh == 3 and reference.nhfield == 1 and reference.ntex == 2
  mwbx.sample(cfg, n_worlds=2, key=jax.random.key(0), backend="native").save(tmp_path / "bank")
  shutil.rmtree(scene_dir)
  return tmp_path / "bank", reference


def test_a_bank_stores_the_files_its_mjcf_names_and_loads_without_them(files_bank, tmp_path, monkeypatch):
  bank_dir, reference = files_bank
  table = json.loads((bank_dir / "manifest.json").read_text())["scene"]["mjcf_assets"]
  assert set(table) == set(FILES)
  for name, digest in table.items():
    assert (bank_dir / "assets" / digest).read_bytes() == FILES[name]
  elsewhere = tmp_path / "elsewhere"
  elsewhere.mkdir()
  monkeypatch.chdir(elsewhere)
  bank = mwbx.Bank.load(bank_dir)
  _same_files(bank.model, reference)  # meshes of one base name each from its own file
  _same_files(bank.scene().model, reference)
  first = int(bank.world_ids[0])
  refined = mwbx.refine(bank, first, ["piece"], t_min=0.1, n_samples=2, key=jax.random.key(1), backend="native")
  refined.save(bank_dir)
  again = mwbx.Bank.load(bank_dir, lazy=False)
  assert again.n_worlds == 4
  _same_files(again.model, reference)
  assert mwbx.bank.shards.verify(bank_dir) == []


def test_a_stored_file_that_is_a_link_is_refused_even_with_the_right_bytes(files_bank, tmp_path):
  bank_dir, _ = files_bank
  digest = json.loads((bank_dir / "manifest.json").read_text())["scene"]["mjcf_assets"]["meshes/tet.obj"]
  copy = tmp_path / "outside.obj"
  copy.write_bytes(FILES["meshes/tet.obj"])
  (bank_dir / "assets" / digest).unlink()
  (bank_dir / "assets" / digest).symlink_to(copy)
  with pytest.raises(MwbxError) as err:
    mwbx.Bank.load(bank_dir).model
  assert "'meshes/tet.obj'" in str(err.value) and "cannot be read" in str(err.value), err.value
  assert str(bank_dir / "assets" / digest) in str(err.value) and "\n" not in str(err.value)
  assert any("meshes/tet.obj" in line for line in mwbx.bank.shards.verify(bank_dir))


def test_a_bank_saved_before_banks_stored_files_is_refused_until_sampled_into_again(tmp_path):
  cfg_path = _write_scene(tmp_path / "scene")
  cfg = mwbx.load_config(cfg_path)
  bank_dir = tmp_path / "bank"
  mwbx.sample(cfg, n_worlds=2, key=jax.random.key(0), backend="native").save(bank_dir)
  manifest = json.loads((bank_dir / "manifest.json").read_text())
  del manifest["scene"]["mjcf_assets"]  # as banks were written before
  (bank_dir / "manifest.json").write_text(json.dumps(manifest))
  with pytest.raises(MwbxError, match=r"<mesh file='tet.obj'> \(in folder 'meshes'\) names 'meshes/tet.obj',"
                                      r" which is not stored with it"):
    mwbx.Bank.load(bank_dir).model
  mwbx.sample(cfg, n_worlds=2, key=jax.random.key(1), backend="native").save(bank_dir)
  _same_files(mwbx.Bank.load(bank_dir).model, mwbx.Scene(cfg).model)


def test_a_scene_naming_a_file_outside_its_folder_is_refused_before_sampling(tmp_path):
  outside = tmp_path / "outside.obj"
  outside.write_bytes(_tet(0.1))
  folder = tmp_path / "scene"
  _write_scene(folder)
  (folder / "scene.xml").write_text(FILES_SCENE.replace('file="tet.obj"', f'file="{outside}"'))
  with pytest.raises(MwbxError) as err:
    mwbx.Scene(mwbx.load_config(folder / "cfg.yaml"))
  text = str(err.value)
  assert str(folder / "cfg.yaml") in text and "scene.mjcf" in text and f"<mesh file='{outside}'>" in text
  assert "outside the MJCF's folder" in text and "\n" not in text


# -- crafted banks: a stored MJCF naming a file outside the bank --------------------------------------


@pytest.fixture
def tiny_bank_dir(tiny_native, tmp_path):
  """A saved bank of 4 worlds of tests/scenes/tiny.yaml (no files of its own)."""
  bank, _ = tiny_native.run(4, jax.random.key(0))
  bank.save(tmp_path / "bank")
  return tmp_path / "bank"


def _craft(bank_dir: pathlib.Path, before_worldbody: str, scene_dir: pathlib.Path | None = None) -> None:
  """Rewrites the bank's stored MJCF with ``before_worldbody`` ahead of its
  <worldbody> and, with ``scene_dir``, says it was sampled from there (the
  folder relative names were found in)."""
  manifest = json.loads((bank_dir / "manifest.json").read_text())
  text = manifest["scene"]["mjcf_text"]
  manifest["scene"]["mjcf_text"] = text.replace("<worldbody>", before_worldbody + "\n  <worldbody>", 1)
  if scene_dir is not None:
    manifest["scene"]["config"]["source"] = str(scene_dir / "tiny.yaml")
    (scene_dir / "tiny.xml").write_text(text)  # the MJCF is there: its relative names were found from there
  (bank_dir / "manifest.json").write_text(json.dumps(manifest))


SIDES = ("right", "left", "up", "down", "front", "back")


def _outside_files(folder: pathlib.Path) -> None:
  """Files a crafted MJCF names, each one the load would take if it read it."""
  folder.mkdir(parents=True, exist_ok=True)
  (folder / "tet.obj").write_bytes(_tet(0.1))
  (folder / "grid.png").write_bytes(_png(4, 4))
  for side in SIDES:
    (folder / f"{side}.png").write_bytes(_png(2, 2))
  (folder / "bumps.bin").write_bytes(_height_field(3, 4))
  (folder / "skin.skn").write_bytes(b"\x00" * 64)  # read, MuJoCo would name its content
  (folder / "evil.xml").write_text('<mujoco><worldbody><body name="evil"><geom size="0.1"/></body>'
                                   '</worldbody></mujoco>')
  (folder / "planted.xml").write_text('<mujoco><asset><mesh name="planted" file="tet.obj"/></asset></mujoco>')


# (case, MJCF ahead of <worldbody> with {out} the outside folder, the reference the message names)
CRAFTED = [
    ("include", '<include file="{out}/planted.xml"/>', "includes '{out}/planted.xml', which is not stored"),
    ("model", '<asset><model name="mm" file="{out}/evil.xml"/></asset>', "<model file='{out}/evil.xml'>"),
    ("mesh", '<asset><mesh name="m" file="{out}/tet.obj"/></asset>', "<mesh file='{out}/tet.obj'>"),
    ("texture", '<asset><texture name="t" type="2d" file="{out}/grid.png"/></asset>',
     "<texture file='{out}/grid.png'>"),
    ("cube texture", '<asset><texture name="sky" type="skybox" '
     + " ".join(f'file{side}="{{out}}/{side}.png"' for side in SIDES) + "/></asset>",
     "<texture fileright='{out}/right.png'>"),
    ("hfield", '<asset><hfield name="h" file="{out}/bumps.bin" size="1 1 0.1 0.1"/></asset>',
     "<hfield file='{out}/bumps.bin'>"),
    ("skin", '<asset><skin file="{out}/skin.skn"/></asset>', "<skin file='{out}/skin.skn'>"),
    ("meshdir", '<compiler meshdir="{out}"/><asset><mesh name="m" file="tet.obj"/></asset>',
     "<mesh file='tet.obj'> (in folder '{out}')"),
    ("texturedir", '<compiler texturedir="{out}"/><asset><texture name="t" type="2d" file="grid.png"/></asset>',
     "<texture file='grid.png'> (in folder '{out}')"),
    ("assetdir", '<compiler assetdir="{out}"/><asset><hfield name="h" file="bumps.bin" size="1 1 0.1 0.1"/>'
     '</asset>', "<hfield file='bumps.bin'> (in folder '{out}')"),
]


@pytest.mark.parametrize("case, snippet, named", CRAFTED, ids=[c[0] for c in CRAFTED])
def test_a_crafted_bank_naming_a_file_outside_it_is_refused_in_one_line(tiny_bank_dir, tmp_path, case, snippet,
                                                                        named):
  out = tmp_path / "elsewhere"
  _outside_files(out)
  _craft(tiny_bank_dir, snippet.format(out=out))
  bank = mwbx.Bank.load(tiny_bank_dir)
  for build in (lambda: bank.model, bank.scene):  # the bank's model, and the scene refinement resamples
    with pytest.raises(MwbxError) as err:
      build()
    text = str(err.value)
    assert named.format(out=out) in text, text
    assert ("outside the bank" in text or "not stored with it" in text) and "\n" not in text, text


def test_a_relative_name_leaving_the_folder_is_refused(tiny_bank_dir, tmp_path):
  # Found relative to where the bank says it was sampled, ../elsewhere/tet.obj exists.
  _outside_files(tmp_path / "elsewhere")
  (tmp_path / "scene").mkdir()
  _craft(tiny_bank_dir, '<asset><mesh name="m" file="../elsewhere/tet.obj"/></asset>', scene_dir=tmp_path / "scene")
  with pytest.raises(MwbxError, match=r"<mesh file='../elsewhere/tet.obj'> names a file outside the bank"):
    mwbx.Bank.load(tiny_bank_dir).model


def test_a_relative_name_the_bank_does_not_store_is_refused(tiny_bank_dir, tmp_path):
  # The folder the bank says it was sampled from holds meshes/tet.obj: it is not read.
  (tmp_path / "scene" / "meshes").mkdir(parents=True)
  (tmp_path / "scene" / "meshes" / "tet.obj").write_bytes(_tet(0.1))
  _craft(tiny_bank_dir, '<asset><mesh name="m" file="meshes/tet.obj"/></asset>', scene_dir=tmp_path / "scene")
  with pytest.raises(MwbxError, match=r"<mesh file='meshes/tet.obj'> names 'meshes/tet.obj', which is not stored"):
    mwbx.Bank.load(tiny_bank_dir).model


def test_refine_of_a_crafted_bank_exits_2_naming_the_model_file(tiny_bank_dir, tmp_path, capsys):
  # `mwbx refine` opened the <model> file and exited 0.
  out = tmp_path / "elsewhere"
  _outside_files(out)
  _craft(tiny_bank_dir, f'<asset><model name="mm" file="{out}/evil.xml"/></asset>')
  code = cli.main(["refine", str(tiny_bank_dir), "--world", "0", "--objects", "ball", "--time", "0.5",
                   "--samples", "2", "--backend", "native"])
  err = capsys.readouterr().err
  assert code == 2, err
  assert f"<model file='{out}/evil.xml'>" in err and "outside the bank" in err
  assert len(err.strip().splitlines()) == 1, err
  assert mwbx.Bank.load(tiny_bank_dir).n_worlds == 4


def test_a_manifest_entry_that_is_not_a_hash_is_refused(tiny_bank_dir):
  manifest = json.loads((tiny_bank_dir / "manifest.json").read_text())
  manifest["scene"]["mjcf_assets"] = {"meshes/tet.obj": "../../../etc/passwd"}
  (tiny_bank_dir / "manifest.json").write_text(json.dumps(manifest))
  with pytest.raises(MwbxError, match=r"scene.mjcf_assets\['meshes/tet.obj'\]: '../../../etc/passwd' is not a"
                                      r" sha256"):
    mwbx.Bank.load(tiny_bank_dir)


def test_stored_files_are_written_once_by_content(tmp_path):
  data = {"a/x.obj": _tet(0.1), "b/x.obj": _tet(0.1), "c.png": _png(2, 2)}
  table = assets_lib.write(tmp_path, data)
  assert len(os.listdir(tmp_path / "assets")) == 2 and table["a/x.obj"] == table["b/x.obj"]
  stored = assets_lib.stored(tmp_path, table)
  assert dict(stored) == data and assets_lib.table(stored) == table
