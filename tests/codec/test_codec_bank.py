"""The codec inside real sampled banks: guarantee, save/load, corruption, `mwbx info`."""

import json
import re

import numpy as np
import pytest

import jax
import mwbx
from mwbx.qpos_store import RawQposStore
from mwbx.codec import CodecError, CompressedQposStore

from test_codec_properties import _angles


def _sample_both(config: str, n_worlds: int):
  """The same worlds twice: qpos kept raw, and compressed as `mwbx sample` does."""
  cfg = mwbx.load_config(f"configs/{config}.yaml")
  with mwbx.Sampler(cfg) as sampler:
    bank, _ = sampler.run(n_worlds, jax.random.key(0))
    raw_store = RawQposStore(sampler.scene.model.nq)
    raw, _ = sampler.run(n_worlds, jax.random.key(0), store=raw_store)
  return cfg, bank, raw


@pytest.fixture(scope="module")
def quickstart():
  return _sample_both("quickstart", 8)


@pytest.mark.parametrize("config", ["quickstart", "pachinko"])
def test_sampled_banks_meet_the_bounds(config, quickstart):
  cfg, bank, raw = quickstart if config == "quickstart" else _sample_both(config, 4)
  assert isinstance(bank.qpos_store, CompressedQposStore) and isinstance(raw.qpos_store, RawQposStore)
  assert isinstance(bank.qpos_store, mwbx.QposStore) and isinstance(raw.qpos_store, mwbx.QposStore)
  np.testing.assert_array_equal(bank.frame_count, raw.frame_count)
  layout = bank.qpos_store.layout
  e_rot = np.deg2rad(cfg.codec.e_rot_deg)
  for w in range(bank.n_worlds):
    got, true = bank.qpos_frames(w), raw.qpos_frames(w).astype(np.float64)
    assert got.shape == true.shape
    for a in layout.pos_adr:
      assert np.abs(got[:, a:a + 3] - true[:, a:a + 3]).max(initial=0) <= cfg.codec.e_pos
    for a in layout.rot_adr:
      assert _angles(got[:, a:a + 4], true[:, a:a + 4]).max(initial=0) <= e_rot * (1 + 1e-3) + 1e-3
    for a in layout.scalar_adr:
      assert np.abs(got[:, a] - true[:, a]).max(initial=0) <= cfg.codec.e_scalar
  stats = bank.qpos_store.stats()
  assert stats["max_error_pos_m"] <= cfg.codec.e_pos
  assert stats["ratio_vs_float32"] > 10


def test_bank_save_load_keeps_streams_and_reports_corruption(quickstart, tmp_path):
  _, bank, _ = quickstart
  bank.save(tmp_path / "bank")
  loaded = mwbx.Bank.load(tmp_path / "bank", lazy=False)  # the streams in memory, to flip a bit in
  assert isinstance(loaded.qpos_store, CompressedQposStore)
  np.testing.assert_array_equal(loaded.qpos_store.data, bank.qpos_store.data)
  np.testing.assert_array_equal(loaded.qpos_frames(5, 10, 20), bank.qpos_frames(5, 10, 20))
  store = loaded.qpos_store
  store.data[store.offsets[3] + 30] ^= 0x01
  with pytest.raises(mwbx.MwbxError, match="world 3: compressed qpos of row 3: corrupt stream"):
    loaded.qpos_frames(3)
  assert issubclass(CodecError, mwbx.MwbxError)


def test_mwbx_info_shows_codec_stats(quickstart, tmp_path, capsys):
  from mwbx import cli
  _, bank, _ = quickstart
  bank.save(tmp_path / "bank")
  assert cli.main(["info", str(tmp_path / "bank")]) == 0
  out = capsys.readouterr().out
  for key in ("bits_per_body_frame", "ratio_vs_float32", "max_error_pos_m", "max_error_rot_deg"):
    assert f"qpos {key}" in out
  on_disk = sum(f.stat().st_size for f in (tmp_path / "bank").rglob("*") if f.is_file())
  assert re.search(rf"^storage +{on_disk:,} bytes on disk, [0-9,]+ bytes in memory$", out, re.M), out
  # A long list is cut to its first names and a count; --json has every name.
  assert cli._names_line([f"b{i}" for i in range(3)]) == "b0, b1, b2"
  many = cli._names_line([f"b{i}" for i in range(200)])
  assert many.startswith("b0, b1,") and "(200 in all; every name: mwbx info --json)" in many and "b199" not in many
  assert cli.main(["info", str(tmp_path / "bank"), "--json"]) == 0
  full = json.loads(capsys.readouterr().out)
  assert full["bodies"] == list(bank.body_names) and full["disk_bytes"] == on_disk


def test_qpos_frames_of_some_bodies_decodes_only_their_joints(quickstart):
  _, bank, raw = quickstart
  model = bank.model
  name = bank.body_names[1]
  body = int(bank.body_ids[1])
  joint = int(model.body_jntadr[body])
  adr = int(model.jnt_qposadr[joint])
  assert model.jnt_type[joint] == 0  # the quickstart objects are free bodies
  cols = bank.qpos_columns(name)
  np.testing.assert_array_equal(cols, np.arange(adr, adr + 7))
  others = np.setdiff1d(np.arange(model.nq), cols)
  for b in (bank, raw):
    full = b.qpos_frames(2, 5, 30)
    part = b.qpos_frames(2, 5, 30, bodies=name)
    np.testing.assert_array_equal(part[:, cols], full[:, cols])
    np.testing.assert_array_equal(part[:, others], 0.0)
  with pytest.raises(mwbx.MwbxError, match="no_such_body"):
    bank.qpos_frames(0, bodies="no_such_body")


def test_stores_take_and_empty_keep_settings_and_worlds(quickstart):
  _, bank, raw = quickstart
  for store in (bank.qpos_store, raw.qpos_store):
    picked = store.take(np.array([3, 0]))
    assert type(picked) is type(store) and picked.n_worlds == 2
    np.testing.assert_array_equal(picked.row_frames(0), store.row_frames(3))
    np.testing.assert_array_equal(picked.row_frames(1), store.row_frames(0))
    empty = store.empty()
    assert empty.n_worlds == 0 and type(empty) is type(store)
