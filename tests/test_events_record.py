"""The contact-event record as a shard keeps it: rows exact, strengths within
STRENGTH_RELATIVE_ERROR, bad bytes refused in one line; counts and known
impulses read without the rows; records merged before they are decoded."""

import numpy as np
import pytest

from mwbx.errors import MwbxError
from mwbx.events.lazy import LazyEvents, impulses_known
from mwbx.events.record import STRENGTH_RELATIVE_ERROR, EventRecord, kept_strength, merge, stored_counts
from mwbx.events.record import stored_impulses_known


def _random_record(rng, ticks_per_frame=3):
  """(record, frame counts) of up to 6 worlds whose rows are sorted as a
  record's are: ticks short or past 65,536, episodes to the world's end,
  strengths 0, NaN, tiny and huge."""
  n_worlds = int(rng.integers(0, 7))
  counts = rng.integers(0, 9, n_worlds).astype(np.int32)
  n = int(counts.sum())
  a = rng.integers(0, 4, n)
  b = a + rng.integers(1, 4, n)
  span = 1 << int(rng.choice([8, 20]))
  first = rng.integers(0, span, n)
  rows = np.stack([a, b, first, first + rng.integers(0, 50, n)], axis=1)
  world = np.repeat(np.arange(n_worlds), counts)
  rows = rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0], world))].astype(np.int32)
  frame_count = rng.integers(1, span // ticks_per_frame + 20, n_worlds)
  if n:  # some episodes last to their world's end, as resting contacts do
    last_frame = np.repeat(frame_count - 1, counts) * ticks_per_frame
    to_end = (rng.random(n) < 0.3) & (last_frame >= rows[:, 2])
    rows[to_end, 3] = last_frame[to_end]
  strength = rng.choice([0.0, np.nan, 1e-11, 1e-3, 7.0, 4e4], (n, 2)) * rng.random((n, 2))
  return EventRecord(rows, counts, kept_strength(strength), ticks_per_frame), frame_count


def _saved_and_loaded(record, frame_count):
  arrays = dict(record.arrays(frame_count), frame_count=frame_count)
  return EventRecord.from_arrays(arrays, record.n_worlds, "shard 00000", record.ticks_per_frame)


def test_a_record_round_trips_through_a_shards_arrays():
  rng = np.random.default_rng(0)
  for _ in range(300):
    record, frame_count = _random_record(rng)
    loaded = _saved_and_loaded(record, frame_count)
    np.testing.assert_array_equal(loaded.rows, record.rows)
    np.testing.assert_array_equal(loaded.counts, record.counts)
    np.testing.assert_array_equal(loaded.strength, record.strength)  # NaN where NaN


def test_kept_strengths_are_within_the_named_error_and_stay_put():
  values = np.geomspace(1e-8, 1e7, 20000, dtype=np.float32).reshape(-1, 2)
  kept = kept_strength(values)
  assert np.abs(kept / values - 1).max() <= STRENGTH_RELATIVE_ERROR
  np.testing.assert_array_equal(kept_strength(kept), kept)  # keeping twice changes nothing
  special = kept_strength(np.array([[0.0, np.nan], [1e-12, 2.5]], np.float32))
  assert special[0, 0] == 0 and np.isnan(special[0, 1]) and special[1, 0] == 0
  assert abs(special[1, 1] / 2.5 - 1) <= STRENGTH_RELATIVE_ERROR


def test_corrupt_event_bytes_are_refused_naming_the_shard():
  record, frame_count = _random_record(np.random.default_rng(1))
  while not len(record.rows):
    record, frame_count = _random_record(np.random.default_rng(len(frame_count) + 2))
  arrays = dict(record.arrays(frame_count), frame_count=frame_count)
  for name in ("events_rows", "events_counts", "events_strength"):
    bad = dict(arrays)
    bad[name] = arrays[name][: len(arrays[name]) // 2]
    with pytest.raises(MwbxError, match="shard 00000: corrupt contact events"):
      EventRecord.from_arrays(bad, record.n_worlds, "shard 00000", record.ticks_per_frame)
  bad = dict(arrays, events_counts=EventRecord.empty(record.n_worlds + 1).arrays(np.ones(record.n_worlds + 1))
             ["events_counts"])
  with pytest.raises(MwbxError, match="corrupt contact events"):
    EventRecord.from_arrays(bad, record.n_worlds, "shard 00000", record.ticks_per_frame)


def test_counts_and_known_impulses_read_without_the_rows_match_the_record():
  rng = np.random.default_rng(2)
  for _ in range(200):
    record, frame_count = _random_record(rng)
    arrays = dict(record.arrays(frame_count), frame_count=frame_count)
    np.testing.assert_array_equal(stored_counts(arrays, record.n_worlds), record.counts)
    assert stored_impulses_known(arrays, len(record.rows)) == int((~np.isnan(record.impulse)).sum())


def _lazy(record, decoded):
  """A LazyEvents of ``record`` that appends to ``decoded`` when it decodes
  (its counts and known impulses told apart, as a shard's headers tell them)."""
  return LazyEvents(lambda: decoded.append(1) or record, lambda: record.counts, record.ticks_per_frame,
                    lambda: int((~np.isnan(record.impulse)).sum()))


def test_merging_undecoded_records_is_the_merge_of_the_records():
  """Parts naming different actors, in different ticks: the lazy merge tells
  counts, bytes and ticks without decoding, then decodes each part once into
  what merging the decoded parts gives; taking worlds stays lazy too."""
  rng = np.random.default_rng(3)
  for _ in range(50):
    (one, _), (two, _) = _random_record(rng, 3), _random_record(rng, 2)
    parts = [(tuple("abcdefg"), one), (tuple("chaibjk"), two)]  # actor indices up to 6
    names, expected = merge(parts)
    decoded = []
    lazy_names, record = merge([(actors, _lazy(r, decoded)) for actors, r in parts])
    assert lazy_names == names == tuple("abcdefghijk") and isinstance(record, LazyEvents)
    assert record.ticks_per_frame == expected.ticks_per_frame == 6 and record.n_worlds == expected.n_worlds
    assert record.nbytes == expected.nbytes and impulses_known(record) == impulses_known(expected)
    np.testing.assert_array_equal(record.offsets, expected.offsets)
    worlds = rng.permutation(record.n_worlds)[: record.n_worlds // 2]
    taken = record.take(worlds)
    assert decoded == [] and not taken.decoded
    np.testing.assert_array_equal(taken.rows, expected.take(worlds).rows)
    np.testing.assert_array_equal(record.rows, expected.rows)
    np.testing.assert_array_equal(record.strength, expected.strength)
    assert decoded == [1, 1] and record.decoded  # each part decoded once, the merge kept
