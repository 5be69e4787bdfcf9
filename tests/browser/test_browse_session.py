"""The browsing session without a page: the query stack, counts, the sorter,
query files and background refinement, against mwbx.queries directly."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import mwbx
from mwbx import queries as mq
from mwbx.browser import Session

from viewer_banks import quickstart_bank


@pytest.fixture()
def session():
  return Session(quickstart_bank(16))


def _boxes(bank):
  cam = mq.Camera.from_model(bank.model, "front")
  include = mq.Query.screen(cam, [0.08, 0.35, 0.27, 0.65], bodies=["ball"], window=(3.5, None))
  exclude = mq.Query.screen(cam, [0.78, 0.55, 1.0, 0.75], bodies=["capsule"], sign="exclude")
  return include, exclude


def test_counts_follow_the_stack_and_equal_evaluate(session):
  bank = session.bank
  include, exclude = _boxes(bank)
  assert session.counts().all == int(bank.valid.sum()) and session.match().all() == bank.valid.all()
  session.add(include)
  session.add(exclude)
  each = np.asarray(mq.evaluate_each(bank, [include, exclude]))
  counts = session.counts()
  assert counts.per_query == (int(each[:, 0].sum()), int(each[:, 1].sum()))
  assert counts.all == int(np.asarray(mq.evaluate(bank, [include, exclude])).sum())
  session.toggle(1)  # off: kept, not applied
  assert session.counts().all == int(each[:, 0].sum()) and len(session.entries) == 2
  assert session.undo() and session.counts().all == counts.all
  session.remove(0)
  assert session.counts().per_query == (int(each[:, 1].sum()),)
  assert session.undo() and session.redo() and len(session.entries) == 1
  while session.undo():
    pass
  assert session.entries == [] and not session.undo()
  with pytest.raises(mwbx.MwbxError, match="query 3: no such query"):
    session.toggle(3)
  with pytest.raises(mwbx.MwbxError, match="'ghost'"):
    session.add(mq.Query.region([0, 0, 0], [1, 1, 1], bodies=["ghost"]))


def test_sorter_ranks_matches_or_the_closest(session):
  bank = session.bank
  include, exclude = _boxes(bank)
  session.add(include)
  rows = session.sorted_rows("angular_travel", "sum", bodies=["round"])
  ids, values = mq.rank(bank, [mq.Term("angular_travel", ("round",), "sum", 1.0)],
                        match=session.match(), top=20)
  assert [r.world for r in rows] == ids.tolist() and np.allclose([r.value for r in rows], values)
  assert all(r.satisfied == 1 and r.parent == -1 for r in rows)
  never = mq.Query.region([100, 100, 100], [101, 101, 101])  # nothing goes there
  session.add(never)
  closest = [r.satisfied for r in session.sorted_rows("angular_travel")]
  assert closest[0] == 1 and closest == sorted(closest, reverse=True)  # the most constraints satisfied first


def test_query_files_round_trip(session, tmp_path):
  bank = session.bank
  for q in _boxes(bank):
    session.add(q)
  session.workdir = tmp_path
  path = session.save_queries("q.yaml")
  other = Session(bank, workdir=tmp_path)
  other.open_queries(path)
  assert other.counts() == session.counts()
  from mwbx.queries.report import run_query_file
  report = run_query_file(bank, path)
  assert tuple(n for _, _, n in report.queries) == session.counts().per_query


def test_refine_in_the_background_joins_the_bank(tmp_path):
  bank = quickstart_bank(4)
  bank.save(tmp_path / "bank")
  session = Session(mwbx.Bank.load(tmp_path / "bank"), tmp_path / "bank")
  include, _ = _boxes(bank)
  parent = int(bank.world_ids[1])
  job = session.refine(parent, "capsule", t_min=0.9, n_samples=4, key=jax.random.key(1), wait=True)
  assert job.error is None and job.new_ids.tolist() == [4, 5, 6, 7]
  assert job.progress is not None and job.progress.done == job.progress.total == 4
  assert session.bank.n_worlds == 8 and session.parent(5) == parent and session.parent(parent) is None
  session.save()
  assert mwbx.Bank.load(tmp_path / "bank").children(parent).tolist() == [4, 5, 6, 7]
  bad = session.refine(999, "capsule", t_min=0.9, n_samples=1, wait=True)
  assert bad.new_ids is None and "world 999: no world with this id" in bad.error
  with pytest.raises(mwbx.MwbxError, match="draw an include box first"):
    session.first_entry_of_last_box(parent, ["capsule"])
  session.add(include)
  t = session.first_entry_of_last_box(parent, ["ball"])
  assert t == mq.first_entry(session.bank, parent, ["ball"], include.frustum)


@pytest.mark.parametrize("scene", ["../x.yaml", "scene.txt", "missing.yaml"])
def test_a_refused_scene_name_does_not_lock_refinement(tmp_path, scene):
  # The refused name left a job never marked done: every later refine said "being refined".
  bank = quickstart_bank(2)
  bank.save(tmp_path / "bank")
  session = Session(mwbx.Bank.load(tmp_path / "bank"), tmp_path / "bank")
  parent = int(bank.world_ids[0])
  with pytest.raises(mwbx.MwbxError, match="scene file|outside|must end in .yaml"):
    session.refine(parent, "capsule", t_min=0.9, n_samples=1, scene=scene)
  assert session.cancel() is None
  job = session.refine(parent, "capsule", t_min=0.9, n_samples=2, key=jax.random.key(1), wait=True)
  assert job.error is None and len(job.new_ids) == 2 and session.bank.n_worlds == 4


def test_touch_queries_and_export_from_the_session(tmp_path):
  bank = quickstart_bank(4)
  bank.save(tmp_path / "bank")
  session = Session(mwbx.Bank.load(tmp_path / "bank"), tmp_path / "bank")
  touch = mwbx.TouchQuery("ball", "floor")
  never = mwbx.TouchQuery("round", ["wall_left", "wall_right"], sign="exclude")
  session.add(touch)
  session.add(never)
  each = mwbx.evaluate_each(session.bank, [touch, never])
  assert session.counts().per_query == tuple(int(n) for n in each.sum(axis=0))
  world = int(session.bank.world_ids[1])
  (tmp_path / "bank" / "exports").mkdir()  # the page writes into folders that exist, and makes none
  written = session.export(world, "exports/w1.npz")
  with np.load(written) as f:
    np.testing.assert_array_equal(f["qpos"], session.bank.qpos_frames(world))
  for name, message in (("../w.npz", "outside"), ("w.txt", "must end in"), ("", "give a file name")):
    with pytest.raises(mwbx.MwbxError, match=message):
      session.export(world, name)
