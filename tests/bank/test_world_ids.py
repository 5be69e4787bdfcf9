"""One notion of a world: every public function and CLI flag takes world ids,
ids are unique within a bank forever, lineage is queryable, worlds can be
dropped, and a refinement repeated without a seed draws new worlds."""

from __future__ import annotations

import dataclasses
import json
import pathlib
import subprocess
import sys

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli

SCENES = pathlib.Path(__file__).parents[1] / "refine_scenes"
T_MIN = 0.1


@pytest.fixture(scope="module")
def config():
  return mwbx.load_config(SCENES / "tiny.yaml")


@pytest.fixture(scope="module")
def offset_bank(config):
  """8 worlds with ids 100..107."""
  return mwbx.sample(config, 8, jax.random.key(0), first_world=100, backend="native")


@pytest.fixture(scope="module")
def bank_dir(config, tmp_path_factory):
  path = tmp_path_factory.mktemp("ids") / "bank"
  mwbx.sample(config, 4, jax.random.key(0), backend="native").save(path)
  return path


def test_ids_not_rows_everywhere(offset_bank, tmp_path):
  bank = offset_bank
  assert bank.world_ids.tolist() == list(range(100, 108))
  ids, _ = mwbx.rank(bank, "collisions:sum", top=2)
  assert set(ids.tolist()) <= set(range(100, 108))
  chosen = int(ids[0])
  row = bank.row_of(chosen)
  assert bank.world_ids[row] == chosen and bank.row_of([chosen, 100]).tolist() == [row, 0]
  # qpos_frames, export_html and refine take the id that rank returned.
  np.testing.assert_array_equal(bank.qpos_frames(chosen), bank.qpos_store.row_frames(row))
  out = mwbx.export_html(bank, tmp_path / "v.html", worlds=[chosen])
  assert out.exists()
  refined = mwbx.refine(bank, chosen, "striker", t_min=T_MIN, n_samples=2, key=jax.random.key(1),
                        backend="native")
  new = refined.world_ids[bank.n_worlds:]
  assert new.tolist() == [108, 109]
  assert refined.parent_world[bank.n_worlds:].tolist() == [chosen, chosen]
  assert refined.lineage["108"]["parent"] == chosen
  # the refined worlds start from the parent's stored frames, found by its id (the
  # refined object's frames are coded again, so within the bound; the rest exactly)
  f0 = int(np.floor(T_MIN * bank.record_fps + 1e-6))
  striker = bank.qpos_columns("striker")
  child, parent = refined.qpos_frames(108)[:f0], bank.qpos_frames(chosen)[:f0]
  np.testing.assert_allclose(child[:, striker[:3]], parent[:, striker[:3]], rtol=0,
                             atol=bank.config["codec"]["e_pos"] * 1.001)
  others = np.setdiff1d(np.arange(bank.model.nq), striker)
  np.testing.assert_array_equal(child[:, others], parent[:, others])


@pytest.mark.parametrize("call", [
    lambda b: b.qpos_frames(3),
    lambda b: b.row_of([100, 3]),
    lambda b: mwbx.refine(b, 3, "striker", t_min=T_MIN, n_samples=1, key=jax.random.key(0)),
    lambda b: mwbx.export_html(b, "/tmp/never.html", worlds=[3]),
    lambda b: b.children(3),
    lambda b: b.drop([3]),
])
def test_unknown_id_is_one_clear_error(offset_bank, call):
  with pytest.raises(mwbx.MwbxError, match=r"world 3: no world with this id .*100\.\.107"):
    call(offset_bank)


def test_append_keeps_ids_unique(config):
  a = mwbx.sample(config, 4, jax.random.key(0), backend="native")
  b = mwbx.sample(config, 4, jax.random.key(7), backend="native")
  both = a.append(b)
  assert both.world_ids.tolist() == list(range(8))
  np.testing.assert_array_equal(both.qpos_frames(5), b.qpos_frames(1))  # moved with its data
  # a refined world of the appended bank keeps pointing at its own parent
  b_refined = mwbx.refine(b, 2, "striker", t_min=T_MIN, n_samples=1, key=jax.random.key(2),
                          backend="native")
  assert b_refined.world_ids[-1] == 4 and b_refined.parent_world[-1] == 2
  merged = a.append(b_refined)
  assert len(set(merged.world_ids.tolist())) == merged.n_worlds == 9
  child = int(merged.world_ids[-1])
  assert merged.parent_world[-1] == 6 and merged.lineage[str(child)]["parent"] == 6
  assert merged.ancestors(child).tolist() == [6]


def test_a_bank_is_a_frozen_record(offset_bank):
  with pytest.raises(dataclasses.FrozenInstanceError):
    offset_bank.flags = offset_bank.flags | mwbx.FLAG_UNSTABLE
  # what a record's methods build comes from the modules beside it
  assert offset_bank.model is offset_bank.model  # built once, kept
  assert offset_bank.flex_objects == () and not offset_bank.flex_body_mask().any()
  assert offset_bank.summary()["worlds"] == 8 and offset_bank.summary()["storage_bytes"] == offset_bank.nbytes


def test_sampling_after_refining_gives_new_ids(config):
  bank = mwbx.sample(config, 4, jax.random.key(0), backend="native")
  bank = mwbx.refine(bank, 1, "striker", t_min=T_MIN, n_samples=2, key=jax.random.key(1),
                     backend="native")
  more = mwbx.sample(config, 3, jax.random.key(0), first_world=bank.next_world_id, backend="native")
  total = bank.append(more)
  assert total.world_ids.tolist() == list(range(9))
  assert len(np.unique(total.world_ids)) == total.n_worlds


def test_lineage_and_drop(config, tmp_path):
  bank = mwbx.sample(config, 3, jax.random.key(0), backend="native")
  bank = mwbx.refine(bank, 1, "striker", t_min=T_MIN, n_samples=2, key=jax.random.key(1),
                     backend="native")  # 3, 4
  bank = mwbx.refine(bank, 4, "striker", t_min=0.2, n_samples=2, key=jax.random.key(2),
                     backend="native")  # 5, 6
  assert bank.children(1).tolist() == [3, 4] and bank.children(4).tolist() == [5, 6]
  assert bank.children(0).size == 0
  assert bank.ancestors(6).tolist() == [4, 1] and bank.ancestors(1).size == 0
  assert sorted(bank.descendants(1).tolist()) == [3, 4, 5, 6]
  assert bank.world_ids[bank.under(4)].tolist() == [4, 5, 6]
  dropped = bank.drop([5, 6])  # back-track: the last refinement was no good
  assert dropped.world_ids.tolist() == [0, 1, 2, 3, 4]
  assert bank.world_ids.tolist() == list(range(7)) and "5" in bank.lineage  # a new bank; this one as it was
  assert "5" not in dropped.lineage and "3" in dropped.lineage
  np.testing.assert_array_equal(dropped.qpos_frames(4), bank.qpos_frames(4))
  dropped.save(tmp_path / "b")
  loaded = mwbx.Bank.load(tmp_path / "b")
  assert loaded.next_world_id == 7  # 5 and 6 are never given again
  again = mwbx.refine(loaded, 4, "striker", t_min=0.2, n_samples=1, key=jax.random.key(3),
                      backend="native")
  assert again.world_ids[-1] == 7 and again.ancestors(7).tolist() == [4, 1]


def test_repeating_a_refinement_without_a_key_draws_new_worlds(offset_bank):
  kwargs = dict(t_min=T_MIN, n_samples=2, backend="native")
  a = mwbx.refine(offset_bank, 101, "striker", **kwargs)
  b = mwbx.refine(offset_bank, 101, "striker", **kwargs)
  assert not np.array_equal(a.qpos_frames(108), b.qpos_frames(108))
  c = mwbx.refine(offset_bank, 101, "striker", key=jax.random.key(4), **kwargs)
  d = mwbx.refine(offset_bank, 101, "striker", key=jax.random.key(4), **kwargs)
  np.testing.assert_array_equal(c.qpos_frames(109), d.qpos_frames(109))


def _mwbx(*argv):
  return subprocess.run([sys.executable, "-m", "mwbx.cli", *map(str, argv)], capture_output=True,
                        text=True, timeout=600)


def test_cli_refine_twice_without_seed_then_query_under_and_drop(bank_dir, tmp_path, capsys):
  work = tmp_path / "work"
  mwbx.Bank.load(bank_dir).save(work)
  for _ in range(2):
    assert cli.main(["refine", str(work), "--world", "2", "--objects", "striker", "--time", "0.1",
                     "--samples", "2", "--backend", "native"]) == 0
  out = capsys.readouterr().out
  assert "ids 4..5" in out and "ids 6..7" in out and "seed " in out
  bank = mwbx.Bank.load(work)
  assert bank.world_ids.tolist() == list(range(8))
  assert not np.array_equal(bank.qpos_frames(4), bank.qpos_frames(6))  # new randomness each run
  assert bank.children(2).tolist() == [4, 5, 6, 7]
  queries = tmp_path / "q.yaml"
  queries.write_text("queries:\n  - {region: {min: [-10, -10, -10], max: [10, 10, 10]}}\n")
  assert cli.main(["query", str(work), str(queries), "--under", "2", "--json"]) == 0
  report = json.loads(capsys.readouterr().out)
  assert sorted(w["world"] for w in report["worlds"]) == [2, 4, 5, 6, 7]
  assert cli.main(["drop", str(work), "6..7"]) == 0
  capsys.readouterr()
  assert mwbx.Bank.load(work).world_ids.tolist() == [0, 1, 2, 3, 4, 5]
  assert cli.main(["query", str(work), str(queries), "--under", "6"]) == 2
  assert "world 6: no world with this id" in capsys.readouterr().err


def test_cli_small_things(bank_dir, capsys):
  assert cli.main(["sample", str(SCENES / "tiny.yaml"), "--worlds", "0", "--out", str(bank_dir)]) == 2
  assert "--worlds: must be at least 1, got 0" in capsys.readouterr().err
  with pytest.raises(SystemExit):
    cli.main(["--version"])
  assert capsys.readouterr().out.strip() == f"mwbx {mwbx.__version__}"
  assert cli.main(["info", str(bank_dir)]) == 0
  out = capsys.readouterr().out
  assert "world ids           0..3" in out and "cameras" in out and len(out.splitlines()) < 40
  # a reader that leaves early gets no BrokenPipe traceback
  piped = subprocess.run(f"{sys.executable} -m mwbx.cli info {bank_dir} --json | head -2",
                         shell=True, capture_output=True, text=True, timeout=600)
  assert piped.stdout.count("\n") == 2 and "Traceback" not in piped.stderr and "Broken" not in piped.stderr


def test_repr_shows_shapes_not_arrays(offset_bank):
  text = repr(offset_bank)
  assert "Bank(8 worlds" in text and "ids 100..107" in text and len(text) < 300
