"""The bank's qpos stores by kind (mwbx/bank/stores.py) and the codec bounds
a config gives (:meth:`CodecSection.bounds`, :meth:`CodecSection.com_step`):
one source for the sampler, refinement and scene versions."""

import numpy as np
import pytest

import mwbx
from mwbx.bank import stores
from mwbx.codec import CodecBounds, CompressedQposStore
from mwbx.config import CodecSection
from mwbx.qpos_store import RawQposStore
from mwbx.refinement import interactions


def test_store_for_a_scene_by_kind(tiny_config):
  scene = mwbx.Scene(tiny_config)
  coded = stores.store_for(scene)
  assert isinstance(coded, CompressedQposStore) and coded.n_worlds == 0
  assert coded.bounds == tiny_config.codec.bounds() and coded.fps == tiny_config.sim.record_fps
  raw = stores.store_for(scene, "raw")
  assert isinstance(raw, RawQposStore) and raw.nq == scene.model.nq and raw.n_worlds == 0
  assert stores.store_class("codec") is CompressedQposStore and stores.store_class("raw") is RawQposStore
  with pytest.raises(mwbx.MwbxError, match=r"unknown qpos store 'zip' \(have: raw, codec\)"):
    stores.store_for(scene, "zip")


def test_codec_section_gives_bounds_in_the_codecs_units():
  section = CodecSection(e_pos=2e-3, e_rot_deg=1.0, e_scalar=3e-3, e_com=1e-3)
  bounds = section.bounds()
  assert isinstance(bounds, CodecBounds)
  assert (bounds.e_pos, bounds.e_rot, bounds.e_scalar) == (2e-3, float(np.deg2rad(1.0)), 3e-3)
  assert section.com_step() == 2e-3  # the grid step: every stored point within e_com
  assert CodecSection(e_com=None).com_step() is None


def test_sampler_and_ghost_slack_take_the_named_bounds(tiny_native, tiny_config):
  assert tiny_native.store.bounds == tiny_config.codec.bounds()
  scene = tiny_native.scene
  radius = np.full(len(scene.body_ids), 0.05)
  small = interactions.ghost_slack(scene.model, scene.body_ids, radius, CodecBounds(1e-3, 1e-2, 1e-3))
  wider = interactions.ghost_slack(scene.model, scene.body_ids, radius, CodecBounds(2e-3, 1e-2, 1e-3))
  # Both tracked bodies hang on one free joint each: √3·e_pos (ℓ∞ per axis) more.
  np.testing.assert_allclose(wider - small, np.sqrt(3.0) * 1e-3, rtol=1e-12)
