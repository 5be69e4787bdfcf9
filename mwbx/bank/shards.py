"""A bank directory: a small manifest plus append-only shards.

::

  BANK/manifest.json          format, scene (config, MJCF, layout), runs, shards, dropped ids
  BANK/shards/00000/          one shard per chunk of worlds: <array>.npy per array, lineage.json
  BANK/assets/<sha256>        the files the MJCF names (meshes, textures, ...; mwbx.bank.assets)
  BANK/config.resolved.json   for people (every default filled in)
  BANK/scene.xml              for people

A shard is written into a temporary folder and renamed into place (atomic on
POSIX), then the manifest is replaced atomically (write, fsync, rename): a
process killed at any moment leaves the last complete manifest and every
shard it names. Shards are never rewritten: appending worlds writes one new
shard, dropping worlds records their ids in the manifest. Every array of a
shard has a CRC32 in the manifest, checked on load; a corrupt shard is named
and the others stay readable (``Bank.load(path, skip_corrupt=True)``).

Runs of ``mwbx sample`` are recorded in the manifest (seed, the ids they are
to produce, finished or not), so a killed run can be resumed: its missing ids
are sampled again, and a world depends only on the seed and its id
(:mod:`mwbx.bank.runs`).

Several processes may share a bank directory. Every manifest update happens
under the directory's lock on the manifest as it is then, and a bank loaded
from a directory remembers the ids it was loaded with (:class:`Origin`), so
:func:`save` adds the worlds this bank added and drops only the ids it
dropped itself: worlds other processes appended meanwhile stay. New worlds
whose ids another writer took meanwhile are renumbered under the lock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import functools
import io
import json
import os
import pathlib
import re
import threading
import typing
import uuid

import numpy as np

from mwbx import files
from mwbx.bank import assets as assets_lib
from mwbx.bank import checks
from mwbx.bank import lazy as lazy_lib
from mwbx.bank import npy
from mwbx.bank import runs
from mwbx.bank.stores import store_class
from mwbx.codec import polyline
from mwbx.events import lazy as events_lazy
from mwbx.events import record as events_lib
from mwbx.errors import MwbxError
from mwbx.progress import NOTICE
from mwbx.queries import path_boxes
from mwbx.yaml_input import short_repr

FORMAT = 3
MANIFEST = "manifest.json"
LOCK = ".lock"  # flock()ed around every manifest update
SHARDS = "shards"
# Shard folder names and array names of a manifest: plain names, never a path
# (a crafted manifest must not make loading read outside the bank).
_PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")


class Origin(typing.NamedTuple):
  """Where a bank was loaded from (or saved to: the bank a save returns), and the ids it had then.

  Attributes:
    path: the bank directory (absolute).
    ids: the world ids the bank held there; a save into ``path`` writes
      worlds not among them and drops those of them the bank no longer holds.
    renamed: for the bank a save returns, the ids that save changed: id in
      the bank saved -> id on disk (worlds whose ids another writer took, or
      written there before under other ids); empty for a loaded bank.
  """

  path: str
  ids: np.ndarray  # i64[k], sorted
  renamed: dict = {}

  def id_on_disk(self, world: int) -> int:
    """The id world ``world`` of the bank saved has on disk."""
    return self.renamed.get(int(world), int(world))


def com_step(config: dict) -> float | None:
  """The COM grid step of a bank's config (None: float32 polylines)."""
  return polyline.grid_step((config.get("codec") or {}).get("e_com"))


def has_manifest(path: pathlib.Path) -> bool:
  return (pathlib.Path(path) / MANIFEST).is_file()


def disk_bytes(path: str | pathlib.Path) -> int:
  """Bytes of the files under a bank folder: a shard's from its manifest
  entry where it says (written since banks keep it: no file of it stat'ed,
  thousands of files at a million worlds), every other file stat'ed."""
  path = pathlib.Path(path)
  said = {}
  if has_manifest(path):
    said = {e["name"]: e["bytes"] for e in read_manifest(path)["shards"]
            if isinstance(e.get("bytes"), int) and not isinstance(e.get("bytes"), bool)}
  total = 0
  for folder, dirs, names in os.walk(path):
    if pathlib.Path(folder) == path / SHARDS:
      total += sum(said[d] for d in dirs if d in said)
      dirs[:] = [d for d in dirs if d not in said]
    total += sum(os.lstat(os.path.join(folder, n)).st_size for n in names
                 if not os.path.islink(os.path.join(folder, n)))
  return total


def scene_meta(bank) -> dict:
  """What every world of a bank shares (JSON)."""
  _, store_meta = bank.qpos_store.empty().state()
  return {
      "digest": bank.digest, "config": bank.config, "mjcf_text": bank.mjcf_text,
      "mjcf_includes": bank.mjcf_includes, "mjcf_assets": assets_lib.table(bank.mjcf_assets or {}),
      "body_names": list(bank.body_names),
      "body_ids": [int(b) for b in bank.body_ids],
      "objects": {k: list(v) for k, v in bank.objects.items()},
      "groups": {k: list(v) for k, v in bank.groups.items()},
      "metric_names": list(bank.metric_names), "record_fps": bank.record_fps,
      "query_fps": bank.query_fps, "timestep": bank.timestep, "qpos_store": store_meta,
      "versions": list(bank.versions),
  }


class BankDirectory:
  """The manifest of one bank directory, and writes to it (shards, runs).

  Args:
    path: the directory (created on the first write).
  """

  def __init__(self, path: str | pathlib.Path):
    self.path = pathlib.Path(path).absolute()
    self.manifest = read_manifest(self.path) if has_manifest(self.path) else None
    self._written: list[str] = []  # shard folders written since the lock was taken, not yet committed

  # -- reading the manifest ---------------------------------------------------------

  def stored_ids(self, with_dropped: bool = False) -> set[int]:
    """Ids of the worlds in the shards, less the dropped ones (unless ``with_dropped``)."""
    if self.manifest is None:
      return set()
    ids = set()
    for entry in self.manifest["shards"]:
      ids.update(i for lo, hi in entry["id_ranges"] for i in range(lo, hi + 1))
    return ids if with_dropped else ids - set(int(i) for i in self.manifest["dropped"])

  def taken(self, ids, runs_too: bool = False) -> np.ndarray:
    """i64[k] those of ``ids`` given to a world here (stored or dropped), or,
    with ``runs_too``, reserved by an unfinished sampling run."""
    ids = np.unique(np.asarray(ids, np.int64))
    if self.manifest is None or not ids.size:
      return ids[:0]
    ranges = [r for e in self.manifest["shards"] for r in e["id_ranges"]]
    if runs_too:
      ranges += [r for rec in self.unfinished_runs() for r in rec.get("group_ranges", rec["id_ranges"])]
    hit = np.isin(ids, np.asarray(self.manifest["dropped"], np.int64))
    for lo, hi in ranges:
      hit[np.searchsorted(ids, lo):np.searchsorted(ids, hi, side="right")] = True
    return ids[hit]

  def same_worlds(self, ids, keys) -> np.ndarray:
    """bool[k]: whether world ``ids[i]`` is stored here (not dropped) with the
    same key ``keys[i]`` (u32[k, 2], the bank's ``keys``), i.e. is the same
    world; reads the ``world_ids`` and ``keys`` of the shards holding them."""
    ids = np.asarray(ids, np.int64)
    keys = np.asarray(keys).reshape(len(ids), -1)
    same = np.zeros(len(ids), bool)
    stored = np.isin(ids, np.asarray(sorted(self.stored_ids()), np.int64))
    if not stored.any():
      return same
    for entry in self.manifest["shards"]:
      inside = np.zeros(len(ids), bool)
      for lo, hi in entry["id_ranges"]:
        inside |= (ids >= lo) & (ids <= hi)
      if not (inside & stored).any():
        continue
      arrays = _load_arrays(self.path, entry, ["world_ids", "keys"])
      at = {int(i): k for i, k in zip(arrays["world_ids"], arrays["keys"].reshape(len(arrays["world_ids"]), -1))}
      for row in np.flatnonzero(inside & stored):
        key = at.get(int(ids[row]))
        same[row] = key is not None and np.array_equal(key, keys[row])
    return same

  def written_by(self, token: str) -> dict[int, tuple[int, np.ndarray]]:
    """The worlds stored here (not dropped) that saves marked ``token`` wrote
    (``saved_by`` in their shards' entries): id in the saving bank -> (id
    here, key u32[2]); reads those shards' ``world_ids`` and ``keys``."""
    if self.manifest is None:
      return {}
    stored = self.stored_ids()
    written = {}
    for entry in self.manifest["shards"]:
      mark = entry.get("saved_by") or {}  # checked by read_manifest
      if mark.get("token") != token:
        continue
      back = {int(new): int(old) for new, old in mark.get("renumbered", [])}
      arrays = _load_arrays(self.path, entry, ["world_ids", "keys"])
      keys = arrays["keys"].reshape(len(arrays["world_ids"]), -1)
      for here, key in zip(arrays["world_ids"].tolist(), keys):
        if here in stored:
          written[back.get(here, here)] = (here, key)
    return written

  def unfinished_runs(self) -> list[dict]:
    """Run records not finished (of one or of several processes)."""
    if self.manifest is None:
      return []
    return [r for r in self.manifest["runs"] if not r["finished"]]

  # -- writing ----------------------------------------------------------------------

  @contextlib.contextmanager
  def _locked(self):
    """Holds the directory's lock and re-reads the manifest: several processes
    (``mwbx sample --num-processes``) write shards into one bank."""
    while True:
      self.path.mkdir(parents=True, exist_ok=True)
      lock = open(self.path / LOCK, "a+b")
      fcntl.flock(lock, fcntl.LOCK_EX)
      # A scene-version save swaps a new directory in while holding the old
      # one's lock: a lock file no longer at the path locks nothing; retry.
      try:
        current = os.stat(self.path / LOCK)
        mine = os.fstat(lock.fileno())
        if (current.st_ino, current.st_dev) == (mine.st_ino, mine.st_dev):
          break
      except FileNotFoundError:
        pass
      lock.close()
    with lock:
      try:
        if has_manifest(self.path):
          self.manifest = read_manifest(self.path)
        # Shards are written only under this lock: a temporary shard folder
        # here now, or a shard in no manifest (its manifest write failed, or
        # its writer died before it), was left by a write that did not land.
        listed = {e["name"] for e in self.manifest["shards"]} if self.manifest is not None else set()
        if (self.path / SHARDS).is_dir():
          for folder in (self.path / SHARDS).iterdir():
            if folder.name.startswith(".tmp-") or (folder.is_dir() and folder.name not in listed):
              files.remove_quietly(folder)
        self._written = []
        yield
      finally:
        fcntl.flock(lock, fcntl.LOCK_UN)

  def _check_scene(self, bank) -> None:
    if self.manifest is None:
      self.manifest = {"format": FORMAT, "scene": scene_meta(bank), "next_id": 0, "dropped": [],
                       "runs": [], "shards": [], "run": {}}
      assets_lib.write(self.path, bank.mjcf_assets or {})
    elif self.manifest["scene"]["digest"] != bank.digest:
      raise MwbxError(f"{self.path}: holds a bank of a different config or MJCF; choose another directory")
    elif "mjcf_assets" not in self.manifest["scene"] and bank.mjcf_assets:
      # Saved before banks stored the files their MJCF names: stored now, from this bank of its scene.
      self.manifest["scene"]["mjcf_assets"] = assets_lib.write(self.path, bank.mjcf_assets)

  def append(self, bank, rows=None, run: dict | None = None) -> None:
    """Writes the worlds ``rows`` of ``bank`` (default all) as one new shard.

    Args:
      bank: worlds of this directory's scene.
      rows: i64[k] bank rows to write (default: every row).
      run: a run record (with an ``id``) to add or replace in the same
        manifest write.
    """
    rows = np.arange(bank.n_worlds) if rows is None else np.asarray(rows, np.int64)
    with self._locked():
      self._check_scene(bank)
      taken = self.taken(bank.world_ids[rows])
      if taken.size:
        raise MwbxError(f"{self.path}: world ids {_some(taken)} are already in the bank; nothing was written")
      self._append_locked(bank, rows, run)
      self.commit()

  def _append_locked(self, bank, rows: np.ndarray, run: dict | None = None, saved_by: dict | None = None) -> None:
    """:meth:`append` with the lock held and the manifest not yet committed;
    ``saved_by`` marks the shard (a save's family token and renumbering:
    :meth:`written_by`)."""
    history = self.manifest["scene"].get("versions", [])
    if len(bank.versions) < len(history):  # sampled from the current scene, without the bank's history
      bank = dataclasses.replace(bank, versions=list(history),
                                 scene_version=np.full(bank.n_worlds, len(history), np.int16))
    if rows.size:
      entry = _write_shard(self.path, bank, rows, self._next_shard_name())
      if saved_by is not None:
        entry["saved_by"] = saved_by
      self.manifest["shards"].append(entry)
      self._written.append(self.manifest["shards"][-1]["name"])
    if run is not None:
      self._put_run(run)
    self.manifest["next_id"] = max(int(self.manifest["next_id"]), bank.next_world_id)
    if bank.run:  # how the bank's worlds are drawn (the seed later runs continue with)
      self.manifest["run"] = {k: v for k, v in bank.run.items() if not k.startswith("corrupt_")}

  def append_run(self, run: dict) -> None:
    """Adds (or replaces, by ``id``) a run record of a bank that exists."""
    with self._locked():
      self._put_run(run)
      self.commit()

  def _put_run(self, run: dict) -> None:
    runs = self.manifest["runs"]
    for i, old in enumerate(runs):
      if old.get("id") == run["id"]:
        runs[i] = dict(run)
        return
    runs.append(dict(run))

  def finish_run(self, run_id: str) -> None:
    with self._locked():
      for record in self.manifest["runs"]:
        if record.get("id") == run_id:
          record["finished"] = True
      self.commit()

  def commit(self) -> None:
    """Replaces the manifest atomically; if that fails (a full disk), the
    shards written since the lock was taken are removed with it: a shard in no
    manifest is never left behind."""
    try:
      files.write_atomic(self.path / MANIFEST, json.dumps(self.manifest, indent=1), "bank manifest")
    except BaseException:
      for name in self._written:
        files.remove_quietly(self.path / SHARDS / name)
      self.manifest["shards"] = [e for e in self.manifest["shards"] if e["name"] not in self._written]
      self._written = []
      raise
    self._written = []

  def add_boxes(self, packed: dict[str, np.ndarray]) -> None:
    """Writes the path boxes (:data:`BOXES`) of shards saved without them,
    beside their arrays, and records them in one manifest write; a shard
    dropped or boxed by another process meanwhile is left as it is."""
    with self._locked():
      entries = {e["name"]: e for e in self.manifest["shards"]}
      for name, array in packed.items():
        entry = entries.get(name)
        if entry is None or BOXES in entry["checksums"]:
          continue
        buffer = io.BytesIO()
        np.save(buffer, array, allow_pickle=False)
        blob = buffer.getvalue()
        files.write_atomic(self.path / SHARDS / name / f"{BOXES}.npy", blob, "query index")
        entry["checksums"][BOXES] = checks.crc32(array)
        entry["index"] = _index_meta()
        if "bytes" in entry:
          entry["bytes"] += len(blob)
      self.commit()

  def _next_shard_name(self) -> str:
    taken = {e["name"] for e in self.manifest["shards"]}
    n = len(self.manifest["shards"])
    while f"{n:05d}" in taken:
      n += 1
    return f"{n:05d}"


def _write_shard(path: pathlib.Path, bank, rows: np.ndarray, name: str) -> dict:
  """Writes the worlds ``rows`` of ``bank`` as shard ``name``; returns its manifest entry."""
  part = bank._take(rows)
  store_arrays, _ = part.qpos_store.state()
  arrays = {n: np.ascontiguousarray(getattr(part, n)) for n in bank.ROW_ARRAYS if n != "com"}
  com = np.asarray(part.com)
  arrays["com_grid"] = polyline.encode(com, com_step(bank.config))
  arrays[BOXES] = path_boxes.pack(path_boxes.build(com))
  arrays.update({f"qpos_{k}": np.ascontiguousarray(v) for k, v in store_arrays.items()})
  if part.events is not None:
    arrays.update(part.events.arrays(part.frame_count))
  lineage = {str(int(i)): bank.lineage[str(int(i))] for i in part.world_ids if str(int(i)) in bank.lineage}
  lineage_bytes = json.dumps(lineage).encode()
  shards = path / SHARDS
  shards.mkdir(parents=True, exist_ok=True)
  tmp = shards / f".tmp-{uuid.uuid4().hex}"
  try:
    tmp.mkdir()
    for key, value in arrays.items():
      with open(tmp / f"{key}.npy", "wb") as f:
        np.save(f, value, allow_pickle=False)
        f.flush()
        os.fsync(f.fileno())
    files.write_fsynced(tmp / "lineage.json", lineage_bytes)
    files.fsync_dir(tmp)
    shard_bytes = sum(f.stat().st_size for f in tmp.iterdir())
    os.rename(tmp, shards / name)
    files.fsync_dir(shards)
  except OSError as err:  # e.g. a full disk: no half shard stays behind
    files.remove_quietly(tmp)
    raise MwbxError(f"{shards / name}: cannot write this shard of {int(part.n_worlds)} worlds ({files.why(err)});"
                    f" nothing of it was kept, the worlds saved before stay") from None
  entry = {"name": name, "worlds": int(part.n_worlds), "id_ranges": runs.id_ranges(part.world_ids),
          "com_row_shape": [int(x) for x in part.com.shape[1:]],
          "checksums": {k: checks.crc32(v) for k, v in arrays.items()},
          "lineage_crc": checks.crc32(np.frombuffer(lineage_bytes, np.uint8)), "bytes": shard_bytes,
          "index": _index_meta()}
  if part.events is not None:  # the names the events' actor indices refer to
    entry["events"] = {"version": events_lib.EVENTS_VERSION, "actors": list(part.event_actors),
                       "ticks_per_frame": int(part.events.ticks_per_frame),
                       "with_impulse": events_lazy.impulses_known(part.events)}
  return entry


def read_manifest(path: pathlib.Path) -> dict:
  file = pathlib.Path(path) / MANIFEST
  try:
    manifest = json.loads(file.read_text())
  except (OSError, ValueError) as err:
    raise MwbxError(f"{file}: unreadable bank manifest ({checks.first_line(err)})") from None
  if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
    raise MwbxError(f"{file}: unsupported bank manifest (format {manifest.get('format')!r}, "
                    f"expected {FORMAT})" if isinstance(manifest, dict) else f"{file}: not a bank manifest")
  for i, entry in enumerate(manifest.get("shards", [])):
    name = entry.get("name") if isinstance(entry, dict) else None
    if not isinstance(name, str) or not _PLAIN_NAME.fullmatch(name):
      raise MwbxError(f"{file}: shards[{i}].name: {name!r} is not a shard name (letters, digits, - and _;"
                      f" never a path)")
    for key in list(entry.get("checksums", {})):
      if not _PLAIN_NAME.fullmatch(key):
        raise MwbxError(f"{file}: shards[{i}].checksums: {key!r} is not an array name (never a path)")
    mark = entry.get("saved_by")
    if mark is not None and not (isinstance(mark, dict) and isinstance(mark.get("token"), str)
                                 and isinstance(mark.get("renumbered", []), list)
                                 and all(isinstance(pair, list) and len(pair) == 2
                                         and all(type(i) is int for i in pair) for pair in mark.get("renumbered", []))):
      raise MwbxError(f"{file}: shards[{i}].saved_by: {short_repr(mark)} is not a save's mark (a token and"
                      f" [id here, id before] pairs)")
  for i, run in enumerate(manifest.get("runs", [])):
    run_id = run.get("id") if isinstance(run, dict) else None
    # A run's id names its liveness lock file (runs/<id>.lock), which is unlinked.
    if run_id is not None and (not isinstance(run_id, str) or not _PLAIN_NAME.fullmatch(run_id)):
      raise MwbxError(f"{file}: runs[{i}].id: {short_repr(run_id)} is not a run id (letters, digits, - and _;"
                      f" never a path)")
  return manifest


def _some(ids) -> str:
  """A few ids of a set, for a message."""
  ids = sorted(int(i) for i in ids)
  return ", ".join(map(str, ids[:10])) + (f" … ({len(ids)} in all)" if len(ids) > 10 else "")


# Arrays of a shard read only when used (lazy banks): the COM polylines, the
# qpos streams and the paths' boxes (`index_boxes`, what a query reads first).
BOXES = "index_boxes"


def _index_meta() -> dict:
  """A shard entry's ``index``: the layout its :data:`BOXES` are stored in."""
  return {"version": path_boxes.VERSION, "chunk": path_boxes.DEFAULT_CHUNK}


def _is_big(name: str) -> bool:
  return name == "com_grid" or name.startswith(("qpos_", "index_"))


def _load_arrays(path: pathlib.Path, entry: dict, names) -> dict:
  """The named arrays of one shard, checked against its manifest entry."""
  where = f"{path}/{SHARDS}/{entry['name']}"  # (a string: pathlib's joins cost more than the reads of small arrays)
  arrays = {}
  try:
    for key in names:
      arrays[key] = npy.read(f"{where}/{key}.npy")
  except Exception as err:  # noqa: BLE001 - np.load of a damaged header raises many kinds
    raise MwbxError(f"{where}: corrupt or missing shard ({type(err).__name__}: "
                    f"{checks.first_line(err)})") from None
  checks.verify(f"{where}", arrays, {k: entry["checksums"][k] for k in names})
  return arrays


def _read_small(path: pathlib.Path, entry: dict) -> tuple[dict, dict]:
  """(arrays but the big ones, lineage) of one shard, checked."""
  where = f"{path}/{SHARDS}/{entry['name']}"
  arrays = _load_arrays(path, entry, [k for k in entry["checksums"] if not _is_big(k)])
  try:
    with open(f"{where}/lineage.json", "rb") as f:
      lineage_bytes = f.read()
  except OSError as err:
    raise MwbxError(f"{where}: corrupt or missing shard ({checks.first_line(err)})") from None
  if checks.crc32(np.frombuffer(lineage_bytes, np.uint8)) != int(entry["lineage_crc"]):
    raise MwbxError(f"{where}: corrupt bank: checksum mismatch in lineage.json")
  try:
    return arrays, json.loads(lineage_bytes)
  except ValueError as err:
    raise MwbxError(f"{where}: corrupt lineage.json ({checks.first_line(err)})") from None


def _shard_events(path: pathlib.Path, entry: dict, arrays: dict, lazy: bool):
  """(actor names, EventRecord) of one shard, or with ``lazy`` a
  :class:`~mwbx.events.lazy.LazyEvents` decoded when first used; ((), None)
  for a shard written before contact events were recorded (or of a later
  events version). Version 1 held frames and no strength: one tick a frame,
  strength unknown."""
  meta = entry.get("events")
  if not meta or meta.get("version") not in (1, 2, events_lib.EVENTS_VERSION) or "events_rows" not in arrays:
    return (), None
  where, version, n_worlds = str(path / SHARDS / entry["name"]), meta["version"], int(entry["worlds"])
  arrays = {k: arrays[k] for k in (*events_lib.STORED_ARRAYS, "frame_count") if k in arrays}  # all a decode keeps alive
  ticks = meta.get("ticks_per_frame", 1) if version > 1 else 1
  if not isinstance(ticks, int) or isinstance(ticks, bool):
    raise MwbxError(f"{where}: corrupt contact events (ticks_per_frame {ticks!r})")
  decode = lambda: events_lib.EventRecord.from_arrays(arrays, n_worlds, where, ticks_per_frame=ticks, version=version)
  if not lazy:
    return tuple(meta["actors"]), decode()
  known = meta.get("with_impulse")  # written since version 3's shards say it
  if known is not None and (not isinstance(known, int) or isinstance(known, bool) or known < 0):
    raise MwbxError(f"{where}: corrupt contact events (with_impulse {known!r})")
  counts = lambda: events_lib.stored_counts(arrays, n_worlds, where, version)
  with_impulse = (lambda: known) if known is not None else (
      lambda: events_lib.stored_impulses_known(arrays, int(counts().sum(dtype=np.int64)), where, version))
  return tuple(meta["actors"]), events_lazy.LazyEvents(decode, counts, ticks, with_impulse)


def _read_com(path: pathlib.Path, entry: dict) -> np.ndarray:
  """f32[w, P, B, 3] COM polylines of one shard, checked and decoded."""
  data = _load_arrays(path, entry, ["com_grid"])["com_grid"]
  try:
    return polyline.decode(data)
  except MwbxError as err:
    raise MwbxError(f"{path / SHARDS / entry['name']}: {err}") from None


def _boxes_loader(path: pathlib.Path, entry: dict, n_points: int):
  """A loader of one shard's path boxes (:mod:`mwbx.queries.path_boxes`), or
  None for a shard saved without them (or in a layout this version does not read)."""
  meta = entry.get("index")
  if not (isinstance(meta, dict) and meta.get("version") == path_boxes.VERSION and BOXES in entry["checksums"]
          and type(meta.get("chunk")) is int and meta["chunk"] > 0):
    return None

  def load():
    stored = _load_arrays(path, entry, [BOXES])[BOXES]
    try:
      return path_boxes.unpack(stored, max(n_points - 1, 1), meta["chunk"])
    except ValueError as err:
      raise MwbxError(f"{path / SHARDS / entry['name']}: corrupt {BOXES}.npy ({err})") from None

  return load


class _BoxesToWrite:
  """The path boxes of a bank's shards saved without them: computed from their
  decoded paths when first asked (each loader below) and written into the
  bank together once every such shard's are known (a first query reads them
  all), so the next opening reads them as stored."""

  def __init__(self, path: pathlib.Path, entries: list[dict]):
    self.path, self.names = path, {e["name"] for e in entries}
    self._pending: dict[str, np.ndarray] = {}
    self._lock = threading.Lock()

  def loader(self, entry: dict):
    def load():
      boxes = path_boxes.build(_read_com(self.path, entry))
      self._add(entry["name"], path_boxes.pack(boxes))
      return boxes
    return load

  def _add(self, name: str, packed: np.ndarray) -> None:
    with self._lock:
      self._pending[name] = packed
      if set(self._pending) != self.names:
        return
      pending, self._pending, self.names = self._pending, {}, set()
    try:
      BankDirectory(self.path).add_boxes(pending)
      NOTICE.info(f"{self.path}: query index written for {len(pending)} shards")
    except (MwbxError, OSError) as err:  # e.g. a read-only bank: answered all the same
      NOTICE.info(f"{self.path}: cannot write its query index ({checks.first_line(err)}); each first query decodes"
                  f" those {len(pending)} shards")


def _read_qpos(path: pathlib.Path, entry: dict, kind, meta: dict):
  """The qpos store of one shard, checked."""
  arrays = _load_arrays(path, entry, [k for k in entry["checksums"] if k.startswith("qpos_")])
  return kind.restore({k[5:]: v for k, v in arrays.items()}, meta)


@dataclasses.dataclass(frozen=True, eq=False)
class _ShardQpos:
  """A lazy bank's loader of one shard's qpos store (called when its worlds
  are decoded); ``figures`` reads only the small arrays, for the store's stats."""

  path: pathlib.Path
  entry: dict
  kind: type
  meta: dict

  def __call__(self):
    return _read_qpos(self.path, self.entry, self.kind, self.meta)

  def figures(self) -> dict:
    """The store's ``row_figures``, from its arrays but the streams (checked)."""
    names = [k for k in self.entry["checksums"] if k.startswith("qpos_") and k != "qpos_data"]
    return self.kind.figures_of_saved({k[5:]: v for k, v in _load_arrays(self.path, self.entry, names).items()})

  def empty(self):
    """A store of the shard's kind and settings, without worlds."""
    return self.kind.restore({}, self.meta)


def verify(path: str | pathlib.Path) -> list[str]:
  """Reads every array of every shard of a bank directory (one shard at a
  time) and every file its MJCF names, and returns one line per corrupt
  shard (naming its arrays) or file."""
  path = pathlib.Path(path).absolute()
  manifest = read_manifest(path)
  problems = assets_lib.verify(path, manifest["scene"].get("mjcf_assets"))
  for entry in manifest["shards"]:
    try:
      _read_small(path, entry)
      _read_com(path, entry)
      _load_arrays(path, entry, [k for k in entry["checksums"] if k.startswith(("qpos_", "index_"))])
    except MwbxError as err:
      problems.append(str(err))
  return problems


def load(cls, path: pathlib.Path, *, skip_corrupt: bool = False, lazy: bool = True):
  """The bank of a shard directory (see :meth:`mwbx.bank.Bank.load`)."""
  manifest = read_manifest(path)
  scene = manifest["scene"]
  stored = assets_lib.stored(path, scene.get("mjcf_assets"))  # the files its MJCF names, read when used
  if not lazy:
    for name in stored:
      stored[name]  # read and checked now
  store_meta = scene["qpos_store"]
  kind = store_class(store_meta["kind"])
  entries, smalls, corrupt, corrupt_ids = [], [], [], []
  for entry in manifest["shards"]:
    try:
      small = _read_small(path, entry)
      if skip_corrupt or not lazy:  # read everything now: a corrupt shard is found here
        small[0]["com"] = _read_com(path, entry)
        small[0]["qpos"] = _read_qpos(path, entry, kind, store_meta)
    except MwbxError:
      if not skip_corrupt:
        raise
      corrupt.append(entry["name"])
      corrupt_ids.extend(entry["id_ranges"])
      continue
    entries.append(entry)
    smalls.append(small)
  if not entries:
    if not manifest["shards"]:
      raise MwbxError(f"{path}: no worlds stored yet (a sampling run has started it)")
    raise MwbxError(f"{path}: no readable shard" + (f" (corrupt: {', '.join(corrupt)})" if corrupt else ""))
  counts = [int(e["worlds"]) for e in entries]
  eager = "com" in smalls[0][0]
  if eager:
    com = np.concatenate([arrays["com"] for arrays, _ in smalls])
    store = smalls[0][0]["qpos"]
    store.extend(*[arrays["qpos"] for arrays, _ in smalls[1:]])
  else:
    row_shape = entries[0].get("com_row_shape") or list(_read_com(path, entries[0]).shape[1:])
    boxes = [_boxes_loader(path, e, row_shape[0]) for e in entries]
    unboxed = [e for e, loader in zip(entries, boxes) if loader is None]
    if unboxed:
      NOTICE.info(f"{path}: {len(unboxed)} of {len(entries)} shards saved without a query index; the first query"
                  f" computes it from their decoded paths and writes it")
      to_write = _BoxesToWrite(path, unboxed)
      boxes = [loader or to_write.loader(e) for e, loader in zip(entries, boxes)]
    com = lazy_lib.LazyRows([lambda e=e: _read_com(path, e) for e in entries], counts, tuple(row_shape),
                            np.float32, companions=boxes)
    disk = functools.cache(lambda: sum(os.stat(f"{path}/{SHARDS}/{e['name']}/{k}.npy").st_size  # when first asked
                                       for e in entries for k in e["checksums"] if k.startswith("qpos_")))
    store = lazy_lib.LazyQposStore(kind.kind, [_ShardQpos(path, e, kind, store_meta) for e in entries], counts,
                                   disk)
  lineage = {}
  for _, shard_lineage in smalls:
    lineage.update(shard_lineage)
  run = dict(manifest.get("run", {}))
  if corrupt:
    run["corrupt_shards"], run["corrupt_worlds"] = corrupt, corrupt_ids
  small_names = [n for n in cls.ROW_ARRAYS if n != "com"]
  for arrays, _ in smalls:  # shards written before scene versions: all of version 0
    arrays.setdefault("scene_version", np.zeros(len(arrays["world_ids"]), np.int16))
  event_actors, events = events_lib.merge([_shard_events(path, e, arrays, lazy and not skip_corrupt)
                                           for e, (arrays, _) in zip(entries, smalls)])
  bank = cls(
      **{name: np.concatenate([arrays[name] for arrays, _ in smalls]) for name in small_names},
      com=com, qpos_store=store, body_names=tuple(scene["body_names"]),
      body_ids=np.asarray(scene["body_ids"], np.int32),
      objects={k: tuple(v) for k, v in scene["objects"].items()},
      groups={k: tuple(v) for k, v in scene["groups"].items()},
      metric_names=tuple(scene["metric_names"]), record_fps=scene["record_fps"],
      query_fps=scene["query_fps"], timestep=scene["timestep"], config=scene["config"],
      mjcf_text=scene["mjcf_text"], mjcf_includes=scene.get("mjcf_includes", {}), mjcf_assets=stored,
      digest=scene["digest"], lineage=lineage, run=run, next_id=int(manifest["next_id"]),
      versions=list(scene.get("versions", [])), events=events, event_actors=event_actors)
  if events is not None and events.ticks_per_frame == 1 and events_lazy.episodes(events) \
      and not events_lazy.impulses_known(events):
    NOTICE.info(f"{path}: contact events known at the stored frames only (sampled before they were found at every"
                " physics step): touch times to a frame, no impulses; sample again for both")
  ids, counts = np.unique(bank.world_ids, return_counts=True)
  if (counts > 1).any():
    twice = ids[counts > 1]
    where = [e["name"] for e in entries if runs.ranges_ids(e["id_ranges"]) & set(twice[:10].tolist())]
    raise MwbxError(f"{path}: world ids {_some(twice)} are stored more than once (shards {', '.join(where)});"
                    f" the bank is inconsistent")
  dropped = np.asarray(manifest["dropped"], np.int64)
  if dropped.size:
    keep = np.flatnonzero(~np.isin(bank.world_ids, dropped))
    bank = bank._take(keep, lineage={k: v for k, v in lineage.items() if int(k) not in set(dropped.tolist())})
  return dataclasses.replace(bank, origin=Origin(str(path), np.sort(bank.world_ids)))


