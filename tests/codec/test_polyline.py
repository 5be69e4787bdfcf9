"""COM polylines on the grid: the bound, exact round trips, the raw fallback."""

import numpy as np
import pytest

from mwbx.codec import CodecError, polyline

E_COM = 5e-4  # metres


def paths(seed=0, w=6, p=40, b=3):
  """f32[W, P, B, 3] falling and resting paths, metres."""
  rng = np.random.default_rng(seed)
  t = np.arange(p)[None, :, None, None] / 30.0
  x0 = rng.uniform(-2, 2, (w, 1, b, 3))
  v = rng.normal(0, 1, (w, 1, b, 3))
  x = x0 + v * np.minimum(t, 0.6)
  x[..., 2] -= 4.9 * np.minimum(t[..., 0], 0.6) ** 2
  return x.astype(np.float32)


def test_grid_bound_and_idempotence():
  x = paths()
  step = polyline.grid_step(E_COM)
  g = polyline.round_to_grid(x, step)
  assert np.abs(g.astype(np.float64) - x).max() <= E_COM * (1 + 1e-6) + 1e-7  # the bound, float32 rounding
  np.testing.assert_array_equal(polyline.round_to_grid(g, step), g)


@pytest.mark.parametrize("shape", [(6, 40, 3, 3), (1, 1, 1, 3), (2, 2, 4, 3), (0, 5, 2, 3)])
def test_round_trip_is_exact(shape):
  step = polyline.grid_step(E_COM)
  x = polyline.round_to_grid(np.random.default_rng(1).uniform(-50, 50, shape).astype(np.float32), step)
  out = polyline.decode(polyline.encode(x, step))
  assert out.dtype == np.float32 and out.shape == x.shape
  np.testing.assert_array_equal(out, x)


def test_grid_paths_are_small_and_off_grid_paths_stay_exact():
  step = polyline.grid_step(E_COM)
  x = paths(w=64, p=121)
  g = polyline.round_to_grid(x, step)
  coded = polyline.encode(g, step)
  assert coded.size * 4 < g.nbytes  # second differences of grid coordinates deflate well
  raw = polyline.encode(x, step)  # not on the grid: stored as float32
  np.testing.assert_array_equal(polyline.decode(raw), x)
  with_nan = g.copy()
  with_nan[0, 3, 1, 2] = np.nan
  np.testing.assert_array_equal(polyline.decode(polyline.encode(with_nan, step)), with_nan)
  np.testing.assert_array_equal(polyline.decode(polyline.encode(g, None)), g)


def test_damaged_blocks_raise():
  step = polyline.grid_step(E_COM)
  coded = polyline.encode(polyline.round_to_grid(paths(), step), step).copy()
  with pytest.raises(CodecError, match="COM polylines"):
    polyline.decode(coded[:30])
  coded[40] ^= 0xFF
  with pytest.raises(CodecError, match="COM polylines"):
    polyline.decode(coded)
  with pytest.raises(CodecError, match="not an encoded"):
    polyline.decode(np.zeros(20, np.uint8))


def test_sampled_banks_store_their_paths_on_the_grid(tiny_native_bank, tmp_path):
  import mwbx
  bank = tiny_native_bank
  step = polyline.grid_step(bank.config["codec"]["e_com"])
  np.testing.assert_array_equal(polyline.round_to_grid(bank.com, step), bank.com)
  path = tmp_path / "bank"
  bank.save(path)
  coded = np.load(path / "shards" / "00000" / "com_grid.npy")
  assert coded.size * 4 < bank.com.nbytes
  np.testing.assert_array_equal(mwbx.Bank.load(path).com, bank.com)
