"""A sampling run into a bank directory: planned, resumable, shared by hosts.

What ``mwbx sample`` does, for research code. :func:`sample_run` plans the
run under the bank's lock (a new run reserves fresh world ids; a run whose
process died is resumed: its missing ids are sampled again, with the same
seed, so the bank ends as if nothing had happened), writes each chunk as a
shard as soon as it is done (a killed run loses at most the chunk in
flight), holds a liveness lock while it runs (so other processes know it is
alive), and with :class:`Hosts` shares the run's ids among processes joined
through ``jax.distributed`` (process 0 plans, each samples its share).

Example::

  import mwbx
  run = mwbx.sample_run("configs/quickstart.yaml", "out/quick", n_worlds=256)
  run.summary.worlds, run.stored       # worlds this run sampled, worlds in the bank
  mwbx.sample_run("configs/quickstart.yaml", "out/quick")   # resumes a killed run, else 256 more
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pathlib
from typing import Callable, Mapping, NamedTuple
import uuid

import jax
import numpy as np

from mwbx import distributed
from mwbx.bank import FLAG_CONTACT_OVERFLOW, FLAG_SIM_ERROR, Bank, BankDirectory, runs
from mwbx.batch_sim import memory
from mwbx.batch_sim.sampler import MAX_WORLD_ID, SampleStats, Sampler, check_chunk_memory, empty_bank
from mwbx.config import Config, load_config
from mwbx.errors import MwbxError
from mwbx.files import write_atomic
from mwbx.scene import Scene

LOG = logging.getLogger("mwbx.sample")


class Hosts(NamedTuple):
  """The processes one run is shared by (``jax.distributed``); the default: this one alone.

  Attributes:
    coordinator: ``HOST:PORT`` of process 0's coordinator.
    num_processes: how many processes share the run.
    process_id: this process's index, 0 … num_processes - 1 (0 plans).
    auto: let ``jax.distributed.initialize()`` detect all three (Slurm, MPI).
    timeout: seconds to wait for the other processes.
  """

  coordinator: str | None = None
  num_processes: int | None = None
  process_id: int | None = None
  auto: bool = False
  timeout: int = 300


@dataclasses.dataclass
class RunSummary:
  """Counts over the chunks of one sampling run (the chunks are not kept).

  Attributes:
    worlds, valid, at_rest, perturbations, sim_errors, overflow: this run's
      worlds and how many were valid, came to rest, were perturbed, stopped
      by MuJoCo errors, overflowed the contact budget.
    stats: the sampler's :class:`~mwbx.batch_sim.SampleStats` (None: this
      process had no worlds to sample).
    budget, warp_solver: the MJX contact budget and mjx:warp solver records, if used.
  """

  worlds: int = 0
  valid: int = 0
  at_rest: int = 0
  perturbations: int = 0
  sim_errors: int = 0
  overflow: int = 0
  stats: SampleStats | None = None
  budget: dict | None = None
  warp_solver: dict | None = None

  def add(self, part) -> None:
    self.worlds += part.n_worlds
    self.overflow += int(((part.flags & FLAG_CONTACT_OVERFLOW) != 0).sum())
    self.budget = part.run.get("contact_budget", self.budget)
    self.warp_solver = part.run.get("warp_solver", self.warp_solver)
    self.valid += int(part.valid.sum())
    self.at_rest += int(part.at_rest.sum())
    self.perturbations += int(part.perturbations.sum())
    self.sim_errors += int(((part.flags & FLAG_SIM_ERROR) != 0).sum())


class SamplingRun(NamedTuple):
  """What :func:`sample_run` did.

  Attributes:
    out: the bank directory.
    seed: the run's seed (the bank's).
    resumed: (worlds done, worlds in the run) of a resumed run, else None.
    summary: this process's :class:`RunSummary`.
    stored: worlds in the bank now.
  """

  out: pathlib.Path
  seed: int
  resumed: tuple[int, int] | None
  summary: RunSummary
  stored: int


class RunInterrupted(KeyboardInterrupt):
  """Ctrl-C (or SIGTERM through the CLI) during a run: ``saved`` of its worlds
  are in ``out``; running it again resumes it."""

  def __init__(self, saved: int, out: pathlib.Path):
    super().__init__(f"interrupted; {saved} worlds of this run are saved in {out}")
    self.saved, self.out = saved, out


def sample_run(config: Config | str | pathlib.Path, out: str | pathlib.Path, *, n_worlds: int | None = None,
               seed: int | None = None, backend: str | None = None, chunk_size: int | None = None,
               hosts: Hosts = Hosts(), progress=None, say: Callable[[str], None] | None = None,
               flags: Mapping[str, str] | None = None) -> SamplingRun:
  """Samples worlds into bank directory ``out``, resumably (see the module).

  Args:
    config: the scene's config (or its YAML path).
    out: the bank directory (made if missing; it may hold this scene's bank).
    n_worlds: worlds of a new run (default 256); a dead run is resumed first.
    seed: the run's seed (default: the bank's, else 0); must match the bank's.
    backend: ``auto`` | ``native`` | ``mjx`` (default: the config's).
    chunk_size: worlds per shard (default: the config's ``sim.chunk_size``).
    hosts: the processes sharing the run (default: this one alone).
    progress: optional callback taking a :class:`mwbx.progress.Progress`.
    say: where one-line announcements go (what runs, where, the engine's
      settings, a world stopped by a MuJoCo error); default: the
      ``mwbx.sample`` logger.
    flags: how the caller spells the parameters, for messages: parameter
      name -> flag (``out``, ``n_worlds``, ``seed`` and the :class:`Hosts`
      fields; e.g. ``{"n_worlds": "--worlds"}`` for a command line); a
      parameter not in it is named as it is spelled here.

  Returns:
    :class:`SamplingRun`.

  Raises:
    MwbxError: a bank of another scene in ``out``, another seed, a run that
      does not fit in memory, a shard that cannot be written (the worlds
      saved before stay; running again resumes).
    RunInterrupted: on Ctrl-C, with the worlds saved.
  """
  say = say or LOG.info
  config = config if isinstance(config, Config) else load_config(config)
  out = pathlib.Path(out)
  scene = Scene(config)
  # Before a bank directory is made or a run recorded: a run that cannot fit leaves nothing behind.
  chunk = chunk_size or config.sim.chunk_size
  check_chunk_memory(scene, min(chunk, n_worlds) if n_worlds else chunk)
  group = distributed.join(hosts.coordinator, hosts.num_processes, hosts.process_id, auto=hosts.auto,
                           timeout=hosts.timeout, flags=flags)
  plan, alive = _plan(out, scene, group, n_worlds, seed, flags) if group.leader else (None, None)
  try:
    plan = distributed.share_plan(group, plan, timeout=hosts.timeout)
    seed, todo = plan["seed"], np.asarray(plan["todo"], np.int64)
    resumed = tuple(plan["resume"]) if plan["resume"] else None
    if resumed and group.leader:
      say(f"resuming: {resumed[0]} of {resumed[1]} worlds done (seed {seed})")
    mine = distributed.my_share(todo, group)
    directory = BankDirectory(out)
    if group.leader:
      record = plan["record"]
    else:  # recorded now, live: a process killed before its first shard is resumed too
      record = {"id": uuid.uuid4().hex, "seed": seed, "id_ranges": runs.id_ranges(mine),
                "group_ranges": runs.id_ranges(todo), "finished": False}
      alive = runs.Liveness(out, record["id"])
      directory.append_run(record)
    record.update(process=group.process_id, processes=group.num_processes)
    summary = _sample_share(config, scene, out, directory, record, mine, seed, group, backend, chunk_size,
                            progress, say)
  finally:
    if alive is not None:
      alive.release()
  directory.finish_run(record["id"])
  write_atomic(out / "config.resolved.json", json.dumps(scene.config.resolved(), indent=2), "resolved config")
  write_atomic(out / "scene.xml", scene.mjcf_text, "scene MJCF")
  return SamplingRun(out, int(seed), resumed, summary, len(directory.stored_ids()))


def _plan(out: pathlib.Path, scene: Scene, group, n_worlds: int | None, seed: int | None,
          flags: Mapping[str, str] | None = None):
  """What a run does (decided by process 0 of a group, under the bank's
  lock): the seed, the world ids to sample (fresh ids reserved at once, or
  those of a dead run), and for a resumed run (worlds done, worlds in it);
  recorded in the manifest with this process's liveness lock held. Messages
  name the parameters as ``flags`` spells them (see :func:`sample_run`)."""
  flags = dict(flags or {})
  out_flag, worlds_flag = flags.get("out", "out"), flags.get("n_worlds", "n_worlds")
  directory = BankDirectory(out)
  if directory.manifest is None and (out / "checkpoints").is_dir():
    Bank.load(out).save(out)  # a bank of the orbax format: its worlds become the first shard
    directory = BankDirectory(out)
  if directory.manifest is not None and directory.manifest["scene"]["digest"] != scene.digest:
    raise MwbxError(f"{out}: holds a bank of a different config or MJCF; choose another {out_flag}")
  if n_worlds is not None:  # before a list of the run's ids is made
    first = 0 if directory.manifest is None else int(directory.manifest["next_id"])
    if first + n_worlds - 1 > MAX_WORLD_ID:
      raise MwbxError(f"{worlds_flag}: {n_worlds:,} worlds from id {first:,} would pass the last world id"
                      f" {MAX_WORLD_ID:,}")
    memory.check(n_worlds * memory.PLAN_BYTES_PER_WORLD, f"{worlds_flag} {n_worlds}: the run's list of world ids",
                 f"sample fewer worlds per run (the same {out_flag} continues the bank)")
  return runs.plan(directory, empty_bank(scene), n_worlds=n_worlds, seed=seed, run_id=uuid.uuid4().hex,
                   share=lambda ids: distributed.my_share(ids, group), flags=flags)


def _sample_share(config, scene, out, directory, record, mine, seed, group, backend, chunk_size, progress,
                  say) -> RunSummary:
  """Samples this process's ids of the run into the bank, a shard per chunk."""
  who = f" (process {group.process_id} of {group.num_processes})" if group.num_processes > 1 else ""
  summary = RunSummary()
  if not mine.size:
    return summary
  with Sampler(scene, backend=backend, chunk_size=chunk_size) as sampler:
    sampler.check_memory(mine.size)  # before anything is announced or allocated
    say(f"sampling {mine.size} worlds of {config.source or 'the config'} on {sampler.backend_label}"
        f" (worlds {mine[0]}..{mine[-1]}, seed {seed}){who} into {out}")
    say(scene.rates.describe())
    record["chunk_size"], record["backend"] = sampler.chunk_size, sampler.backend_label
    if sampler.contact_budget is not None:
      say(f"contact budget: {sampler.contact_budget.describe()}")
      record["contact_budget"] = sampler.contact_budget._asdict()
    if sampler.warp_solver is not None:
      say(f"warp solver: {sampler.warp_solver.describe()}")
      record["warp_solver"] = sampler.warp_solver._asdict()
    errors_shown = 0
    try:
      for part, stats in sampler.run_chunks(mine.size, jax.random.key(seed), ids=mine, progress=progress):
        part = dataclasses.replace(part, run={**part.run, "seed": seed})
        if stats.tree_frames:  # what sleep skipped in this run's worlds so far (mwbx info sums the runs)
          record["tree_frames"] = [stats.asleep_tree_frames, stats.tree_frames]
        # Each chunk is a shard on disk as soon as it is done: a killed run loses at most the
        # chunk in flight, and running it again resumes it.
        try:
          directory.append(part, run=record)
        except MwbxError as err:  # e.g. a full disk: the run stays resumable
          raise MwbxError(f"{err}; {summary.worlds} worlds of this run are saved in {out}; run the same"
                          f" command again to resume") from None
        summary.add(part)
        for world_id, message in stats.sim_errors[errors_shown:]:
          say(f"world {world_id}: MuJoCo error, world flagged and the run goes on: {' '.join(message.split())}")
        errors_shown = len(stats.sim_errors)
    except KeyboardInterrupt:
      raise RunInterrupted(summary.worlds, out) from None
  summary.stats = stats
  return summary
