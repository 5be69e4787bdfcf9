"""Adding and removing objects in a refinement (paper §5, the refrigerator toy):
a bank moves to a later version of its scene, added objects enter the active
set at t_min, removed ones leave while their ghosts stay; objects the change
never reaches keep their stored paths exactly (mwbx/bank/versions.py,
mwbx/refinement/refine.py)."""

import math

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.bank import versions
from mwbx.errors import MwbxError
from conftest import REPO

TOY = REPO / "configs" / "refrigerator_toy.yaml"
TOY_BLOCK = REPO / "configs" / "refrigerator_toy_block.yaml"
BUCKET_TOP_X, BUCKET_FLOOR_Z, CHUTE_Z = 0.035, 0.70, 0.62  # m, from mwbx/assets/refrigerator_toy.xml


@pytest.fixture(scope="module")
def toy_bank():
  return mwbx.sample(mwbx.load_config(TOY), n_worlds=6, key=jax.random.key(0), backend="native")


def _columns(bank, obj):
  return bank.qpos_columns(f"object:{obj}")


def _marble_xz(bank, world):
  q = bank.qpos_frames(world)
  c = _columns(bank, "marble")
  return q[:, c[0]], q[:, c[2]]


def _activated_frame(bank, child, obj):
  t = bank.lineage[str(child)]["activated_at"].get(obj)
  return None if t is None else int(round(t * bank.record_fps))


def test_adding_a_block_stops_the_marble_and_keeps_untouched_objects_exactly(toy_bank):
  parent = int(toy_bank.world_ids[0])
  before = toy_bank.qpos_frames(parent)
  phases = []
  bank = mwbx.refine(toy_bank, parent, scene=TOY_BLOCK, add="block", t_min=0.0, n_samples=4,
                     key=jax.random.key(1), backend="native", progress=lambda p: phases.append(p.phase))
  assert len(bank.versions) == 1 and "block" in bank.objects
  assert phases[0] == "re-laying" and "refining" in phases
  # Every world kept; the old ones decode exactly as before, the block parked in them.
  after = bank.qpos_frames(parent)
  np.testing.assert_array_equal(after[:, :before.shape[1]], before)
  block = _columns(bank, "block")
  e_pos = bank.config["codec"]["e_pos"]  # parked values are coded like any others
  np.testing.assert_allclose(after[:, block[:3]], np.broadcast_to(versions.PARKED_POSITION, (len(after), 3)),
                             atol=e_pos)
  assert bank.absent(parent) == {"block": (0.0, math.inf)}
  assert int(bank.scene_version[bank.row_of(parent)]) == 0

  px, _ = _marble_xz(bank, parent)
  children = [int(c) for c in bank.children(parent)]
  assert len(children) == 4
  untouched = 0
  for child in children:
    assert int(bank.scene_version[bank.row_of(child)]) == 1
    assert bank.lineage[str(child)]["added"] == {"block": 0.0}
    assert bank.absent(child) == {}
    q = bank.qpos_frames(child)
    cx, _ = _marble_xz(bank, child)
    # The marble replays its stored path until the block reaches it (re-coded
    # with the rest of its channel: within the bound), then stops against it on
    # the top chute instead of going on.
    hit = _activated_frame(bank, child, "marble")
    assert hit is not None and hit > 0
    np.testing.assert_allclose(cx[:hit], px[:hit], atol=e_pos * 1.0001)
    assert abs(cx[-1] - q[0, block[0]]) < 0.1 and abs(cx[-1] - px[-1]) > 0.05
    for obj in bank.objects:
      if obj not in bank.lineage[str(child)]["active"]:
        untouched += 1
        np.testing.assert_array_equal(q[:, _columns(bank, obj)], after[:len(q), _columns(bank, obj)])
  assert untouched > 0  # the bucket the marble never reached


def test_removing_the_top_bucket_lets_the_marble_fall_through(toy_bank):
  # A parent whose marble the top bucket turned to the right: the left bucket
  # never moved in it, and a marble falling through lands on the right chute too.
  left = _columns(toy_bank, "bucket_left")[0]
  top = _columns(toy_bank, "bucket_top")[0]
  parents = [int(w) for w in toy_bank.world_ids
             if np.abs(toy_bank.qpos_frames(int(w))[:, left]).max() < 1e-3
             and toy_bank.qpos_frames(int(w))[:, top].max() > 0.5]
  assert parents, "no sampled world tipped the top bucket right"
  parent = parents[0]
  t_min = 1.0  # s: the marble is still on the top chute
  bank = mwbx.refine(toy_bank, parent, remove="bucket_top", t_min=t_min, n_samples=4, key=jax.random.key(2),
                     backend="native")
  stored = bank.qpos_frames(parent)
  px, pz = _marble_xz(bank, parent)
  below_bucket = lambda x, z: np.any((np.abs(x - BUCKET_TOP_X) < 0.03) & (z < BUCKET_FLOOR_Z) & (z > CHUTE_Z))
  assert not below_bucket(px, pz)  # the bucket held it
  f0 = int(round(t_min * bank.record_fps))
  untouched = 0
  for child in (int(c) for c in bank.children(parent)):
    entry = bank.lineage[str(child)]
    assert entry["removed"] == {"bucket_top": t_min} and "bucket_top" not in entry["active"]
    assert bank.absent(child) == {"bucket_top": (t_min, math.inf)}
    q = bank.qpos_frames(child)
    cx, cz = _marble_xz(bank, child)
    assert below_bucket(cx, cz)  # fell through where the bucket was
    np.testing.assert_array_equal(q[f0:, top], np.full(len(q) - f0, stored[f0, top]))  # parked at its angle
    if "bucket_left" not in entry["active"]:
      untouched += 1
      np.testing.assert_array_equal(q[:, left], stored[:len(q), left])
  assert untouched > 0
  # Refined again later, the removed bucket stays out: parked at its angle,
  # colliding with nothing, even when the marble passes where it was.
  child = int(bank.children(parent)[0])
  again = mwbx.refine(bank, child, "marble", t_min=1.2, n_samples=2, key=jax.random.key(3), backend="native")
  for grandchild in (int(c) for c in again.children(child)):
    assert again.absent(grandchild) == {"bucket_top": (t_min, math.inf)}
    q = again.qpos_frames(grandchild)
    np.testing.assert_array_equal(q[f0:, top], np.full(len(q) - f0, stored[f0, top]))
    assert below_bucket(*_marble_xz(again, grandchild))


def test_an_upgraded_bank_is_rewritten_in_place_and_loads_back(toy_bank, tmp_path):
  path = tmp_path / "fridge"
  toy_bank.save(path)
  loaded = mwbx.Bank.load(path)
  bank = mwbx.refine(loaded, int(loaded.world_ids[1]), scene=TOY_BLOCK, add="block", t_min=0.5, n_samples=2,
                     key=jax.random.key(3), backend="native")
  bank.save(path)
  back = mwbx.Bank.load(path)
  assert back.digest == bank.digest and len(back.versions) == 1
  assert back.versions[0]["digest"] == toy_bank.digest
  np.testing.assert_array_equal(back.scene_version, bank.scene_version)
  np.testing.assert_array_equal(back.world_ids, bank.world_ids)
  for w in back.world_ids:
    np.testing.assert_array_equal(back.qpos_frames(int(w)), bank.qpos_frames(int(w)))
  child = int(back.world_ids[-1])
  assert back.absent(child) == {"block": (0.0, 0.5)}
  # A world of the new version refines as any other.
  again = mwbx.refine(back, child, "marble", t_min=1.0, n_samples=2, key=jax.random.key(4), backend="native")
  assert again.n_worlds == back.n_worlds + 2
  assert again.absent(int(again.world_ids[-1])) == {"block": (0.0, 0.5)}


def test_the_command_line_adds_and_removes(toy_bank, tmp_path, capsys):
  path = tmp_path / "fridge"
  toy_bank.save(path)
  assert cli.main(["refine", str(path), "--world", "2", "--scene", str(TOY_BLOCK), "--add", "block",
                   "--time", "0.2", "--samples", "2", "--seed", "5", "--backend", "native"]) == 0
  assert cli.main(["refine", str(path), "--world", "3", "--remove", "bucket_left", "--time", "0.5",
                   "--samples", "2", "--seed", "6", "--backend", "native"]) == 0
  captured = capsys.readouterr()
  out = captured.out
  assert "added: block" in out and "removed: bucket_left" in out
  assert captured.err.count("mwbx: bank moved to scene version 1 (") == 1  # the first call only
  bank = mwbx.Bank.load(path)
  assert bank.n_worlds == toy_bank.n_worlds + 4 and len(bank.versions) == 1
  assert bank.absent(int(bank.world_ids[-1]))["bucket_left"] == (0.5, math.inf)
  # Sampling more worlds of the current version into it records their version.
  assert cli.main(["sample", str(TOY_BLOCK), "--worlds", "2", "--backend", "native", "--out", str(path)]) == 0
  bank = mwbx.Bank.load(path)
  assert (bank.scene_version[-2:] == 1).all() and bank.absent(int(bank.world_ids[-1])) == {}
  # An object the bank's scene does not have names the flag to fix.
  assert cli.main(["refine", str(path), "--world", "2", "--add", "ramp", "--time", "0.2", "--samples", "2"]) == 2
  assert "--scene" in capsys.readouterr().err


def test_scene_changes_that_do_not_fit_are_named(toy_bank, tmp_path):
  world = int(toy_bank.world_ids[0])
  with pytest.raises(MwbxError, match="already in world"):
    mwbx.refine(toy_bank, world, add="marble", t_min=0.5, n_samples=1, backend="native")
  with pytest.raises(MwbxError, match="remove.*'block'|unknown|block"):
    mwbx.refine(toy_bank, world, remove="block", t_min=0.5, n_samples=1, backend="native")
  # A version that drops an object of the bank, or changes its rates.
  text = (REPO / "mwbx" / "assets" / "refrigerator_toy.xml").read_text()
  start = text.index('<body name="bucket_right"')
  (tmp_path / "no_bucket.xml").write_text(text[:start] + text[text.index("</body>", start) + 7:])
  cfg = (REPO / "configs" / "refrigerator_toy.yaml").read_text()
  (tmp_path / "no_bucket.yaml").write_text(cfg.replace("refrigerator_toy.xml", "no_bucket.xml").replace(
      "buckets: [bucket_top, bucket_left, bucket_right]", "buckets: [bucket_top, bucket_left]"))
  with pytest.raises(MwbxError, match="missing: bucket_right"):
    mwbx.refine(toy_bank, world, scene=tmp_path / "no_bucket.yaml", add=(), remove="bucket_top", t_min=0.5,
                n_samples=1)
  (tmp_path / "fast.xml").write_text((REPO / "mwbx" / "assets" / "refrigerator_toy_block.xml").read_text())
  (tmp_path / "refrigerator_toy.xml").write_text(text)
  (tmp_path / "fast.yaml").write_text(cfg.replace("refrigerator_toy.xml", "fast.xml").replace(
      "end_time: 5.0", "end_time: 4.0"))
  with pytest.raises(MwbxError, match="sim: must equal"):
    mwbx.refine(toy_bank, world, scene=tmp_path / "fast.yaml", add="block", t_min=0.5, n_samples=1)
