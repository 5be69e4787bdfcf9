"""Banks opened lazily: the manifest and small arrays at once, COM polylines
and qpos per shard on demand; queries stream a shard at a time with the same
answers as a bank in memory; a corrupt shard is named when it is read."""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import tracemalloc

import jax
import numpy as np
import pytest

import mwbx
from mwbx import cli
from mwbx.bank import lazy, shards
from mwbx.progress import NOTICE
from mwbx.queries import paths as query_lib

REPO = pathlib.Path(__file__).resolve().parents[2]
TINY = REPO / "tests" / "refine_scenes" / "tiny.yaml"
N_SHARDS = 8
PER_SHARD = 4


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
  """(path, the bank in memory): 8 shards of 4 tiny worlds each."""
  config = mwbx.load_config(TINY)
  path = tmp_path_factory.mktemp("lazy") / "bank"
  directory = mwbx.bank.BankDirectory(path)
  parts = []
  with mwbx.Sampler(config, backend="native", chunk_size=PER_SHARD) as sampler:
    for part, _ in sampler.run_chunks(N_SHARDS * PER_SHARD, jax.random.key(3)):
      directory.append(part)
      parts.append(part)
  return path, mwbx.Bank.concatenate(parts)


def _queries(bank):
  """A few boxes over where the worlds' paths go, include and exclude, any and all."""
  com = np.asarray(bank.com)
  lo, hi = com.reshape(-1, 3).min(0), com.reshape(-1, 3).max(0)
  mid = (lo + hi) / 2
  return [
      mwbx.Query.region(lo, mid),
      mwbx.Query.region(mid, hi, sign="exclude", window=(0.5, None)),
      mwbx.Query.region(lo, (lo + 3 * hi) / 4, mode="all", radius=0.02),
  ]


def test_opening_reads_no_polylines_or_qpos(sharded):
  path, memory = sharded
  bank = mwbx.Bank.load(path)
  assert isinstance(bank.com, lazy.LazyRows) and isinstance(bank.qpos_store, lazy.LazyQposStore)
  assert not bank.com._map.pieces._cache and not bank.qpos_store._map.pieces._cache
  assert bank.com.shape == memory.com.shape and bank.n_worlds == N_SHARDS * PER_SHARD
  np.testing.assert_array_equal(bank.metrics, memory.metrics)
  # One world's qpos reads its one shard.
  world = int(bank.world_ids[PER_SHARD * 5 + 1])
  np.testing.assert_array_equal(bank.qpos_frames(world), memory.qpos_frames(world))
  assert list(bank.qpos_store._map.pieces._cache) == [5]
  np.testing.assert_array_equal(bank.com[PER_SHARD * 2 + 3], memory.com[PER_SHARD * 2 + 3])
  assert list(bank.com._map.pieces._cache) == [2]
  np.testing.assert_array_equal(np.asarray(bank.com), memory.com)


def test_streamed_queries_answer_like_the_bank_in_memory(sharded, monkeypatch):
  path, memory = sharded
  queries = _queries(memory)
  expected = mwbx.evaluate_each(memory, queries)
  assert expected.any() and not expected.all()  # the boxes tell worlds apart
  monkeypatch.setattr(query_lib, "IN_MEMORY_COM_BYTES", 0)  # stream even this small bank
  bank = mwbx.Bank.load(path)
  assert query_lib.streams(bank)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, queries), expected)
  np.testing.assert_array_equal(mwbx.constraints_satisfied(bank, queries),
                                mwbx.constraints_satisfied(memory, queries))
  for got, want in zip(mwbx.rank(bank, "collisions", queries=queries[:1], top=5),
                       mwbx.rank(memory, "collisions", queries=queries[:1], top=5)):
    np.testing.assert_array_equal(got, want)
  for w in (0, 13, 30):
    frustum = queries[0].frustum
    assert (query_lib.first_entry(bank, w, None, frustum)
            == query_lib.first_entry(memory, w, None, frustum))
  # Dropping worlds keeps the bank lazy and the answers right.
  dropped = bank.drop([1, 2, 17])
  keep = ~np.isin(memory.world_ids, [1, 2, 17])
  assert isinstance(dropped.com, lazy.LazyRows)
  np.testing.assert_array_equal(mwbx.evaluate_each(dropped, queries), expected[keep])


def _peak_of_streamed_evaluation(memory, path: pathlib.Path, n_shards: int, per_shard: int = 512):
  """(numpy peak bytes of one streamed evaluate_each, decoded COM bytes) on a
  bank of ``n_shards`` shards of the sampled worlds under new ids."""
  directory = mwbx.bank.BankDirectory(path)
  for s in range(n_shards):
    part = dataclasses.replace(memory._take(np.arange(per_shard) % memory.n_worlds),
                               world_ids=np.arange(s * per_shard, (s + 1) * per_shard, dtype=np.int64))
    directory.append(part)
  queries = _queries(memory)
  bank = mwbx.Bank.load(path)
  expected = np.tile(mwbx.evaluate_each(memory, queries), (n_shards * per_shard // memory.n_worlds, 1))
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, queries), expected)  # also compiles
  bank = mwbx.Bank.load(path)
  tracemalloc.start()
  try:
    mwbx.evaluate_each(bank, queries)
    _, peak = tracemalloc.get_traced_memory()
  finally:
    tracemalloc.stop()
  return peak, bank.com.nbytes


def test_streamed_queries_hold_a_few_shards_at_a_time(sharded, tmp_path, monkeypatch):
  """Peak numpy memory of a streamed evaluation grows with the bank by its
  stored path boxes only (the index, kept whole: a fraction of the bank)."""
  monkeypatch.setattr(query_lib, "IN_MEMORY_COM_BYTES", 0)
  memory = sharded[1]
  # Boxes tested and undecided worlds decoded a shard's worth at a time.
  monkeypatch.setattr(query_lib, "DECODED_BLOCK_BYTES", 512 * int(np.prod(memory.com.shape[1:])) * 4)
  monkeypatch.setattr(query_lib, "BOXED_CHUNKS", 512 * memory.com.shape[2])
  small, small_whole = _peak_of_streamed_evaluation(memory, tmp_path / "small", 4)
  big, big_whole = _peak_of_streamed_evaluation(memory, tmp_path / "big", 32)
  assert big_whole == 8 * small_whole
  boxes = sum(x.nbytes for x in query_lib.stored_boxes(mwbx.Bank.load(tmp_path / "big"))[:4])
  assert boxes < big_whole / 4
  assert big < 1.3 * small + 2 * boxes, (small, big, boxes)  # the boxes, and their pieces while joined
  assert big < big_whole / 2, (big, big_whole)


def test_a_corrupt_shard_is_named_when_read(sharded, tmp_path, capsys):
  import shutil
  path = tmp_path / "bank"
  shutil.copytree(sharded[0], path)
  target = path / "shards" / "00003" / "com_grid.npy"
  data = bytearray(target.read_bytes())
  data[-5] ^= 0x01
  target.write_bytes(bytes(data))
  bank = mwbx.Bank.load(path)  # the small arrays are intact: it opens
  bank.qpos_frames(0)  # other shards read fine
  np.testing.assert_array_equal(bank.com[0], sharded[1].com[0])
  with pytest.raises(mwbx.MwbxError, match=r"shards/00003: corrupt bank: checksum mismatch in com_grid"):
    mwbx.evaluate_each(bank, _queries(sharded[1]))
  with pytest.raises(mwbx.MwbxError, match=r"shards/00003: corrupt bank: checksum mismatch in com_grid"):
    mwbx.Bank.load(path, lazy=False)
  problems = shards.verify(path)
  assert len(problems) == 1 and "00003" in problems[0] and "com_grid" in problems[0]
  assert cli.main(["info", str(path), "--verify"]) == 2
  err = capsys.readouterr().err
  assert "00003" in err and "com_grid" in err
  rest = mwbx.Bank.load(path, skip_corrupt=True)
  assert rest.n_worlds == (N_SHARDS - 1) * PER_SHARD and rest.run["corrupt_shards"] == ["00003"]


def test_refining_a_lazy_bank_saves_one_new_shard(sharded, tmp_path):
  import shutil
  path = tmp_path / "bank"
  shutil.copytree(sharded[0], path)
  bank = mwbx.Bank.load(path)
  world = int(bank.world_ids[9])
  grown = mwbx.refine(bank, world, list(bank.objects)[:1], t_min=0.5, n_samples=2,
                      key=jax.random.key(1))
  new = grown._take(np.flatnonzero(grown.parent_world == world))
  assert new.n_worlds == 2
  assert isinstance(grown.qpos_store, lazy.LazyQposStore)
  grown.save(path)
  assert len(list((path / "shards").iterdir())) == N_SHARDS + 1
  again = mwbx.Bank.load(path)
  for w in new.world_ids:
    np.testing.assert_array_equal(again.qpos_frames(int(w)), new.qpos_frames(int(w)))
  assert again.ancestors(int(new.world_ids[0])).tolist() == [world]


def test_a_lazy_banks_qpos_stats_read_no_streams(sharded, tmp_path, monkeypatch):
  """``mwbx info``'s qpos figures of a lazy bank come from each shard's small
  arrays, equal to the store in memory's: whole, a subset in another order,
  and with refined worlds in memory appended; raw stores too."""
  path, memory = sharded
  bank = mwbx.Bank.load(path)
  monkeypatch.setattr(shards, "_read_qpos", lambda *a: pytest.fail("stats read a shard's streams"))
  assert bank.qpos_store.stats() == memory.qpos_store.stats()
  rows = np.array([9, 2, 30, 3])
  assert bank._take(rows).qpos_store.stats() == memory._take(rows).qpos_store.stats()
  monkeypatch.undo()
  grown = mwbx.refine(bank, int(bank.world_ids[9]), list(bank.objects)[:1], t_min=0.5, n_samples=2,
                      key=jax.random.key(1))
  assert isinstance(grown.qpos_store, lazy.LazyQposStore)
  assert grown.qpos_store.stats() == grown.qpos_store.concrete().stats()
  raw = mwbx.Bank.concatenate([dataclasses.replace(memory._take(np.arange(4)), qpos_store=mwbx.RawQposStore(
      memory.model.nq, np.zeros((10, memory.model.nq)), np.array([0, 1, 3, 6, 10])))])
  raw.save(tmp_path / "raw")
  lazy_raw = mwbx.Bank.load(tmp_path / "raw").qpos_store
  assert lazy_raw.stats() == raw.qpos_store.stats() == {"codec": "raw float32", "frames": 10,
                                                        "bytes": 10 * memory.model.nq * 4 + 5 * 8,
                                                        "bytes_per_world": (10 * memory.model.nq * 4 + 40) / 4}


def test_lazy_rows_index_like_numpy():
  """LazyRows over three pieces against the numpy array it stands for."""
  a = np.random.default_rng(0).random((10, 4, 3)).astype(np.float32)
  rows = lazy.LazyRows([lambda: a[:3], a[3:7], lambda: a[7:]], [3, 4, 3], (4, 3), np.float32)
  keys = [5, -1, slice(2, 8), [1, 8, 1], np.array([[0, 9], [4, 4]]), a[:, 0, 0] > 0.5, (slice(1, 9, 2), 2),
          (np.array([1, 5]), np.array([0, 3])), (3, 1, 2), (np.array([2, 7]), slice(None), 1)]
  for key in keys:
    np.testing.assert_array_equal(rows[key], a[key], err_msg=str(key))
  np.testing.assert_array_equal(np.asarray(rows.take([9, 0, 4])), a[[9, 0, 4]])
  np.testing.assert_array_equal(np.asarray(lazy.LazyRows.concat([rows, a[:2]])), np.concatenate([a, a[:2]]))
  assert rows.shape == a.shape and rows.nbytes == a.nbytes and len(rows) == 10
  with pytest.raises(IndexError):
    rows[10]


def test_contact_events_are_decoded_when_first_used(sharded, tmp_path, monkeypatch, capsys):
  """Opening, `mwbx info` (from the shards' headers, or their counts and
  strengths where older shards do not say), the summary and taking worlds
  decode no episode; the first use decodes them, equal to the bank in
  memory's; an events blob whose checksum holds but whose bytes do not is
  named then, and by an eager open."""
  import json
  import shutil
  from mwbx.bank import checks
  from mwbx.events import lazy as events_lazy
  from mwbx.events.record import EventRecord
  path, memory = sharded
  assert len(memory.events.rows) and (~np.isnan(memory.events.impulse)).all()
  older = tmp_path / "older"  # shards whose headers do not count known impulses
  shutil.copytree(path, older)
  manifest = json.loads((older / "manifest.json").read_text())
  for entry in manifest["shards"]:
    del entry["events"]["with_impulse"]
  (older / "manifest.json").write_text(json.dumps(manifest))
  rows = np.array([9, 2, 30, 3])
  with monkeypatch.context() as m:
    m.setattr(EventRecord, "from_arrays", classmethod(lambda *a, **k: pytest.fail("decoded the episodes")))
    for folder in (path, older):
      bank = mwbx.Bank.load(folder)
      assert isinstance(bank.events, events_lazy.LazyEvents) and not bank.events.decoded
      assert bank.events.nbytes == memory.events.nbytes and bank.summary() == memory.summary() | {
          "storage_bytes": bank.nbytes}
      taken = bank._take(rows).events
      assert cli.main(["info", str(folder)]) == 0
      assert f"contact events      {len(memory.events.rows):,} episodes, found at every physics step, with" \
             " impulses" in capsys.readouterr().out
  for got, want in ((bank.events, memory.events), (taken, memory.events.take(rows))):
    np.testing.assert_array_equal(got.rows, want.rows)
    np.testing.assert_array_equal(got.counts, want.counts)
    np.testing.assert_array_equal(got.strength, want.strength)
  target = older / "shards" / "00003" / "events_rows.npy"
  blob = np.load(target)[:-7]  # cut short, checksum made to agree
  np.save(target, blob)
  manifest["shards"][3]["checksums"]["events_rows"] = checks.crc32(blob)
  (older / "manifest.json").write_text(json.dumps(manifest))
  bank = mwbx.Bank.load(older)
  with pytest.raises(mwbx.MwbxError, match=r"shards/00003: corrupt contact events"):
    bank.events.world(0)
  with pytest.raises(mwbx.MwbxError, match=r"shards/00003: corrupt contact events"):
    mwbx.Bank.load(older, lazy=False)


def test_bytes_on_disk_are_the_files_bytes_without_a_stat_per_shard_file(sharded, tmp_path, monkeypatch):
  """``mwbx info``'s bytes on disk: each shard's from its manifest entry
  (none of its files stat'ed), equal to every file's size summed; stray
  files and shards whose entries do not say are stat'ed."""
  import json
  import os
  import shutil
  path = tmp_path / "bank"
  shutil.copytree(sharded[0], path)
  (path / "shards" / ".tmp-left-by-a-killed-run").mkdir()
  (path / "shards" / ".tmp-left-by-a-killed-run" / "com_grid.npy").write_bytes(b"x" * 1000)
  (path / "notes.txt").write_bytes(b"y" * 10)
  files = lambda: sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
  lstat = os.lstat
  stat_in_shards = lambda p, *a, **k: (pytest.fail(f"stat'ed {p}") if "/shards/0" in str(p) else lstat(p, *a, **k))
  with monkeypatch.context() as m:
    m.setattr(os, "lstat", stat_in_shards)
    assert shards.disk_bytes(path) == files()
  manifest = json.loads((path / "manifest.json").read_text())
  del manifest["shards"][2]["bytes"]  # a shard of a bank written before entries said
  (path / "manifest.json").write_text(json.dumps(manifest))
  assert shards.disk_bytes(path) == files()


def test_queries_start_from_the_stored_path_boxes(sharded, tmp_path, monkeypatch):
  """Shards hold their paths' boxes; a fresh bank's first query reads them
  and decodes only the shards holding worlds they leave open, with the
  answers of the bank in memory; a bank saved before them is boxed by its
  first query (said once, written into the bank, read as stored after); a
  damaged box file is named."""
  import json
  import shutil
  from mwbx.queries import path_boxes
  path, memory = sharded
  queries = _queries(memory)
  # A box about the body that rests (its boxes lie inside: every world met) and one
  # beside it (its boxes lie outside): answered without decoding a path.
  rest = np.asarray(memory.com[0, 0, 2])
  small = [mwbx.Query.region(rest - 0.1, rest + 0.1, bodies=["far"]),
           mwbx.Query.region(rest + 0.2, rest + 0.3, bodies=["far"], sign="exclude")]
  assert mwbx.evaluate_each(memory, small).all()
  manifest = json.loads((path / "manifest.json").read_text())
  assert all(e["index"] == {"version": path_boxes.VERSION, "chunk": path_boxes.DEFAULT_CHUNK} for e in manifest["shards"])
  read = []
  real = shards._read_com
  monkeypatch.setattr(shards, "_read_com", lambda p, e: read.append(e["name"]) or real(p, e))
  bank = mwbx.Bank.load(path)
  assert query_lib.answered_from_boxes(bank)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, small), mwbx.evaluate_each(memory, small))
  assert read == []
  bank = mwbx.Bank.load(path)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, queries), mwbx.evaluate_each(memory, queries))
  bank = mwbx.Bank.load(path)
  bank.com.materialized()  # decoded whole already: its full index is built instead
  assert not query_lib.answered_from_boxes(bank)

  older = tmp_path / "older"
  shutil.copytree(path, older)
  for entry in manifest["shards"]:
    del entry["index"], entry["checksums"][shards.BOXES]
    (older / "shards" / entry["name"] / f"{shards.BOXES}.npy").unlink()
  (older / "manifest.json").write_text(json.dumps(manifest))
  seen = []
  handler = logging.Handler()
  handler.emit = lambda record: seen.append(record.getMessage())
  monkeypatch.setattr(NOTICE, "level", logging.INFO)
  NOTICE.addHandler(handler)
  try:
    bank = mwbx.Bank.load(older)
    assert seen == [f"{older}: {N_SHARDS} of {N_SHARDS} shards saved without a query index; the first query computes"
                    " it from their decoded paths and writes it"]
    np.testing.assert_array_equal(mwbx.evaluate_each(bank, queries), mwbx.evaluate_each(memory, queries))
    assert seen[1:] == [f"{older}: query index written for {N_SHARDS} shards"]
    assert shards.verify(older) == []
    read.clear()
    bank = mwbx.Bank.load(older)
    assert len(seen) == 2
  finally:
    NOTICE.removeHandler(handler)
  np.testing.assert_array_equal(mwbx.evaluate_each(bank, small), mwbx.evaluate_each(memory, small))
  assert read == []
  assert sorted(p.name for p in (older / "shards" / "00002").iterdir()) == sorted(
      p.name for p in (path / "shards" / "00002").iterdir())

  target = older / "shards" / "00002" / f"{shards.BOXES}.npy"
  data = bytearray(target.read_bytes())
  data[-3] ^= 0x01
  target.write_bytes(bytes(data))
  with pytest.raises(mwbx.MwbxError, match=rf"shards/00002: corrupt bank: checksum mismatch in {shards.BOXES}"):
    mwbx.evaluate_each(mwbx.Bank.load(older), queries)
  assert any("00002" in p and shards.BOXES in p for p in shards.verify(older))


def test_the_page_frames_a_lazy_bank_from_its_boxes(sharded, monkeypatch):
  """The view's bounds from the stored path boxes equal those from every
  decoded path, and read none (a world whose boxes hold a point not finite
  is read)."""
  from mwbx.queries import path_boxes
  from mwbx.viewer import framing
  path, memory = sharded
  bank = mwbx.Bank.load(path)
  rows = np.arange(memory.n_worlds)
  read = []
  real = shards._read_com
  monkeypatch.setattr(shards, "_read_com", lambda p, e: read.append(e["name"]) or real(p, e))
  want = framing.scene_bounds(memory, memory.model, rows, None, None)
  np.testing.assert_array_equal(framing.scene_bounds(bank, bank.model, rows, None, None), want)
  assert read == []
  com = np.asarray(memory.com).copy()
  com[9, 3, 1] = np.nan
  com[9, 4, 1] = np.nanmax(com[:, :, 1], axis=(0, 1)) + 5.0  # beyond the others: seen only by reading world 9
  odd = lazy.LazyRows([lambda: com], [len(com)], com.shape[1:], np.float32,
                      companions=[lambda: path_boxes.build(com)])
  lo, hi = framing.scene_bounds(dataclasses.replace(memory, com=odd), memory.model, rows, None, None)
  np.testing.assert_array_equal(hi, framing.scene_bounds(dataclasses.replace(memory, com=com), memory.model, rows,
                                                         None, None)[1])
  assert hi[1] >= com[9, 4, 1, 1]
