"""The ``mwbx`` command: thin wrappers over the public API.

  mwbx sample CONFIG [--worlds N] [--seed S] [--backend auto|mjx|native] [--out DIR]
              [--num-processes N --process-id I --coordinator HOST:PORT | --distributed]
  mwbx info DIR [--json]
  mwbx query BANK QUERIES.yaml [--rank METRIC[:sum|max]] [--top K] [--under ID] [--json]
  mwbx view BANK [--worlds 3,17 | --top K [--rank METRIC]] [--queries Q.yaml] [--html OUT.html] [--no-browser]
  mwbx refine BANK --world ID --objects NAMES (--box u0,v0,u1,v1 --camera CAM | --time T) --samples N
              [--seed S] [--out DIR] [--scene NEW.yaml --add NAMES] [--remove NAMES]
  mwbx solve BANK QUERIES.yaml [--budget N] [--time-budget S] [--step-budget N] [--samples N] [--seed S]
              [--out DIR] [--plot PNG]
  mwbx drop BANK IDS [--out DIR]
  mwbx browse BANK [--port P] [--host 127.0.0.1] [--workdir DIR] [--autosave] [--no-browser]
  mwbx export BANK --world ID [--usd FILE] [--mp4 FILE] [--npz FILE] [--fps F] [--start S] [--stop S]
              [--camera NAME | --look-at EX EY EZ TX TY TZ] [--width 1280] [--height 720]

Worlds are named by their ids everywhere (what `query` lists).

Every error a user can cause ends in one line naming the file, field or value
(exit status 2), never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import pathlib
import secrets
import signal
import sys
import textwrap
import threading

import jax
import mujoco

import mwbx
from mwbx import __version__
from mwbx.bank import runs, shards, warm
from mwbx.batch_sim.sampling_run import Hosts, RunInterrupted, sample_run
from mwbx.errors import MwbxError
from mwbx.events import lazy as events_lazy
from mwbx.progress import notices_to_stderr, reporter
from mwbx.queries import Camera, ScreenBox, load_queries
from mwbx.queries.report import run_query_file
from mwbx.refinement import RefineRequest, run_refinement
from mwbx.world_ids import parse_world_ids

# The viewer (meshcat), the page (viser), search (optax) and the MJX contact
# budget (mujoco.mjx) are imported by the commands that use them: seconds of
# imports every other command does not pay.


def _cmd_sample(args) -> int:
  _check_sample_args(args)
  config = mwbx.load_config(args.config)
  out = pathlib.Path(args.out or f"out/{pathlib.Path(args.config).stem}")
  hosts = Hosts(args.coordinator, args.num_processes, args.process_id, args.distributed, args.timeout)
  warming = warm.start(args.config)  # the codec compiles beside the native loop on a first run
  try:
    with _reporter_with_safe_points("sample") as update:
      run = sample_run(config, out, n_worlds=args.worlds, seed=args.seed, backend=args.backend,
                       chunk_size=args.chunk_size, hosts=hosts, progress=update,
                       say=lambda message: print(f"mwbx: {message}", file=sys.stderr, flush=True),
                       flags=SAMPLE_FLAGS)
  except RunInterrupted as err:
    print(f"mwbx: interrupted; {err.saved} worlds of this run are saved in {err.out};"
          f" run the same command again to resume", file=sys.stderr)
    return 130
  finally:
    if warming is not None:  # its work is done or no longer needed
      warming.kill()
      warming.wait()
  _print_run(run)
  return 0


@contextlib.contextmanager
def _reporter_with_safe_points(name: str):
  """The progress reporter of command ``name``, taking Ctrl-C at its reports.

  A KeyboardInterrupt raised inside JAX's tracing can surface as another
  error (a ValueError from its compilation cache), so the first SIGINT only
  sets a flag, and the next progress report (made where Python code runs,
  between blocks) raises KeyboardInterrupt; a command that finishes first
  just finishes. A second SIGINT interrupts at once. Nothing changes where
  SIGINT is not Python's default handler (ignored, or handled by the
  caller)."""
  pending = []

  def on_sigint(signum, frame):
    if pending:
      raise KeyboardInterrupt
    pending.append(signum)

  previous = signal.getsignal(signal.SIGINT)
  installed = previous is signal.default_int_handler and threading.current_thread() is threading.main_thread()
  if installed:
    signal.signal(signal.SIGINT, on_sigint)
  try:
    with reporter(name) as report:
      def update(p):
        if pending:
          raise KeyboardInterrupt
        report(p)

      yield update
  finally:
    if installed:
      signal.signal(signal.SIGINT, previous)


# The most worlds one `mwbx sample` run may ask for (ids are 32-bit).
MAX_WORLDS = 1 << 32
# The most worlds one chunk may hold (its buffers are checked against memory too).
MAX_CHUNK_SIZE = 1 << 24


# How `mwbx sample` spells sample_run's parameters (and its Hosts), for the library's messages.
SAMPLE_FLAGS = {"out": "--out", "n_worlds": "--worlds", "seed": "--seed", "coordinator": "--coordinator",
                "num_processes": "--num-processes", "process_id": "--process-id"}


def _check_sample_args(args) -> None:
  """Counts and seeds of ``mwbx sample`` in range, named in the message."""
  counts = (("--worlds", args.worlds, MAX_WORLDS), ("--chunk-size", args.chunk_size, MAX_CHUNK_SIZE))
  for flag, value, limit in counts:
    if value is not None and value < 1:
      raise MwbxError(f"{flag}: must be at least 1, got {value}")
    if value is not None and value > limit:
      raise MwbxError(f"{flag}: must be at most {limit:,} worlds, got {value}")
  if args.seed is not None and not -(1 << 63) <= args.seed < (1 << 63):
    raise MwbxError(f"--seed: must fit in 64 bits (signed), got {args.seed}")


def _print_run(run) -> None:
  """The summary ``mwbx sample`` prints of a :class:`~mwbx.batch_sim.SamplingRun`."""
  s = run.summary
  n = max(1, s.worlds)
  errors = f", {s.sim_errors} of them stopped by MuJoCo errors" if s.sim_errors else ""
  unstable = s.worlds - s.valid - s.overflow
  overflow = f", {s.overflow} over the contact budget" if s.overflow else ""
  print(f"worlds sampled      {s.worlds} ({s.valid} valid, {unstable} unstable{errors}{overflow})")
  print(f"worlds at rest      {s.at_rest} ({s.at_rest / n:.0%})")
  print(f"perturbations       {s.perturbations} ({s.perturbations / n:.1f} per world)")
  if s.stats is not None:
    st = s.stats
    if s.budget:
      print(f"contact budget      {_budget_line(s.budget)}")
    if s.warp_solver:
      w = s.warp_solver
      print(f"warp solver         {w['solver']}, tolerance {w['tolerance']:g}, {w['iterations']} iterations"
            f" ({w['reason']})")
    if st.asleep_share is not None:
      print(f"asleep              {st.asleep_share:.1%} of the tree-frames (island sleep: MuJoCo skipped their"
            f" physics)")
    print(f"world-steps/s       {st.world_steps_per_second:,.0f} ({st.backend};"
          f" {st.world_steps:,} steps in {st.run_seconds:.2f} s, compile {st.compile_seconds:.1f} s,"
          f" compression {st.codec_seconds:.1f} s, contact events {st.events_seconds:.1f} s)")
  size = sum(f.stat().st_size for f in (run.out / "shards").rglob("*") if f.is_file())
  print(f"bank                {run.out} ({run.stored} worlds, {size / 1e6:.1f} MB on disk)")


def _rest_saved(bank) -> str:
  """What stopping worlds at rest (or asleep) saved: the share of frames to
  the end time that were not simulated."""
  end_time = (bank.config.get("sim") or {}).get("end_time")
  if not end_time or not bank.n_worlds:
    return ""
  full = round(float(end_time) * bank.record_fps) + 1  # frames of a world that runs to the end
  total = full * bank.n_worlds
  saved = 1.0 - float(bank.frame_count.clip(max=full).sum()) / total
  return f" (stopping there saved {saved:.1%} of the frames to the end time)" if saved > 0 else ""


def _sleep_saved(path) -> str:
  """What island sleep skipped in the bank's sampling runs: the share of
  kinematic trees asleep over the frames their worlds stepped (each run
  records its own; banks sampled before runs recorded it say nothing)."""
  if not shards.has_manifest(pathlib.Path(path)):
    return ""
  runs = shards.read_manifest(pathlib.Path(path)).get("runs")
  counted = [r["tree_frames"] for r in (runs if isinstance(runs, list) else []) if isinstance(r, dict)
             and isinstance(r.get("tree_frames"), list) and len(r["tree_frames"]) == 2
             and all(isinstance(x, int) and x >= 0 for x in r["tree_frames"])]  # a crafted record counts nothing
  asleep, total = (sum(c[i] for c in counted) for i in (0, 1))
  if total <= 0 or asleep > total:
    return ""
  return (f"; asleep {asleep / total:.1%} of the tree-frames sampled (MuJoCo skipped their physics:"
          f" {asleep:,} of {total:,})")


def _budget_line(record: dict) -> str:
  """The MJX contact budget a bank's worlds were sampled under (its ``run`` record)."""
  from mwbx.batch_sim.contact_budget import ContactBudget  # lazy: imports mujoco.mjx (seconds)
  return ContactBudget.from_dict(record).describe()


def _cmd_info(args) -> int:
  problems = []
  if args.verify:  # read every array of every shard, not only what the summary needs
    problems = shards.verify(args.bank) if shards.has_manifest(pathlib.Path(args.bank)) else []
    if problems and not args.skip_corrupt:
      raise MwbxError(f"{len(problems)} corrupt shard{'s' * (len(problems) > 1)}: " + "; ".join(problems))
    if problems:  # every corrupt shard named, then the summary of the others
      print(f"mwbx: --verify: {len(problems)} corrupt shard{'s' * (len(problems) > 1)}: " + "; ".join(problems),
            file=sys.stderr)
  bank = _load_bank(args)
  s = bank.summary()
  if args.json:
    print(json.dumps({**s, "world_ids": [int(bank.world_ids.min()), int(bank.world_ids.max())]
                      if bank.n_worlds else None, "next_world_id": bank.next_world_id,
                      "cameras": _cameras(bank), "objects": {k: list(v) for k, v in bank.objects.items()},
                      "bodies": list(bank.body_names), "groups": {k: list(v) for k, v in bank.groups.items()},
                      "disk_bytes": shards.disk_bytes(args.bank),
                      "config": bank.config, "digest": bank.digest, "run": bank.run,
                      "scene_versions": [v["digest"] for v in bank.versions] + [bank.digest]}, indent=2))
    return 1 if problems else 0
  print(f"bank                {args.bank}")
  errors = f", {s['sim_errors']} of them stopped by MuJoCo errors" if s["sim_errors"] else ""
  overflow = f", {s['contact_overflow']} over the contact budget" if s["contact_overflow"] else ""
  print(f"worlds              {s['worlds']} ({s['valid']} valid, {s['unstable']} unstable{errors}{overflow})")
  if bank.run.get("contact_budget"):
    print(f"contact budget      {_budget_line(bank.run['contact_budget'])}")
  print(f"at rest             {s['at_rest_fraction']:.1%}{_rest_saved(bank)}")
  if bank.run.get("sleep"):
    from mwbx.batch_sim.sleep import SleepSettings  # lazy: the bank alone needs no engine
    print(f"sleep               {SleepSettings.from_record(bank.run['sleep']).describe()}{_sleep_saved(args.bank)}")
  print(f"mean collisions     {s['mean_collisions']:.2f} per world")
  print(f"perturbations       {s['perturbations']}")
  print(f"storage             {shards.disk_bytes(args.bank):,} bytes on disk, {s['storage_bytes']:,} bytes in memory")
  for key, value in s["qpos"].items():
    print(f"qpos {key:<22}{value:,.4g}" if isinstance(value, float) else f"qpos {key:<22}{value}")
  print(f"world ids           {_id_span(bank)}")
  print(f"refined worlds      {int((bank.parent_world >= 0).sum())}")
  print(f"objects             {_names_line(list(bank.objects))}")
  if bank.versions:
    counts = [int((bank.scene_version == v).sum()) for v in range(len(bank.versions) + 1)]
    print(f"scene versions      {len(bank.versions) + 1} (worlds per version: {', '.join(map(str, counts))};"
          f" version 0 had {', '.join(bank.versions[0]['objects'])})")
  print(f"bodies              {_bodies_line(bank)}")
  print(f"groups              {'; '.join(f'{k}: {_names_line(list(v))}' for k, v in bank.groups.items()) or 'none'}")
  print(f"cameras             {', '.join(_cameras(bank)) or 'none (screen queries need a named MJCF camera)'}")
  print(f"metrics             {', '.join(bank.metric_names)}")
  if bank.events is None:
    print("contact events      none (the bank was saved before they were recorded)")
  else:
    statics = [a for a in bank.event_actors if a not in bank.objects]
    episodes, known = events_lazy.episodes(bank.events), events_lazy.impulses_known(bank.events)
    found = ("at every physics step, with impulses" if known == episodes else "on the stored frames (no impulses)"
             if not known else f"at every physics step ({known / episodes:.0%} with impulses; the rest on stored"
             " frames)")
    print(f"contact events      {episodes:,} episodes, found {found}; static actors:"
          f" {', '.join(statics) or 'none'}")
  print(f"rates               record {bank.record_fps:g} fps, query {bank.query_fps:g} fps,"
        f" timestep {bank.timestep:.6g} s")
  print(f"config              {bank.config.get('source') or '-'} (full: mwbx info --json)")
  return 1 if problems else 0


def _load_bank(args):
  """The bank of ``args.bank``; with ``--skip-corrupt`` without its corrupt
  shards, naming them and their worlds."""
  bank = mwbx.Bank.load(args.bank, skip_corrupt=args.skip_corrupt)
  if bank.run.get("corrupt_shards"):
    worlds = ", ".join(f"{lo}..{hi}" if hi > lo else f"{lo}" for lo, hi in bank.run["corrupt_worlds"])
    print(f"mwbx: skipped corrupt shards {', '.join(bank.run['corrupt_shards'])} (worlds {worlds});"
          f" `mwbx info {args.bank} --verify` says what is wrong", file=sys.stderr)
  return bank


def _id_span(bank) -> str:
  ids = bank.world_ids
  return f"{int(ids.min())}..{int(ids.max())} (next {bank.next_world_id})" if bank.n_worlds else "none"


INFO_NAMES = 12  # names `mwbx info` lists in a line before it says how many there are


def _names_line(names: list[str]) -> str:
  """``names`` joined, or the first few and how many in all (``--json`` lists every one)."""
  if len(names) <= INFO_NAMES:
    return ", ".join(names)
  return f"{', '.join(names[:INFO_NAMES])}, … ({len(names)} in all; every name: mwbx info --json)"


def _bodies_line(bank) -> str:
  """The tracked bodies, a flex's vertex bodies as one span ("cloth_0 … cloth_224
  (225 bodies of flex cloth)"), not hundreds of names."""
  spans = {}
  for name in bank.flex_objects:
    members = bank.objects[name]
    if len(members) > 2:
      spans.update({b: None for b in members})
      spans[members[0]] = f"{members[0]} … {members[-1]} ({len(members)} bodies of flex {name})"
  return _names_line([spans[b] if b in spans else b for b in bank.body_names if spans.get(b, b) is not None])


def _cameras(bank) -> list[str]:
  """'name (aspect a)' of each named MJCF camera."""
  model = bank.model
  out = []
  for i in range(model.ncam):
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i)
    if name:
      out.append(f"{name} (aspect {Camera.from_model(model, name).aspect:.3g})")
  return out


def _cmd_view(args) -> int:
  import mwbx.viewer  # lazy: meshcat
  bank = _load_bank(args)
  queries = None
  if args.queries:
    queries = load_queries(args.queries, bank=bank)
  ids = parse_world_ids(args.worlds, flag="--worlds", known=bank.world_ids) if args.worlds else None
  ids, match = mwbx.viewer.choose_worlds(bank, ids=ids, top=args.top, rank=args.rank, queries=queries,
                                         flags={"ids": "--worlds", "top": "--top", "rank": "--rank"})
  if args.top is not None or args.rank is not None:
    note = mwbx.viewer.select.closest_note(match, bank)
    if note:
      print(f"mwbx: {note}", file=sys.stderr)
  paths = None if args.paths == "none" else True if args.paths == "all" else args.paths.split(",")
  kwargs = dict(worlds=ids, paths=paths, layout=args.layout, camera=args.camera,
                queries=queries.queries if queries is not None else None)
  shown = "default" if ids is None else ", ".join(str(int(i)) for i in ids)
  if args.html:
    out = mwbx.viewer.export_html(bank, args.html, **kwargs)
    print(f"wrote {out} (worlds {shown})")
    return 0
  with mwbx.viewer.view(bank, open=not args.no_browser, zmq_url=args.zmq_url, **kwargs) as vis:
    print(f"mwbx: showing worlds {shown} at {vis.url()}", file=sys.stderr)
    if vis.server_proc is None:
      return 0  # drawn into a server someone else runs
    try:  # from the announcement on, Ctrl-C (or SIGTERM) is the way out, not an error
      print("mwbx: meshcat server running; Ctrl-C stops it", file=sys.stderr)
      vis.wait()
    except KeyboardInterrupt:
      pass  # leaving the with block stops the server
  return 0


def _cmd_query(args) -> int:
  bank = _load_bank(args)
  report = run_query_file(bank, args.queries, rank=args.rank, top=args.top, under=args.under,
                          flags={"top": "--top"})
  print(json.dumps(report.to_dict(), indent=2) if args.json else report.format())
  return 0


def _cmd_refine(args) -> int:
  bank = _load_bank(args)
  # Which flags go together is the command's to say; what they name, refine checks.
  if args.objects is None and args.add is None and args.remove is None:
    raise MwbxError("refine: name objects to refine (--objects), to add (--add) or to remove (--remove)")
  if (args.box is None) == (args.time is None):
    raise MwbxError("refine: give either --box with --camera, or --time")
  frustum = None
  if args.box is not None:
    if args.camera is None:
      raise MwbxError("--box: needs --camera (an MJCF camera name)")
    try:
      u0, v0, u1, v1 = (float(x) for x in args.box.split(","))
    except ValueError:
      raise MwbxError(f"--box: expected u0,v0,u1,v1 in normalised screen coordinates, got {args.box!r}") from None
    frustum = Camera.from_model(bank.model, args.camera).frustum(ScreenBox(u0, v0, u1, v1))
  out = pathlib.Path(args.out or args.bank)
  # Without --seed every run draws new worlds; the seed is printed to repeat one.
  seed = secrets.randbits(31) if args.seed is None else args.seed
  with _reporter_with_safe_points("refine") as update:
    done = run_refinement(bank, RefineRequest(args.world, args.objects or (), frustum=frustum, t_min=args.time,
                                          n_samples=args.samples, key=jax.random.key(seed), backend=args.backend,
                                          scene=args.scene, add=args.add or (), remove=args.remove or ()),
                      progress=update)
  total, new, stats = done.bank, done.new, done.stats
  if done.scene_version is not None:
    print(f"mwbx: bank moved to scene version {done.scene_version} ({args.scene})", file=sys.stderr)
  active = [len(new.lineage[str(int(i))]["active"]) for i in new.world_ids]
  print(f"mwbx: saving {total.n_worlds} worlds to {out}", file=sys.stderr)
  total = total.save(out)  # the new worlds' ids on disk (another process may have taken theirs meanwhile)
  saved = [total.origin.id_on_disk(i) for i in new.world_ids]
  ids = f"{saved[0]}..{saved[-1]}"
  print(f"refined worlds      {new.n_worlds} of world {args.world} from t_min = {new.refine_time[0]:.4f} s"
        f" (ids {ids}, seed {seed}; {int(new.valid.sum())} valid)")
  print(f"active objects      {min(active)}..{max(active)} per world (asked: {args.objects or 'none'})")
  for world_id, message in stats.sim_errors[:5]:  # the flag is in the bank; the first few messages here
    print(f"mwbx: refined world {saved[int(world_id - new.world_ids[0])]} stopped by a MuJoCo error:"
          f" {message.splitlines()[0] if message else '(no message)'}", file=sys.stderr)
  if args.add or args.remove:
    print(f"scene changes       added: {args.add or 'none'}; removed: {args.remove or 'none'}"
          f" (scene version {int(new.scene_version[0])})")
  print(f"world-steps/s       {stats.world_steps_per_second:,.0f} ({stats.backend};"
        f" {stats.world_steps:,} steps in {stats.run_seconds:.2f} s, compile {stats.compile_seconds:.1f} s,"
        f" compression {stats.codec_seconds:.1f} s, contact events {stats.events_seconds:.1f} s)")
  print(f"bank                {out} ({total.n_worlds} worlds, {total.nbytes / 1e6:.1f} MB in memory)")
  return 0


DEFAULT_SOLVE_REFINEMENTS = 100  # `mwbx solve` without --budget, --time-budget or --step-budget


def _solve_budget(args, budget_type):
  """The search's budget from ``mwbx solve``'s flags: a time or step budget
  given alone is the limit (no default refinement count cuts it short)."""
  refinements = args.budget
  if refinements is None and args.time_budget is None and args.step_budget is None:
    refinements = DEFAULT_SOLVE_REFINEMENTS
  return budget_type(refinements=refinements, seconds=args.time_budget,
                     world_steps=None if args.step_budget is None else int(args.step_budget))


def _cmd_solve(args) -> int:
  from mwbx.search import Budget, SolveInterrupted, progress_plot, solve  # lazy: optax
  bank = _load_bank(args)
  queries = mwbx.load_queries(args.queries, bank=bank)
  # SolveOptions' fields by name: solve() checks the goal first, then them.
  options = dict(budget=_solve_budget(args, Budget), key=jax.random.key(args.seed), samples=args.samples,
                 keep=args.keep, tries_per_world=args.tries, patience=args.patience, backend=args.backend,
                 guided_rounds=args.guided_rounds, guided_batch=args.guided_batch, reseed_rounds=args.reseed_rounds)
  interrupted = False
  try:
    with _reporter_with_safe_points("solve") as update:
      result = solve(bank, queries, progress=update, **options)
  except SolveInterrupted as stop:  # Ctrl-C: the refinements done are kept, as sampling keeps its chunks
    result, interrupted = stop.result, True
  out = pathlib.Path(args.out or args.bank)
  before = set(bank.world_ids.tolist())
  new = [(int(i), int(p)) for i, p in zip(result.bank.world_ids.tolist(), result.bank.parent_world.tolist())
         if int(i) not in before]
  if interrupted and not new:
    print("mwbx: interrupted before a refinement finished; nothing was written", file=sys.stderr)
    return 130
  print(f"mwbx: saving {result.bank.n_worlds} worlds to {out}", file=sys.stderr)
  saved = result.bank.save(out)  # the new worlds' ids on disk (another process may have taken theirs meanwhile)
  result = result._replace(bank=saved, world=saved.origin.id_on_disk(result.world))
  plot = pathlib.Path(args.plot) if args.plot else out.parent / f"{out.name}-solve.png"
  plot.parent.mkdir(parents=True, exist_ok=True)
  progress_plot(result.steps, plot, title=f"mwbx solve {pathlib.Path(args.queries).name}")
  history = plot.with_suffix(".json")
  history.write_text(json.dumps({"message": result.message, "world": result.world, "solved": result.solved,
                                 "steps": [s._asdict() for s in result.steps]}, indent=1))
  if interrupted:
    refined = [saved.origin.id_on_disk(i) for i, parent in new if parent >= 0]
    spans = ", ".join(f"{a}..{b}" if b > a else f"{a}" for a, b in runs.id_ranges(refined)) or "none"
    guided = len(new) - len(refined)
    print(f"mwbx: interrupted after {result.steps[-1].refinements} refinements; kept {len(refined)} refined worlds"
          f" (ids {spans}){f' and {guided} guided worlds' if guided else ''} in {out}; best world so far"
          f" {result.world} ({result.satisfied} of {result.n_queries} queries met)", file=sys.stderr)
    return 130
  lineage = [int(i) for i in result.bank.ancestors(result.world)][::-1] + [result.world]
  print(result.message)
  if result.advice:
    print(textwrap.fill(result.advice, width=100))
  print(f"world               {result.world} ({result.satisfied} of {result.n_queries} queries;"
        f" lineage {' -> '.join(str(i) for i in lineage)})")
  print(f"bank                {out} ({result.bank.n_worlds} worlds)")
  print(f"progress            {plot} and {history.name}")
  return 0 if result.solved else 1


def _cmd_drop(args) -> int:
  bank = _load_bank(args)
  ids = parse_world_ids(args.ids, flag="IDS", known=bank.world_ids)
  kept = bank.drop(ids)
  out = pathlib.Path(args.out or args.bank)
  kept = kept.save(out)
  dropped = ", ".join(f"{lo}..{hi}" if hi > lo else str(lo) for lo, hi in runs.id_ranges(ids))
  print(f"dropped worlds      {dropped}")
  print(f"bank                {out} ({kept.n_worlds} worlds, ids {_id_span(kept)})")
  return 0


def _cmd_browse(args) -> int:
  from mwbx.browser import browse  # lazy: viser
  from mwbx.browser.guard import resolve_host  # lazy: the browser package loads viser
  bank = _load_bank(args)
  resolve_host(args.host, flag="--host")  # first here, so that a bad one is named by its flag
  browse(bank, path=args.bank, host=args.host, port=args.port, open_browser=not args.no_browser,
         workdir=args.workdir, autosave=args.autosave)
  return 0


def _cmd_export(args) -> int:
  # lazy: mwbx.export brings the viewer's kinematics and framing, and usd-core / imageio-ffmpeg on first call
  from mwbx.export import export_npz, export_usd, render_video
  from mwbx.export import target  # lazy: with mwbx.export above
  from mwbx.export.poses import clip_frames  # lazy: with mwbx.export above
  from mwbx.export.video import check_fps, check_size, free_camera, gl_backend_name  # lazy: as above
  # Every flag checked before anything is written: a bad one leaves no file behind.
  if not (args.usd or args.mp4 or args.npz):
    raise MwbxError("export: name at least one file to write: --usd FILE, --mp4 FILE or --npz FILE")
  if args.camera is not None and args.look_at is not None:
    raise MwbxError("export: give --camera or --look-at, not both")
  if not args.mp4 and (args.camera is not None or args.look_at is not None):
    raise MwbxError(f"{'--camera' if args.camera is not None else '--look-at'}: places the video's camera;"
                    f" give it with --mp4 FILE")
  # Each file: its suffix, nothing special at its name (a symlink, FIFO, device), a folder that takes it.
  for kind in ("npz", "usd", "mp4"):
    if getattr(args, kind):
      target.check_target(getattr(args, kind), kind, flag=f"--{kind}")
      target.check_folder(getattr(args, kind), flag=f"--{kind}")
  if args.mp4:
    check_size(args.width, args.height, prefix="--")  # the bank's MJCF may allow more: checked again below
    check_fps(30.0 if args.fps is None else args.fps, prefix="--")
    gl_backend_name()  # a bad MUJOCO_GL is named before anything is written
  look_at = None
  if args.look_at is not None:
    look_at = (args.look_at[:3], args.look_at[3:])
    try:
      free_camera(*look_at)
    except MwbxError as err:
      raise MwbxError(f"--look-at: {str(err).split(': ', 1)[-1]}") from None
  bank = _load_bank(args)
  n_frames = int(bank.frame_count[bank.row_of(args.world)])  # names an id the bank does not hold
  if args.mp4:
    check_size(args.width, args.height, bank.model, prefix="--")  # up to the MJCF's offscreen buffer
  if args.camera is not None and mujoco.mj_name2id(bank.model, mujoco.mjtObj.mjOBJ_CAMERA, args.camera) < 0:
    model = bank.model
    names = [model.camera(c).name for c in range(model.ncam) if model.camera(c).name]
    raise MwbxError(f"--camera: no camera {args.camera!r} in the MJCF (have: {', '.join(names) or 'none'})")
  video_fps = 30.0 if args.fps is None else args.fps
  # Each file's clip (recorded frames shown), which also checks --fps, --start and --stop.
  rates = {"npz": None, "usd": args.fps, "mp4": video_fps}
  try:
    clips = {kind: clip_frames(max(n_frames, 1), float(bank.record_fps), rates[kind], args.start, args.stop)[0]
             for kind in rates if getattr(args, kind)}
  except MwbxError as err:  # named as the flags are
    raise MwbxError(f"--{err}" if str(err).startswith(("fps:", "start:", "stop:")) else str(err)) from None
  with _reporter_with_safe_points("export") as update:
    for kind in ("npz", "usd", "mp4"):
      if not getattr(args, kind):
        continue
      if kind == "npz":
        path = export_npz(bank, args.world, args.npz, start=args.start, stop=args.stop)
      elif kind == "usd":
        path = export_usd(bank, args.world, args.usd, fps=args.fps, start=args.start, stop=args.stop,
                          progress=update)
      else:
        path = render_video(bank, args.world, args.mp4, camera=args.camera, look_at=look_at, width=args.width,
                            height=args.height, fps=video_fps, start=args.start, stop=args.stop, progress=update)
      fps = bank.record_fps if rates[kind] is None else rates[kind]
      size = pathlib.Path(path).stat().st_size
      print(f"wrote {path} (world {args.world}, {len(clips[kind])} frames at {fps:g} fps, {_file_size(size)})")
  return 0


def _file_size(n: int) -> str:
  """A file's size for people: kB below a megabyte, else MB."""
  return f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.1f} kB"


def build_parser() -> argparse.ArgumentParser:
  parser = argparse.ArgumentParser(prog="mwbx", description="Many-Worlds Browsing on JAX and MuJoCo.")
  parser.add_argument("--version", action="version", version=f"mwbx {__version__}")
  sub = parser.add_subparsers(dest="command", required=True)
  _add_sample(sub)
  _add_info(sub)
  _add_query(sub)
  _add_view(sub)
  _add_refine(sub)
  _add_solve(sub)
  _add_drop(sub)
  _add_browse(sub)
  _add_export(sub)
  return parser


def _skip_corrupt(p) -> None:
  """The flag every command that opens a bank takes."""
  p.add_argument("--skip-corrupt", action="store_true",
                 help="open the bank without its corrupt shards (named on stderr)")


def _add_sample(sub) -> None:
  """`mwbx sample CONFIG`: sample worlds into a bank, alone or with other processes."""
  p = sub.add_parser("sample", help="sample worlds of a config into a bank")
  p.add_argument("config", help="YAML config (e.g. configs/quickstart.yaml)")
  p.add_argument("--num-processes", type=int, default=None, metavar="N",
                 help="processes (hosts) sampling this run together, each its share of the worlds")
  p.add_argument("--process-id", type=int, default=None, metavar="I", help="this process, 0..N-1")
  p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                 help="process 0's address, where the processes agree on the run")
  p.add_argument("--distributed", action="store_true",
                 help="let jax.distributed.initialize() find the processes (Slurm, MPI)")
  p.add_argument("--timeout", type=int, default=300, metavar="S",
                 help="seconds to wait for the other processes (default 300)")
  p.add_argument("--worlds", type=int, default=None, help="worlds to sample (default 256)")
  p.add_argument("--seed", type=int, default=None, help="run seed (default 0, or the bank's)")
  p.add_argument("--backend", choices=("auto", "mjx", "native"), default=None)
  p.add_argument("--chunk-size", type=int, default=None, help="worlds per chunk (simulated and compressed together)")
  p.add_argument("--out", default=None, help="bank directory; an existing bank is continued")
  p.set_defaults(func=_cmd_sample)


def _add_info(sub) -> None:
  """`mwbx info BANK`: summarize a bank."""
  p = sub.add_parser("info", help="summarize a bank")
  p.add_argument("bank")
  p.add_argument("--json", action="store_true")
  p.add_argument("--verify", action="store_true",
                 help="check every shard's checksums (opening reads only the small arrays); with"
                      " --skip-corrupt: name every corrupt shard, summarize the rest, exit 1")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_info)


def _add_query(sub) -> None:
  """`mwbx query BANK QUERIES`: match and rank worlds."""
  p = sub.add_parser("query", help="find worlds of a bank with screen-box, whole-geometry, joint and "
                                   "orientation queries (docs/queries.md) and rank them")
  p.add_argument("bank", help="bank directory")
  p.add_argument("queries", help="query YAML (e.g. configs/queries/quickstart.yaml)")
  p.add_argument("--rank", default=None, metavar="METRIC[:sum|max]",
                 help="rank matches by a metric summed or maxed over all tracked bodies")
  p.add_argument("--top", type=int, default=None, help="list at most K worlds")
  p.add_argument("--under", type=int, default=None, metavar="ID",
                 help="only world ID and the worlds refined from it (directly or not)")
  p.add_argument("--json", action="store_true")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_query)


def _add_view(sub) -> None:
  """`mwbx view BANK`: meshcat playback or standalone HTML."""
  p = sub.add_parser("view", help="show worlds, paths and queries in meshcat (or write HTML)")
  p.add_argument("bank")
  p.add_argument("--worlds", default=None, help="world ids to play back, e.g. 3,17")
  p.add_argument("--top", type=int, default=None,
                 help="play back the best K worlds by --rank (or the query file's rank; else the first K matching)")
  p.add_argument("--rank", default=None, help="metric to rank by, NAME[:sum|max]")
  p.add_argument("--queries", default=None, help="query file (YAML): frustums drawn, paths coloured")
  p.add_argument("--paths", default="all", help="COM paths: all, none, or body/object/group names a,b")
  p.add_argument("--layout", choices=("overlay", "grid"), default="overlay")
  p.add_argument("--camera", default=None, help="MJCF camera to view from (default: fit the scene)")
  p.add_argument("--html", default=None, help="write one standalone HTML file instead of serving")
  p.add_argument("--zmq-url", default=None, help="draw into a running meshcat server")
  p.add_argument("--no-browser", action="store_true", help="only print the URL")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_view)


def _add_refine(sub) -> None:
  """`mwbx refine BANK --world ID`: resample objects of one world from t_min on."""
  p = sub.add_parser("refine", help="resample chosen objects of one world from a time or a screen box on")
  p.add_argument("bank", help="bank directory")
  p.add_argument("--world", type=int, required=True, help="id of the world to refine")
  p.add_argument("--objects", default=None, help="objects or groups to refine, e.g. ball_0,cubes")
  p.add_argument("--scene", default=None, metavar="NEW.yaml",
                 help="a later version of the bank's scene (its objects first, then new ones) to add objects from")
  p.add_argument("--add", default=None, metavar="NAMES", help="objects of --scene to insert at t_min")
  p.add_argument("--remove", default=None, metavar="NAMES", help="objects to take out at t_min (their ghosts stay)")
  p.add_argument("--box", default=None, help="screen box u0,v0,u1,v1 (normalised, origin top-left)")
  p.add_argument("--camera", default=None, help="MJCF camera the box is drawn in")
  p.add_argument("--time", type=float, default=None, help="t_min in seconds (instead of --box)")
  p.add_argument("--samples", type=int, required=True, help="refined worlds to make")
  p.add_argument("--seed", type=int, default=None, help="refinement seed (default: a new one, printed)")
  p.add_argument("--backend", choices=("auto", "mjx", "native"), default=None)
  p.add_argument("--out", default=None, help="bank directory to write (default: BANK, as a new step)")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_refine)


def _add_solve(sub) -> None:
  """`mwbx solve BANK QUERIES`: search refinements until every query is met."""
  p = sub.add_parser("solve", help="search refinements for a world that meets every query, unattended")
  p.add_argument("bank", help="bank directory")
  p.add_argument("queries", help="query YAML: the goal (every query met)")
  p.add_argument("--budget", type=int, default=None, metavar="N",
                 help="refinements at most (default 100 when no other budget is given)")
  p.add_argument("--time-budget", type=float, default=None, metavar="S",
                 help="wall seconds at most (alone: no refinement limit)")
  p.add_argument("--step-budget", type=float, default=None, metavar="N", help="world-steps at most")
  p.add_argument("--samples", type=int, default=32, help="refined worlds per refinement (default 32)")
  p.add_argument("--keep", type=int, default=4, help="children kept per refinement (default 4)")
  p.add_argument("--tries", type=int, default=4, help="refinements from one world at most (default 4)")
  p.add_argument("--patience", type=int, default=40,
                 help="refinements without progress before guided reseeding (default 40)")
  p.add_argument("--guided-rounds", type=int, default=0, metavar="R",
                 help="batches of guided sampling added before the search (default 0)")
  p.add_argument("--guided-batch", type=int, default=64, metavar="M", help="worlds per guided batch")
  p.add_argument("--reseed-rounds", type=int, default=4, metavar="R",
                 help="at a stall, guided batches aimed at the query refinements meet least (default 4; 0: none)")
  p.add_argument("--seed", type=int, default=0, help="search seed (default 0: repeatable)")
  p.add_argument("--backend", choices=("auto", "mjx", "native"), default=None)
  p.add_argument("--out", default=None, help="bank directory to write (default: BANK, as a new step)")
  p.add_argument("--plot", default=None, help="progress plot PNG (default: BANK-solve.png next to the bank)")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_solve)


def _add_drop(sub) -> None:
  """`mwbx drop BANK IDS`: remove worlds."""
  p = sub.add_parser("drop", help="remove worlds from a bank (their ids are never reused)")
  p.add_argument("bank", help="bank directory")
  p.add_argument("ids", help="world ids, e.g. 260,261")
  p.add_argument("--out", default=None, help="bank directory to write (default: BANK, as a new step)")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_drop)


def _add_browse(sub) -> None:
  """`mwbx browse BANK`: the interactive page."""
  p = sub.add_parser("browse", help="browse a bank in the browser: draw boxes, sort, play, refine")
  p.add_argument("bank", help="bank directory")
  p.add_argument("--port", type=int, default=None, help="port to serve on (default: a free one)")
  p.add_argument("--host", default="127.0.0.1", help="address to serve on (not loopback: a warning)")
  p.add_argument("--workdir", default=None, help="directory the page reads and writes query files in"
                 " (default: BANK)")
  p.add_argument("--autosave", action="store_true", help="on Ctrl-C, save the worlds refined on the page")
  p.add_argument("--no-browser", action="store_true", help="only print the URL")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_browse)


def _add_export(sub) -> None:
  """`mwbx export BANK --world ID`: one world as USD, mp4 and/or npz (docs/export.md)."""
  p = sub.add_parser("export", help="write one world as a USD stage, an mp4 or an npz (docs/export.md)")
  p.add_argument("bank", help="bank directory")
  p.add_argument("--world", type=int, required=True, metavar="ID", help="id of the world to export")
  p.add_argument("--usd", default=None, metavar="FILE",
                 help="USD stage with time-sampled body poses: .usda (text), .usd or .usdc (binary)")
  p.add_argument("--mp4", default=None, metavar="FILE",
                 help="H.264 video (MuJoCo's offscreen renderer; OpenGL backend from MUJOCO_GL: egl, osmesa, glfw)")
  p.add_argument("--npz", default=None, metavar="FILE",
                 help="decoded qpos and every body's pose, every recorded frame (.npz)")
  p.add_argument("--fps", type=float, default=None, metavar="F",
                 help="USD samples and video frames per second (default: USD every recorded frame, video 30;"
                      " video 1 to 1000); the npz keeps every recorded frame")
  p.add_argument("--start", type=float, default=0.0, metavar="S", help="from this time on, s (default 0)")
  p.add_argument("--stop", type=float, default=None, metavar="S", help="up to this time, s (default: the end)")
  p.add_argument("--camera", default=None, metavar="NAME", help="MJCF camera the video is rendered from")
  p.add_argument("--look-at", type=float, nargs=6, default=None, metavar=("EX", "EY", "EZ", "TX", "TY", "TZ"),
                 help="video camera at eye EX EY EZ looking at target TX TY TZ, m (instead of --camera;"
                      " neither: the viewer's first view)")
  p.add_argument("--width", type=int, default=1280,
                 help="video width, pixels, even, at most 8192 or the MJCF's offwidth (default 1280)")
  p.add_argument("--height", type=int, default=720,
                 help="video height, pixels, even, at most 8192 or the MJCF's offheight (default 720)")
  _skip_corrupt(p)
  p.set_defaults(func=_cmd_export)


def _enable_compilation_cache() -> None:
  """Keeps compiled kernels on disk, so a second ``mwbx`` run skips compiling."""
  cache = os.environ.get("MWBX_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "mwbx", "jax"))
  try:
    os.makedirs(cache, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", cache)
    # Every kernel, not only those that took a second to compile (JAX's
    # default): a fresh `mwbx query` compiled five small ones each time
    # (0.65 s of XLA on the tower's query file).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
  except OSError:
    pass  # a read-only home: compile every time


def _terminate(signum, frame):
  raise KeyboardInterrupt  # SIGTERM ends like Ctrl-C: servers stopped, nothing half-written


def _quiet_unraisable(unraisable) -> None:
  """Drops the 'Event loop is closed' that tensorstore's threads raise after a
  failed bank restore (the one-line error already said what happened)."""
  exc = unraisable.exc_value
  if isinstance(exc, RuntimeError) and "Event loop is closed" in str(exc):
    return
  sys.__unraisablehook__(unraisable)


def main(argv: list[str] | None = None) -> int:
  args = build_parser().parse_args(argv)
  sys.unraisablehook = _quiet_unraisable
  notices_to_stderr()  # what a bank or a page has to say once
  _enable_compilation_cache()
  previous = signal.signal(signal.SIGTERM, _terminate)
  try:
    return args.func(args)
  except MwbxError as err:
    hint = ("; --skip-corrupt opens the bank without the corrupt shard"
            if "corrupt" in str(err) and getattr(args, "skip_corrupt", True) is False else "")
    print(f"mwbx: error: {err}{hint}", file=sys.stderr)
    return 2
  except KeyboardInterrupt:
    print("mwbx: interrupted; nothing was written for the unfinished run", file=sys.stderr)
    return 130
  except BrokenPipeError:  # e.g. `mwbx info --json | head`: the reader left
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
    return 0
  finally:
    signal.signal(signal.SIGTERM, previous)


def run() -> None:
  """The ``mwbx`` command: :func:`main` in a process of its own."""
  # The imported modules' objects (jax, MuJoCo, numba: millions) live as long as the
  # process: frozen, no collection walks them again, nor Python's at exit (0.6 s a command).
  gc.freeze()
  sys.exit(main())


if __name__ == "__main__":
  run()
