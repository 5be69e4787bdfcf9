"""Saving a bank into a directory that other processes may share.

A bank loaded from a directory remembers the ids it held there
(:class:`mwbx.bank.shards.Origin`). Saving it back, under the directory's
lock and on the manifest as it is at that moment:

- writes the worlds it added (one new shard) and records as dropped only the
  ids it dropped itself; worlds other processes appended since it was loaded
  stay, and so do the worlds of corrupt shards it was loaded without;
- gives its new worlds fresh ids if another writer took one of theirs
  meanwhile (stored, dropped, or reserved by a sampling run; parents and
  lineage follow), so two processes refining one bank both
  keep their worlds;
- a bank moved to a later scene version is written whole beside the
  directory and swapped in with one atomic exchange (``renameat2``), so the
  path always holds a complete bank; it is refused, and nothing written, if
  other processes added worlds since the load or a sampling run is writing.

A bank not loaded from the directory (e.g. sampled in memory) drops nothing
and writes every world that is not already stored there (the same id with
the same key); a world whose id is taken there by another world gets a fresh
id, as above.

Saving changes no bank: :func:`save` returns the bank as saved (the ids its
worlds have on disk, the directory's ``next_id``, an origin naming every world
it holds there), as ``Bank.append`` and ``Bank.drop`` return new banks. Each
shard a save writes is marked, in the manifest, with the saving bank's family
token (:attr:`Bank.save_token`, shared with the banks made from it) and the
ids it renumbered: worlds a save of the family wrote into a directory, and
still stored there with their keys, are not written again, so saving a bank
twice, or a bank made from it before the first save returned, writes each
world once.
"""

from __future__ import annotations

import ctypes
import dataclasses
import errno
import json
import os
import pathlib
import shutil
import uuid

import numpy as np

from mwbx import files
from mwbx.bank import runs
from mwbx.bank import shards
from mwbx.errors import MwbxError


def save(bank, path: str | os.PathLike):
  """Writes ``bank`` into directory ``path`` (see the module); returns the bank as saved.

  ``bank`` itself is unchanged (its ids, ``next_id`` and origin). The bank
  returned holds the same worlds under the ids they have on disk (new worlds
  renumbered if another process took their ids meanwhile; parent ids and
  lineage follow), the directory's ``next_id``, and an origin naming every
  world it holds there and the ids this save changed
  (``origin.id_on_disk(id)``): saving it again writes nothing. Saving ``bank`` (or a
  bank made from it) into ``path`` again writes none of the worlds this save
  wrote, as long as they are stored there.

  Args:
    bank: the :class:`mwbx.Bank` to write.
    path: the bank directory (created if missing).

  Returns:
    a new :class:`mwbx.Bank`: ``bank`` as it is stored in ``path`` now.

  Example:
    >>> bank = mwbx.Bank.load("out/quick").append(more)
    >>> saved = bank.save("out/quick")   # its new worlds' ids may differ from bank's
    >>> saved.origin.id_on_disk(12)      # the id world 12 of ``bank`` has on disk
    >>> saved.save("out/quick")          # writes nothing new
  """
  path = pathlib.Path(path).absolute()
  if shards.has_manifest(path):
    stored = shards.read_manifest(path)
    if (stored["scene"]["digest"] != bank.digest
        and stored["scene"]["digest"] in {v["digest"] for v in bank.versions}):
      return _rewrite(bank, path)
  directory = shards.BankDirectory(path)
  origin = _origin_in(bank, path)
  with directory._locked():
    directory._check_scene(bank)
    if origin is not None:
      new = np.flatnonzero(~np.isin(bank.world_ids, origin.ids))
      gone = set(directory.taken(np.setdiff1d(origin.ids, bank.world_ids)).tolist())
    else:  # a world stored there with the same id and key is the same world; others are new
      new = np.flatnonzero(~directory.same_worlds(bank.world_ids, bank.keys))
      gone = set()
    earlier = _saved_before(directory, bank, new)
    rows = new[~np.isin(bank.world_ids[new], list(earlier))]
    mapping = {**earlier, **_fresh_ids(directory, bank.world_ids[rows])}
    out = renumbered(bank, {old: new_id for old, new_id in mapping.items() if old != new_id})
    if gone:
      directory.manifest["dropped"] = sorted(set(directory.manifest["dropped"]) | gone)
    directory._append_locked(out, rows, saved_by=_saved_by(bank, out, rows))
    directory.commit()
    next_id = int(directory.manifest["next_id"])
  write_readables(path, bank)
  return _as_saved(out, path, next_id, {old: disk for old, disk in mapping.items() if old != disk})


def write_readables(path: pathlib.Path, bank) -> None:
  """``config.resolved.json`` and ``scene.xml`` (for people), each written atomically."""
  files.write_atomic(path / "config.resolved.json", json.dumps(bank.config, indent=2), "resolved config")
  files.write_atomic(path / "scene.xml", bank.mjcf_text, "scene MJCF")


def _origin_in(bank, path: pathlib.Path):
  origin = getattr(bank, "origin", None)
  return origin if origin is not None and pathlib.Path(origin.path) == path else None


def _saved_before(directory, bank, rows: np.ndarray) -> dict[int, int]:
  """old id -> id on disk of those worlds ``rows`` of ``bank`` that a save of
  ``bank`` (or of a bank of its family: :attr:`Bank.save_token`) wrote into
  ``directory`` and that are still stored there with the same key; read from
  the shards those saves wrote."""
  written = directory.written_by(bank.save_token) if rows.size else {}
  if not written:
    return {}
  keys = np.asarray(bank.keys).reshape(bank.n_worlds, -1)
  found = {}
  for row in rows.tolist():
    hit = written.get(int(bank.world_ids[row]))
    if hit is not None and np.array_equal(hit[1], keys[row]):
      found[int(bank.world_ids[row])] = hit[0]
  return found


def _saved_by(bank, out, rows: np.ndarray) -> dict:
  """The mark a save puts on the shard it writes: ``bank``'s family token and
  the ids of ``rows`` it renumbered (id on disk, id in ``bank``)."""
  moved = [[int(new), int(old)] for old, new in zip(bank.world_ids[rows].tolist(), out.world_ids[rows].tolist())
           if old != new]
  return {"token": bank.save_token, "renumbered": moved}


def _as_saved(bank, path: pathlib.Path, next_id: int, renamed: dict | None = None):
  """``bank`` (ids as on disk) with the directory's ``next_id``, an origin of
  all its ids there and of the ids this save ``renamed`` (old -> on disk),
  and a family token of its own."""
  return dataclasses.replace(bank, next_id=max(bank.next_world_id, next_id),
                             origin=shards.Origin(str(path), np.sort(bank.world_ids), dict(renamed or {})),
                             save_token=uuid.uuid4().hex)


def _fresh_ids(directory, ids: np.ndarray) -> dict[int, int]:
  """old id -> new id (from the directory's ``next_id`` on) for new worlds if
  any of their ids is taken there: stored, dropped, or reserved by an
  unfinished sampling run; empty if none is."""
  if not directory.taken(ids, runs_too=True).size:
    return {}
  first = int(directory.manifest["next_id"])
  return {int(old): first + k for k, old in enumerate(ids.tolist())}


def renumbered(bank, mapping: dict[int, int]):
  """``bank`` with world ids replaced by ``mapping`` (old -> new); parent ids
  and lineage follow. ``bank`` itself if the mapping is empty."""
  if not mapping:
    return bank
  move = lambda i: mapping.get(int(i), int(i))
  lineage = {}
  for key, entry in bank.lineage.items():
    entry = dict(entry)
    if "parent" in entry:
      entry["parent"] = move(entry["parent"])
    lineage[str(move(key))] = entry
  return dataclasses.replace(
      bank, world_ids=np.array([move(i) for i in bank.world_ids], np.int64),
      parent_world=np.array([move(p) for p in bank.parent_world], np.int64), lineage=lineage,
      next_id=max(bank.next_world_id, max(mapping.values()) + 1))


def _rewrite(bank, path: pathlib.Path):
  """Writes ``bank`` (of a later scene version) whole beside ``path`` and
  exchanges the two directories atomically, all under ``path``'s lock;
  returns the bank as saved."""
  directory = shards.BankDirectory(path)
  origin = _origin_in(bank, path)
  ids = set(bank.world_ids.tolist())
  fresh = path.parent / f".{path.name}.upgrade-{uuid.uuid4().hex[:8]}"
  with directory._locked():
    manifest = directory.manifest
    if manifest["scene"]["digest"] not in {v["digest"] for v in bank.versions}:
      raise MwbxError(f"{path}: its scene changed since this bank was loaded; load it again (nothing was written)")
    live = [r["id"] for r in directory.unfinished_runs() if runs.is_live(path, r.get("id"))]
    if live:
      raise MwbxError(f"{path}: a sampling run is writing into this bank (run {live[0]}); save the new scene"
                      f" version when it has finished (nothing was written)")
    stored = directory.stored_ids()
    loaded = set(origin.ids.tolist()) if origin is not None else ids
    others = stored - loaded
    if others:
      raise MwbxError(f"{path}: worlds {shards._some(others)} were added by another process since this bank"
                      f" was loaded; load the bank again and redo the scene change (nothing was written)")
    try:
      target = shards.BankDirectory(fresh)
      with target._locked():
        target._check_scene(bank)
        target._append_locked(bank, np.arange(bank.n_worlds),
                              saved_by={"token": bank.save_token, "renumbered": []})
        target.manifest["runs"] = manifest.get("runs", [])
        target.manifest["dropped"] = sorted(set(manifest.get("dropped", [])) | ((loaded - ids) & stored))
        target.manifest["next_id"] = max(int(target.manifest["next_id"]), int(manifest.get("next_id", 0)))
        target.commit()
        next_id = int(target.manifest["next_id"])
      write_readables(fresh, bank)
      exchange(fresh, path)  # ``fresh`` now names the old directory
    except BaseException:
      files.remove_quietly(fresh)
      raise
  shutil.rmtree(fresh, ignore_errors=True)
  return _as_saved(bank, path, next_id)


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def exchange(a: pathlib.Path, b: pathlib.Path) -> None:
  """Swaps the directories ``a`` and ``b`` atomically (Linux ``renameat2``
  with ``RENAME_EXCHANGE``): ``b`` never stops existing. Where the kernel or
  file system cannot, two renames (a brief moment without ``b``)."""
  libc = ctypes.CDLL(None, use_errno=True)
  renameat2 = getattr(libc, "renameat2", None)
  if renameat2 is not None:
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
      files.fsync_dir(b.parent)
      return
    code = ctypes.get_errno()
    if code not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
      raise MwbxError(f"{b}: cannot swap in the new scene version ({os.strerror(code)}); the bank is unchanged")
  aside = b.parent / f".{b.name}.previous-{uuid.uuid4().hex[:8]}"
  os.rename(b, aside)
  os.rename(a, b)
  os.rename(aside, a)
  files.fsync_dir(b.parent)
