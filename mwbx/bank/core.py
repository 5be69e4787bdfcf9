"""The bank: every sampled world of one scene, as arrays plus metadata.

Per world it stores the id and key, status flags, the recorded ``qpos`` frames
(through a pluggable store: raw float32 here, compressed by ``mwbx.codec``),
the tracked bodies' COM polylines at the query rate, the metric table and the
perturbation count; per bank the config, the MJCF text and a hash of both.
A bank directory is a manifest plus append-only shards (:mod:`mwbx.bank.shards`);
saving writes only worlds not stored yet, so an append costs its new shard.

Worlds are named by **world ids**, unique within a bank forever (sampled,
appended and refined worlds alike; a dropped world's id is never reused).
Every public function takes ids; a bank row is internal (:meth:`Bank.row_of`).
"""

from __future__ import annotations

import dataclasses
import pathlib
import uuid
from typing import ClassVar, Mapping, Sequence

import mujoco
import numpy as np

from mwbx import scene as scene_lib
from mwbx.bank import growth
from mwbx.bank import legacy
from mwbx.bank import lineage as lineage_lib
from mwbx.bank import model as model_lib
from mwbx.bank import saving
from mwbx.bank import shards
from mwbx.bank import summary as summary_lib
from mwbx.bank import versions
from mwbx.bank.flags import FLAG_AT_REST
from mwbx.bank.flags import INVALID
from mwbx.errors import MwbxError
from mwbx.events.record import EventRecord
from mwbx.qpos_store import QposStore


@dataclasses.dataclass(frozen=True)
class Bank:
  """Sampled worlds of one scene: a frozen record of arrays and metadata.

  Every operation returns a new bank (:meth:`append`, :meth:`drop`,
  :meth:`save`, refinement) and leaves this one as it was. The behaviour
  lives beside the record: lineage (:mod:`mwbx.bank.lineage`), the scene and
  model (:mod:`mwbx.bank.model`), new banks from old (:mod:`mwbx.bank.growth`),
  counts (:mod:`mwbx.bank.summary`) and persistence (:mod:`mwbx.bank.saving`,
  :mod:`mwbx.bank.shards`); the methods here call them.

  Attributes:
    world_ids: i64[W] world ids, unique within the bank (a sampled world's id is
      also its index in its run, which determines its randomness).
    keys: u32[W, 2] raw key data of each world.
    flags: u8[W] FLAG_FINISHED | FLAG_AT_REST | FLAG_UNSTABLE | FLAG_SIM_ERROR
      | FLAG_CONTACT_OVERFLOW.
    frame_count: i32[W] recorded qpos frames per world (at ``record_fps``).
    com: f32[W, P, B, 3] tracked COM polylines at ``query_fps``, m; points
      past ``com_count`` repeat the last one.
    com_count: i32[W] valid polyline points.
    metrics: f32[W, B, M] per-body metrics named by ``metric_names``.
    perturbations: i32[W] perturbations applied.
    steps: i32[W] physics steps simulated.
    parent_world: i64[W] id of the world this one was refined from (-1: sampled).
    refine_time: f32[W] time the refinement started from, s (NaN: sampled).
    qpos_store: the recorded qpos frames (raw or compressed).
    body_names, body_ids, objects, groups, metric_names: scene layout.
    record_fps, query_fps, timestep: rates (Hz) and physics step (s).
    config: resolved config (dict); mjcf_text: the MJCF; mjcf_includes: file name ->
      text of each MJCF file it includes; digest: sha256 of all three.
    mjcf_assets: name -> bytes of every other file the MJCF names (meshes,
      textures, height fields, skins, ``<model>`` files; :mod:`mwbx.bank.assets`):
      the bank's model is built from its MJCF text, includes and these alone
      (none if left out).
    lineage: per refined world (keyed by its id as a string): parent id, t_min,
      the objects asked for, the final active set, objects added or removed.
    scene_version: i16[W] the version of the scene each world belongs to
      (0: the scene the bank was sampled from; the current one is
      ``len(versions)``; :mod:`mwbx.bank.versions`).
    versions: the earlier versions' scene records (digest, config, MJCF,
      objects), oldest first.
    next_id: the smallest id never given to a world of this bank.
    run: how the worlds were drawn (e.g. ``{"seed": 0}``).
    events: each world's contact episodes (:class:`mwbx.events.EventRecord`),
      or None for a bank saved before they were recorded.
    event_actors: the actor names the events' indices refer to (objects, then
      named static geoms, :mod:`mwbx.events.actors`).
  """

  world_ids: np.ndarray
  keys: np.ndarray
  flags: np.ndarray
  frame_count: np.ndarray
  com: np.ndarray
  com_count: np.ndarray
  metrics: np.ndarray
  perturbations: np.ndarray
  steps: np.ndarray
  parent_world: np.ndarray
  refine_time: np.ndarray
  qpos_store: QposStore
  body_names: tuple[str, ...]
  body_ids: np.ndarray
  objects: dict[str, tuple[str, ...]]
  groups: dict[str, tuple[str, ...]]
  metric_names: tuple[str, ...]
  record_fps: float
  query_fps: float
  timestep: float
  config: dict
  mjcf_text: str
  digest: str
  mjcf_includes: dict = dataclasses.field(default_factory=dict)
  mjcf_assets: Mapping | None = dataclasses.field(default=None, compare=False)
  lineage: dict = dataclasses.field(default_factory=dict)
  run: dict = dataclasses.field(default_factory=dict)
  next_id: int = 0
  scene_version: np.ndarray | None = None
  versions: list = dataclasses.field(default_factory=list)
  events: EventRecord | None = None
  event_actors: tuple[str, ...] = ()
  _model: object = dataclasses.field(default=None, repr=False, compare=False)
  # Where the bank was loaded from or saved to (the bank a save returns), with the
  # ids it held there (mwbx.bank.shards.Origin): what a save into that directory adds and drops.
  origin: object = dataclasses.field(default=None, repr=False, compare=False)
  # Shared with the banks made from this one (append, drop, take) and new for a
  # bank loaded or returned by a save: the shards a save writes carry it, so a
  # later save of this family finds the worlds it wrote (mwbx.bank.saving).
  save_token: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex, repr=False, compare=False)

  # The arrays with a row per world, in the order shards store them.
  ROW_ARRAYS: ClassVar[tuple[str, ...]] = (
      "world_ids", "keys", "flags", "frame_count", "com", "com_count", "metrics", "perturbations", "steps",
      "parent_world", "refine_time", "scene_version")

  def __post_init__(self):  # defaults computed from other fields, set once as the record is made
    if self.mjcf_assets is None:
      object.__setattr__(self, "mjcf_assets", {})
    if self.scene_version is None:  # banks of one scene version, and those saved before versions
      object.__setattr__(self, "scene_version", np.full(len(self.world_ids), len(self.versions), np.int16))

  # -- views --------------------------------------------------------------------

  @property
  def n_worlds(self) -> int:
    return int(len(self.world_ids))

  @property
  def valid(self) -> np.ndarray:
    """bool[W]: worlds that did not go unstable, stop on a MuJoCo error or
    overflow their contact budget (the only ones queries see)."""
    return (self.flags & INVALID) == 0

  @property
  def at_rest(self) -> np.ndarray:
    return (self.flags & FLAG_AT_REST) != 0

  @property
  def next_world_id(self) -> int:
    """The id the next new world gets (never one given before)."""
    return max(int(self.next_id), int(self.world_ids.max()) + 1 if self.n_worlds else 0)

  def __repr__(self) -> str:
    refined = int((self.parent_world >= 0).sum())
    ids = (f"ids {int(self.world_ids.min())}..{int(self.world_ids.max())}" if self.n_worlds
           else "no worlds")
    return (f"Bank({self.n_worlds} worlds ({int(self.valid.sum())} valid, {refined} refined), {ids}, "
            f"{len(self.body_names)} bodies, com {tuple(self.com.shape)}, "
            f"qpos {self.qpos_store.kind} {self.qpos_store.nbytes:,} bytes)")

  # -- world ids and lineage (mwbx.bank.lineage) --------------------------------

  def row_of(self, ids):
    """Bank rows of world ids: an int for an int, i64[k] for a sequence.

    Raises:
      MwbxError: naming the first id the bank does not hold.
    """
    return rows_of(self.world_ids, ids)

  def children(self, world_id: int) -> np.ndarray:
    """i64[k] ids of the worlds refined directly from ``world_id``."""
    return lineage_lib.children(self, world_id)

  def descendants(self, world_id: int) -> np.ndarray:
    """i64[k] ids of every world refined from ``world_id``, directly or not."""
    return lineage_lib.descendants(self, world_id)

  def ancestors(self, world_id: int) -> np.ndarray:
    """i64[k] ids of the worlds ``world_id`` was refined from, its parent first,
    up to the sampled world (or the first one dropped from the bank)."""
    return lineage_lib.ancestors(self, world_id)

  def under(self, world_id: int) -> np.ndarray:
    """bool[W] worlds in the family tree below ``world_id``, itself included."""
    return lineage_lib.under(self, world_id)

  # -- frames, bodies, scene and model (mwbx.bank.model) ---------------------------

  def qpos_frames(self, world: int, start: int = 0, stop: int | None = None, *,
                  bodies: str | Sequence[str] | None = None) -> np.ndarray:
    """f32[T, nq] decoded qpos of world ``world`` (frame f at f / record_fps s).

    Args:
      world: world id.
      start, stop: frame range, slice semantics; only those frames are decoded.
      bodies: body, object or group names; only the joints that place them (their
        own and their ancestors') are decoded, the other qpos columns are zero.

    Example:
      >>> q = bank.qpos_frames(3, 0, 60, bodies="ball_6")  # first half second of one ball
    """
    row = self.row_of(int(world))
    columns = None if bodies is None else self.qpos_columns(bodies)
    try:
      return self.qpos_store.row_frames(row, start, stop, columns=columns)
    except MwbxError as err:  # the store knows rows; name the world the caller asked for
      raise type(err)(f"world {int(world)}: {err}") from None

  def qpos_columns(self, bodies: str | Sequence[str]) -> np.ndarray:
    """i64[k] qpos columns of the joints placing the named bodies (body, object or
    group names): the joints of each body and of its ancestors."""
    return model_lib.qpos_columns(self.model, self.body_ids[self.select_bodies(bodies)])

  def select_bodies(self, names: str | Sequence[str]) -> np.ndarray:
    """i32[k] indices into the tracked-body axis for body, object or group names."""
    return scene_lib.select_bodies(names, self.body_names, self.objects, self.groups, "selection", "bank")

  def mjcf_dir(self) -> str | None:
    """The folder the MJCF was in when the bank was sampled (for people;
    nothing is read there): :func:`mwbx.bank.model.mjcf_dir`."""
    return model_lib.mjcf_dir(self.config)

  def scene(self) -> scene_lib.Scene:
    """The bank's :class:`mwbx.Scene`, built only from the config, MJCF text
    and files stored in it (what refinement and solve resample);
    :func:`mwbx.bank.model.scene`."""
    return model_lib.scene(self)

  @property
  def model(self) -> mujoco.MjModel:
    """The scene's ``MjModel`` (with the mwbx observation sensors), built once
    from the MJCF text, includes and files stored in the bank alone
    (:func:`mwbx.bank.model.build_model`) and kept."""
    if self._model is None:
      object.__setattr__(self, "_model", model_lib.build_model(self))  # a cache, not a field's value
    return self._model

  def with_scene(self, scene, progress=None) -> "Bank":
    """This bank in a later version of its scene (objects added after its
    own), every world kept; see :func:`mwbx.bank.versions.upgrade`."""
    return versions.upgrade(self, scene, progress)

  def absent(self, world: int) -> dict[str, tuple[float, float]]:
    """Objects not in world ``world`` for a while: name -> (from, until) s
    (``until`` inf: to the end); see :func:`mwbx.bank.versions.absent`."""
    return versions.absent(self, world)

  def metric(self, name: str) -> np.ndarray:
    """f32[W, B] one metric column."""
    if name not in self.metric_names:
      raise MwbxError(f"metric: unknown metric {name!r} (have: {', '.join(self.metric_names)})")
    return self.metrics[..., self.metric_names.index(name)]

  @property
  def flex_objects(self) -> tuple[str, ...]:
    """The objects that are flexes (cloth, soft solids, ropes)."""
    return model_lib.flex_objects(self)

  def flex_body_mask(self) -> np.ndarray:
    """bool[B] the tracked bodies that are a flex's own (vertex or node)
    bodies, which have no orientation; not a body a flex is pinned to."""
    return model_lib.flex_body_mask(self)

  # -- counts (mwbx.bank.summary) ---------------------------------------------------

  def object_collisions(self) -> np.ndarray:
    """f64[W] impacts per world (a flex counts its most-struck vertex's)."""
    return summary_lib.object_collisions(self)

  def summary(self) -> dict:
    """Counts for ``mwbx info`` and the sampling summary."""
    return summary_lib.summary(self)

  @property
  def nbytes(self) -> int:
    """Bytes the bank's arrays, store and events take in memory."""
    arrays = sum(getattr(self, name).nbytes for name in self.ROW_ARRAYS)
    events = 0 if self.events is None else self.events.nbytes
    return int(arrays + self.qpos_store.nbytes + events)

  # -- new banks from this one (mwbx.bank.growth) ------------------------------------

  def drop(self, ids) -> "Bank":
    """A bank without the worlds ``ids`` (their ids are never given again).

    Their lineage entries go; worlds refined from them keep their parent id.
    Saving the result records them as dropped in the bank directory.
    """
    return growth.drop(self, ids)

  def _take(self, rows: np.ndarray, **changes) -> "Bank":
    """The bank of ``rows`` (i64[k], in that order); the store is copied."""
    return growth.take_rows(self, rows, **changes)

  def append(self, other: "Bank") -> "Bank":
    """A bank with ``other``'s worlds after this one's (same scene and config).

    Ids stay unique: if any of ``other``'s ids is below :attr:`next_world_id`,
    all of ``other``'s worlds get new ids from there on (in order; parent ids
    inside ``other`` follow), else they keep theirs.
    """
    return growth.append(self, other)

  @staticmethod
  def concatenate(banks: Sequence["Bank"]) -> "Bank":
    """One bank of the worlds of ``banks`` (same scene, distinct ids), in order.

    Unlike chained :meth:`append` calls, each array is concatenated once.
    """
    return growth.concatenate(banks)

  # -- persistence --------------------------------------------------------------

  def save(self, path: str | pathlib.Path) -> "Bank":
    """Writes the bank to directory ``path`` as append-only shards; returns the bank as saved.

    Worlds already stored there (same scene) are not written again: a save
    after an append or a refinement writes one new shard with the new worlds,
    and worlds this bank dropped are recorded as such. Other processes may
    write the same directory: worlds they added since this bank was loaded
    stay, and new worlds whose ids they took meanwhile are given fresh ids.
    Also writes ``path/config.resolved.json`` and ``path/scene.xml`` for
    people. See :mod:`mwbx.bank.saving`.

    Like :meth:`append` and :meth:`drop`, saving leaves this bank as it is
    (ids, ``next_id``, origin) and returns a new one: the same worlds under
    the ids they have on disk (parent ids and lineage following), with the
    directory's ``next_id``, whose next save writes only what changes after
    it. Keep using the returned bank. Saving this one again writes none of
    the worlds this save wrote (nor does saving a bank made from it), as
    long as they are stored there.

    Args:
      path: the bank directory (created if missing).

    Returns:
      the bank as stored in ``path``.

    Example:
      >>> bank = mwbx.refine(mwbx.Bank.load("out/quick"), 3, "ball", t_min=0.5, n_samples=8)
      >>> bank = bank.save("out/quick")   # the refined worlds' ids as on disk
      >>> bank.save("out/quick")          # writes nothing new
    """
    return saving.save(self, path)

  @classmethod
  def load(cls, path: str | pathlib.Path, *, skip_corrupt: bool = False, lazy: bool = True) -> "Bank":
    """Reads a bank directory; MwbxError if missing or corrupt.

    Args:
      path: the directory (shards written by :meth:`save`, or an older orbax
        checkpoint).
      skip_corrupt: load the worlds of every intact shard and leave out those
        whose checksums fail (listed in ``bank.run["corrupt_shards"]``); by
        default a corrupt shard is an error naming it and its arrays. Reads
        every shard now (one at a time).
      lazy: read only the manifest and each shard's small arrays (ids, flags,
        metrics, ...) now; ``com`` is then a :class:`~mwbx.bank.lazy.LazyRows`
        and ``qpos_store`` a :class:`~mwbx.bank.lazy.LazyQposStore`, each
        reading a shard when first used (its checksums are checked then), so
        banks larger than memory open at once and queries stream over their
        shards. ``lazy=False`` reads and checks everything now.

    The bank remembers the ids it was loaded with (``bank.origin``): saving it
    back adds its new worlds and drops only the ids it dropped, whatever other
    processes wrote meanwhile. Shards holding one id twice, and shard names
    that are paths, are errors naming them.

    Example:
      >>> bank = mwbx.Bank.load("out/pachinko")           # manifest + metrics only
      >>> hits = mwbx.evaluate(bank, queries)               # a shard at a time
      >>> q = bank.qpos_frames(int(bank.world_ids[hits][0]))  # reads one shard
    """
    path = pathlib.Path(path).absolute()
    if not path.is_dir():
      raise MwbxError(f"{path}: no bank here (not a directory)")
    if shards.has_manifest(path):
      bank = shards.load(cls, path, skip_corrupt=skip_corrupt, lazy=lazy)
    elif (path / "checkpoints").is_dir():
      bank = legacy.load(cls, path)
    else:
      raise MwbxError(f"{path}: no bank here (no manifest.json)")
    bank.check()
    return bank

  def check(self) -> None:
    """Raises MwbxError if the arrays disagree with each other."""
    w = self.n_worlds
    for name in self.ROW_ARRAYS:
      if len(getattr(self, name)) != w:
        raise MwbxError(f"bank: {name} has {len(getattr(self, name))} rows, expected {w}")
    if self.qpos_store.n_worlds != w:
      raise MwbxError(f"bank: qpos store has {self.qpos_store.n_worlds} worlds, expected {w}")
    if self.events is not None and self.events.n_worlds != w:
      raise MwbxError(f"bank: contact events of {self.events.n_worlds} worlds, expected {w}")
    if self.com.ndim != 4 or self.com.shape[2] != len(self.body_names):
      raise MwbxError(f"bank: com has shape {self.com.shape}, expected [W, P, {len(self.body_names)}, 3]")


def rows_of(world_ids: np.ndarray, ids):
  """Rows of ``ids`` in ``world_ids`` (i64[W], unique): an int for an int, i64[k]
  for a sequence; MwbxError naming the first id not there (:meth:`Bank.row_of`)."""
  world_ids = np.asarray(world_ids, np.int64)
  scalar = np.ndim(ids) == 0
  wanted = np.atleast_1d(np.asarray(ids)).reshape(-1)
  if wanted.size and not np.issubdtype(wanted.dtype, np.integer):
    if not np.all(np.mod(wanted.astype(np.float64), 1) == 0):
      raise MwbxError(f"world ids must be integers, got {ids!r}")
  wanted = wanted.astype(np.int64)
  order = np.argsort(world_ids, kind="stable")
  sorted_ids = world_ids[order]
  pos = np.minimum(np.searchsorted(sorted_ids, wanted), max(len(sorted_ids) - 1, 0))
  found = sorted_ids[pos] == wanted if len(sorted_ids) else np.zeros(wanted.shape, bool)
  if not found.all():
    missing = int(wanted[~found][0])
    span = (f"ids {int(sorted_ids[0])}..{int(sorted_ids[-1])}, {len(sorted_ids)} worlds"
            if len(sorted_ids) else "no worlds")
    raise MwbxError(f"world {missing}: no world with this id in the bank ({span})")
  rows = order[pos].astype(np.int64)
  return int(rows[0]) if scalar else rows

