"""docs/benchmarks.md and the README's headline figures, from out/bench/*.json.

Figures are never typed by hand: each `scripts/bench_*.py` writes JSON with the
machine it ran on, and this script turns whatever JSON is there into tables.
It also copies the JSON to docs/bench/ so the committed figures keep their
source. Usage:

  .venv/bin/python scripts/make_benchmarks_doc.py [--bench out/bench]
"""

from __future__ import annotations

import argparse
import json
import statistics
import pathlib
import re
import shutil

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
HEADLINE = re.compile(r"(<!-- headline figures: generated -->\n).*?(<!-- end of generated figures -->)", re.S)


def _load(bench: pathlib.Path, name: str) -> dict | None:
  path = bench / f"{name}.json"
  return json.loads(path.read_text()) if path.exists() else None


def _n(x: float, digits: int = 3) -> str:
  return f"{x:,.0f}" if abs(x) >= 1000 else f"{x:.{digits}g}"


def sampler(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Sampler", "",
           "`scripts/bench_sampler.py`: in one run and from the same randomized initial states, "
           "(a) a Python loop of `mujoco.mj_step`, (b) bare `mujoco.rollout` without perturbations "
           "(one call, all steps, a thread per core), (g) the same with MuJoCo's profiling timers off "
           "as mwbx steps (MuJoCo 4 otherwise reads the clock about 30 times a step to fill `MjData.timer`), "
           "(c) bare MJX stepping, (d) the mwbx sampler "
           "on the native backend (its stepping), (e) the mwbx sampler on MJX, (f) the whole of (d)'s "
           "`Sampler.run` on the wall clock (stepping, compression, the bank assembled). The baselines step "
           "the MJCF as written, without the sensors mwbx adds. Repeats alternate; each keeps its best.", "",
           f"Machine: {d['machine']}, MuJoCo {d['mujoco']}.", "",
           "| scene | what | batch | world-steps/s |", "|---|---|---:|---:|"]
  head = []
  for scene, s in d["scenes"].items():
    for r in s["rows"]:
      lines.append(f"| {scene} | ({r['key']}) {r['what']} | {r['batch']} | {r['world_steps_per_s']:,.0f} |")
  lines += ["", "| scene | (d)/(b) | (d)/(a) | (e)/(c) | native own cost (thread time outside `mj_step`) |",
            "|---|---:|---:|---:|---:|"]
  for scene, s in d["scenes"].items():
    ratios = s["ratios"]
    d_row = next(r for r in s["rows"] if r["key"] == "d")
    own = d_row.get("overhead_over_physics")
    lines.append(f"| {scene} | {ratios['d_over_b']:.2f} | {ratios['d_over_a']:.2f} | "
                 f"{ratios['e_over_c']:.2f} |" if "e_over_c" in ratios else
                 f"| {scene} | {ratios['d_over_b']:.2f} | {ratios['d_over_a']:.2f} | – |")
    lines[-1] += f" {own:.1%} |" if own is not None else " – |"
    head.append(f"{scene} {ratios['d_over_b']:.2f}× bare `mujoco.rollout` and "
                f"{ratios['d_over_a']:.2f}× a Python `mj_step` loop")
  walls = []
  for scene, s in d["scenes"].items():
    f = next((r for r in s["rows"] if r["key"] == "f"), None)
    if f is not None:
      against_g = f", {s['ratios']['f_over_g']:.2f}× (g)" if "f_over_g" in s["ratios"] else ""
      walls.append(f"{scene} {s['ratios']['f_over_b']:.2f}× (b){against_g} ({f['wall_s']:.2f} s wall: stepping "
                   f"{f['stepping_s']:.2f} s and {f['wall_s'] - f['stepping_s']:.2f} s after it; compression "
                   f"{f['codec_s']:.2f} thread-seconds, most of them beside the stepping)")
  if walls:
    lines += ["", f"The whole `Sampler.run`, (f)/(b): {'; '.join(walls)}. Worlds that finish early are "
              "compressed while the others still step (so stepping and compression share the two cores, and "
              "the compression seconds are its thread's, overlapped); what is left to win is compression's "
              "own cost (the fit is compiled, `mwbx/codec/fit_kernels.py`) and the loop's bookkeeping. "
              "Against (g), the baseline that also skips MuJoCo's timers, the ratio is what the sampler's "
              "own work costs."]
  lines += ["", "MJX on CPU is for checking, not speed: its figures come from short runs of small "
            "batches. Compile time is kept apart from every rate."]
  return lines, [f"**sampling** (native): {'; '.join(head)}"]


def codec(d: dict) -> tuple[list[str], list[str]]:
  b = d["bounds"]
  lines = ["## Codec", "",
           "`scripts/bench_codec.py`: sampled quickstart and pachinko banks (raw `qpos` kept for "
           "the comparison), simulated free boxes and an articulated chain; every world compressed "
           "on its own at the same ℓ∞ bound by each method. A body-frame is one tracked body for "
           f"one frame. Bounds: {b['e_pos'] * 1e3:g} mm, {b['e_rot'] * 57.29577951308232:.3g}°. "
           "Decoding is timed as the best of several tries, baseline included.", "",
           f"Machine: {d['machine']} ({d['cpu_count']} cores).", ""]
  head = []
  for name, r in d["data"].items():
    lines += [f"**{name}** ({r['worlds']} worlds, {r['body_frames']:,} body-frames)", "",
              "| method | bytes | × smaller than float32 | bits / body-frame | max error (mm) | max error (°) |",
              "|---|---:|---:|---:|---:|---:|"]
    for method, m in r["rows"].items():
      label = f"**{method}**" if method == "mwbx codec" else method
      lines.append(f"| {label} | {m['bytes']:,} | {m['ratio_vs_float32']:.1f} | "
                   f"{m['bits_per_body_frame']:.2f} | {1e3 * m['max_error_pos_m']:.3f} | "
                   f"{m['max_error_rot_deg']:.3f} |")
    c, base = r["codec"], r["quant+delta2+zstd speed"]
    lines += ["", f"Codec vs the best baseline ({r['best_baseline']}): **{r['gain_vs_best_baseline']:.2f}× "
              f"smaller**. Encode {c['encode_body_frames_per_s'] / 1e6:.2f} M body-frames/s (baseline "
              f"{base['encode_body_frames_per_s'] / 1e6:.2f}); decode of all worlds "
              f"{c['decode_body_frames_per_s'] / 1e6:.2f} M body-frames/s (baseline "
              f"{base['decode_body_frames_per_s'] / 1e6:.2f}); one world {c['decode_one_world_ms']:.2f} ms.", ""]
    if name in ("quickstart", "pachinko"):
      codec_row = r["rows"]["mwbx codec"]
      head.append(f"{name} {codec_row['ratio_vs_float32']:.1f}× smaller than float32 and "
                  f"{r['gain_vs_best_baseline']:.2f}× smaller than {r['best_baseline']}, max error "
                  f"{1e3 * codec_row['max_error_pos_m']:.3f} mm / {codec_row['max_error_rot_deg']:.3f}°")
  for config, t in d["sampling"].items():
    lines.append(f"`mwbx sample` {config}, compiled: raw store {t['sample_raw_s']:.2f} s, compressed "
                 f"{t['sample_codec_s']:.2f} s; codec {t['codec_s']:.2f} s = "
                 f"{100 * t['codec_share_of_wall']:.1f} % of the wall time.")
  lines += ["", "![rate-distortion](bench/codec_rd.png)", "",
            "*Bits per channel-frame against the bound, as in the paper's Fig. 3.*"]
  return lines, [f"**codec**: {'; '.join(head)}"]


def queries(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Queries", "",
           "`scripts/bench_queries.py`: include, exclude and include-any-of-16-bodies boxes on "
           "synthetic ballistic paths, plus a real quickstart bank with the example queries. "
           "Baselines in the same run: brute force over every segment in numpy and in one jitted "
           "JAX kernel. \"same\": mwbx's answers equal both brute-force ones.", "",
           f"Machine: {d['machine']}, jax {d['jax']}, load average {d['load_average'][0]:.1f}.", "",
           "| bank | W | B | P | segments | query | matches | mwbx ms | numpy ms | jax brute ms | vs numpy | same | rank ms |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---|---:|"]
  for r in d["rows"]:
    lines.append(f"| {r['bank']} | {r['worlds']} | {r['bodies']} | {r['points']} | {r['segments']:,} | "
                 f"{r['query']} | {r['matches']} | {r['mwbx_ms']:.1f} | {r['numpy_ms']:.0f} | "
                 f"{r['jax_brute_ms']:.0f} | {r['speedup_vs_numpy']:.0f}× | "
                 f"{'yes' if r['identical'] else 'NO'} | {r['rank_ms']:.2f} |")
  largest = max(r["segments"] for r in d["rows"])
  big = [r for r in d["rows"] if r["segments"] == largest]
  same = all(r["identical"] for r in d["rows"])
  head = (f"**queries**: {largest / 1e6:.1f} M segments in {min(r['mwbx_ms'] for r in big):.1f}–"
          f"{max(r['mwbx_ms'] for r in big):.1f} ms per query, {min(r['speedup_vs_numpy'] for r in big):.0f}×+ "
          f"brute-force numpy, answers {'identical' if same else 'NOT identical'}")
  return lines, [head]


def viewer(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Viewer", "", "`scripts/bench_viewer.py`: building animations and path scenes against "
           "meshcat's own API, and rendering them in headless Chromium (software WebGL).", "",
           f"Machine: {d['machine']}.", "",
           "| measurement | case | mwbx | baseline | ratio |", "|---|---|---:|---:|---:|"]
  for key in ("animation", "paths"):
    r = d[key]
    lines.append(f"| {key} build | {r['case']} | {r['mwbx_s']:.3f} s | {r['baseline_s']:.3f} s "
                 f"({r['baseline']}) | {r['speedup']:.1f}× |")
  head = [f"**viewer**: paths built {d['paths']['speedup']:.0f}× faster than one meshcat `Line` per polyline"]
  if "browser" in d:
    b = d["browser"]
    lines.append(f"| browser frame | {b['case']} | {b['mwbx']['ms_per_frame']:.1f} ms, "
                 f"{b['mwbx']['draw_calls']} draw calls | {b['baseline']['ms_per_frame']:.1f} ms, "
                 f"{b['baseline']['draw_calls']} draw calls | {b['speedup']:.0f}× |")
    head[0] += f", drawn {b['speedup']:.0f}× faster per browser frame"
  e = d["export"]
  lines.append(f"| export_html | {e['case']} | {e['export_html_s']:.2f} s, {e['html_mb']:.1f} MB | | |")
  return lines, head


def refinement(d: dict) -> tuple[list[str], list[str]]:
  s, r, span = d["sample"], d["refine"], d["span_sampling"]
  lines = ["## Refinement", "",
           "`scripts/bench_refine.py`: sample N worlds, then refine the object of one world that "
           "still moves most after mid-way into N new worlds (same backend and batch). Second "
           "baseline: plain sampling of the same time span from the parent's state at t_min. "
           "Warmed up; compile time never counted; runs interleaved, fastest kept.", "",
           f"Machine: {d['machine']}; {d['config']}, {d['worlds']} worlds, {d['backend']}; refining "
           f"`{d['object']}` of world {d['parent']} ({d['parent_frames']} frames) from t_min = "
           f"{d['t_min_s']:.3f} s; {r['mean_active_objects']:.1f} objects active per refined world on "
           f"average (at most {r['max_active_objects']}).", "",
           "| | whole worlds from scratch | plain sampling from t_min | refinement from t_min |",
           "|---|---:|---:|---:|",
           f"| world-steps | {s['world_steps']:,} | {span['world_steps']:,} | {r['world_steps']:,} |",
           f"| stepping time, s | {s['run_s']:.2f} | {span['run_s']:.2f} | {r['run_s']:.2f} |",
           f"| µs per world-step | {s['us_per_world_step']:.1f} | {span['us_per_world_step']:.1f} | "
           f"{r['us_per_world_step']:.1f} |",
           f"| refinement's cost per step relative to it | {d['step_cost_ratio']:.2f} | "
           f"{d['step_cost_ratio_same_span']:.2f} | 1 |", "",
           f"Largest applied perturbation: {r['max_perturbation_ratio']:.3f} α‖Δv‖."]
  for key, label in (("refine_lockstep", "Lockstep rollout loop (`loop=\"lockstep\"`, the loop the compiled one "
                                         "replaced)"),
                     ("refine_frame_playback", "Lockstep with frame-boundary playback")):
    fp = d.get(key)
    if fp:
      lines.append(f"{label}: {fp['us_per_world_step']:.1f} µs per world-step "
                   f"({fp['step_cost_ratio']:.2f}× whole worlds, {fp['step_cost_ratio_same_span']:.2f}× "
                   "the same span).")
  cases = d.get("cases", [])
  if cases and "activation" in cases[0]:
    lines += ["", "Per case (the compiled loop; *exact*: the objects `mwbx.refinement.exact_active` activates, "
              "MuJoCo's geom distance with the same margin at every stored frame; interactive: "
              f"{d['worlds']} refined worlds, warm, compression included):", "",
              "| refined object | active objects (sphere test) | exact test | ratio | never fewer | "
              "cost per step vs the same span | vs the lockstep loop | wall | first world done |",
              "|---|---:|---:|---:|---|---:|---:|---:|---:|"]
    for c in cases:
      a, rr = c["activation"], c["refine"]
      lock = c.get("refine_lockstep")
      lines.append(
          f"| `{c['object']}` | {np.mean(a['sphere_active']):.2f} | {np.mean(a['exact_active']):.2f} | "
          f"{a['ratio_mean']:.2f} | {'yes' if a['never_fewer'] else '**no**'} | "
          f"{c['step_cost_ratio_same_span']:.2f} | "
          f"{(lock['run_s'] / rr['run_s']) if lock else float('nan'):.2f}× faster | {rr['wall_s']:.2f} s | "
          f"{rr['first_world_s']:.2f} s |")
  head = [f"**refinement**: {d['step_cost_ratio_same_span']:.2f}× the cost per step of plain sampling "
          f"over the same span, {d['speedup_wall']:.2f}× faster than sampling whole worlds (wall)"]
  few = [c for c in cases[1:] if "activation" in c]
  if few:
    c = few[0]
    head[0] += (f"; {c['step_cost_ratio_same_span']:.2f}× with {np.mean(c['activation']['sphere_active']):.0f} "
                f"object active; {d['worlds']} refined worlds in {d['refine']['wall_s']:.2f} s wall")
  return lines, head


def solve(d: dict) -> tuple[list[str], list[str]]:
  m = d["machine"]
  lines = ["## Solve", "",
           "`scripts/bench_solve.py`: `mwbx.solve` searching the refinement tree unattended "
           "([search](search.md)), and guided sampling against plain sampling. "
           f"Machine: {m['cpus']}-core {m['machine']} CPU, no GPU ({m['backend']}); commit {m['commit']}; "
           f"load average {m['load_average']:.1f} at the start.", ""]
  head = []
  rows = [d[k] for k in ("siggraph", "staircase") if k in d]
  part_commits = [f"{r['scene']} at {r['machine']['commit']} (load {r['machine']['load_average']:.1f})"
                  for r in rows if "machine" in r]
  if isinstance(d.get("guided"), dict) and "machine" in d["guided"]:
    g = d["guided"]["machine"]
    part_commits.append(f"guided at {g['commit']} (load {g['load_average']:.1f})")
  if part_commits:
    lines[-2] = lines[-2].split(" Machine:")[0] + (f" Machine: {m['cpus']}-core {m['machine']} CPU, no GPU "
                                                  f"({m['backend']}); measured " + ", ".join(part_commits) + ".")
  if rows:
    lines += ["| scene | sampled | valid | best sampled | plain-sampling estimate | budget | result | "
              "refinements | world-steps | wall (sample + solve) |",
              "|---|---:|---:|---:|---:|---:|---|---:|---:|---:|"]
    for r in rows:
      result = "all met" if r["solved"] else f"{r['satisfied']} of {r['n_queries']} met"
      estimate = (f"{r['independent_estimate']:.1e} per world" if r["independent_estimate"] > 0 else
                  f"below 1 in {r['valid']} (a query no sampled world meets)")
      lines.append(f"| {r['scene']} | {r['worlds_sampled']} | {r['valid']} | {r['sampled_best_met']} of "
                   f"{r['n_queries']} | {estimate} | {r['budget_seconds']:.0f} s | "
                   f"{result} | {r['refinements']} | {r['world_steps']:,} | {r['wall_seconds']:.0f} s |")
    lines += [""] + [f"![{r['scene']} solve progress](bench/{r['plot']})" for r in rows] + [""]
    for r in rows:
      lines.append(f"* {r['scene']}: {r['message']}")
    lines.append("")
    s = d.get("siggraph")
    if s:
      reached = next(t for t, _, met in s["curve"] if met == s["satisfied"])
      head.append(f"spelling SIGGRAPH unattended: {s['satisfied']} of 8 letters in their slots after "
                  f"{reached / 60:.1f} min{' (all of them)' if s['solved'] else ''}, no more within "
                  f"{s['budget_seconds'] / 60:.0f} min (plain sampling: ~{s['independent_estimate']:.0e} per world)"
                  if not s["solved"] else
                  f"spelling SIGGRAPH solved unattended in {reached / 60:.1f} min")
    t = d.get("staircase")
    if t and t["solved"]:
      head.append(f"the spiral staircase in {t['solve_seconds']:.0f} s ({t['refinements']} refinements)")
  robust = d.get("robustness")
  if robust:
    lines += ["Seeds (sampling and search keyed by the seed; same budgets; world-steps/s: how fast the machine "
              "ran that search, physics and all, since the same search path takes the same world-steps on any "
              "machine; load: the 1-minute load average "
              "before sampling and after the search, on a machine shared with other work):", "",
              "| scene | seed | queries | result | refinements | world-steps | solve time | world-steps/s | "
              "plain-sampling estimate | load | commit |",
              "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in robust["runs"]:
      result = "all met" if r["solved"] else f"{r['satisfied']} of {r['n_queries']} met"
      estimate = "–"
      if "independent_estimate" in r:
        estimate = (f"{r['independent_estimate']:.1e} ({r['worlds_sampled']} worlds)" if r["independent_estimate"] > 0
                    else f"0: a query none of {r['worlds_sampled']} worlds meets")
      load = (f"{r['load_average_before']:.1f} / {r['load_average_after']:.1f}" if "load_average_before" in r
              else "–")
      lines.append(f"| {r['scene']} | {r['seed']} | {r['n_queries']} | {result} | {r['refinements']} | "
                   f"{r['world_steps']:,} | {r['solve_seconds']:.0f} s | "
                   f"{r['world_steps'] / max(r['solve_seconds'], 1e-9) / 1e3:.1f} k | {estimate} | {load} | "
                   f"{r['commit']} |")
    lines.append("")
    stepped = [r for r in robust["runs"] if "reference_rate" in r]
    if stepped:
      budgets = sorted({(r["scene"], r["budget_world_steps"], r["reference_rate"]) for r in stepped})
      lines += ["Runs on a world-step budget ("
                + "; ".join(f"{scene}: {n / 1e6:.2f} M world-steps, {n / rate / 60:.0f} min at {rate / 1e3:.1f} k "
                            "world-steps/s" for scene, n, rate in budgets)
                + "; each scene's rate as its solves ran on this machine at load 2 or less) take the same path on any machine and "
                "under any load; the summary counts their time as world-steps at that rate, the table shows the "
                "wall time they took while the machine also ran other work.", ""]
    lines += _seed_summary(robust["runs"])
    upright = [r for r in robust["runs"] if r["scene"] == "siggraph" and r["n_queries"] == 16]
    if upright:
      solved = [r for r in upright if r["solved"]]
      commits = ", ".join(sorted({r["commit"] for r in upright if "commit" in r}))
      head.append(f"SIGGRAPH upright (16 queries): {len(solved)} of {len(upright)} seeds solved within 10 min"
                  + (f", {max(_solve_time(r) for r in solved) / 60:.1f} min at most" if solved else "")
                  + f" (load ≤ {max(r['load_average_after'] for r in upright):.0f}"
                  + (f", {commits})" if commits else ")"))
  guided = dict(d.get("guided") or {})
  if "guided" in guided:  # one case, as written before there were several
    guided = {"quickstart": guided}
  guided.pop("machine", None)  # named in the section's machine line
  if guided:
    lines += ["**Guided vs plain sampling**: per seed, R rounds of M guided worlds (default optimiser) against "
              "plain sampling of at least as many world-steps, pooled over the seeds. The repeat rate is the "
              "share of guided matches whose initial state matches again under fresh perturbations: what any "
              "proposal over initial states can control.", "",
              "| scene | query | plain rate | rounds × worlds × seeds | guided matches | plain matches | "
              "per million world-steps, guided / plain | ratio | second half | repeat rate |",
              "|---|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for g in guided.values():
      gg, p = g["guided"], g["plain"]
      repeat = g.get("repeat_rate")
      lines.append(f"| `{g['config']}` | `{g['query']}` | {p['rate']:.2%} | {g['rounds']} × {g['batch']} × "
                   f"{len(g['seeds'])} | {gg['matches']} of {gg['worlds']} | {p['matches']} of {p['worlds']} | "
                   f"{gg['per_million_steps']:.1f} / {p['per_million_steps']:.1f} | {g['ratio']:.1f}× | "
                   f"{g['late_ratio']:.1f}× | {'-' if repeat is None else f'{repeat:.0%}'} |")
    lines += ["", "Per seed (ratio of matches per world-step):", ""]
    for g in guided.values():
      lines.append(f"* `{g['query']}`: " + ", ".join(f"seed {r['seed']} {r['ratio']:.1f}× "
                                                    f"({r['guided_matches']} vs {r['plain_matches']} matches)"
                                                    for r in g["seeds"]))
    lines.append("")
    head.append("guided sampling finds " + " and ".join(f"{g['ratio']:.1f}× (`{g['query']}`)"
                                                      for g in guided.values())
                + " as many matching worlds per world-step as plain sampling")
  lines += _chain(d)
  return lines, ([f"**solve**: {'; '.join(head)}"] if head else [])


def bank(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Bank", "",
           "`scripts/bench_bank.py`: each scene sampled twice with the same seed and saved as shards: "
           "COM polylines as float32 (`codec.e_com: null`, the baseline; deflated like every shard "
           "block of polylines) and on the grid (default `e_com`). Bytes on disk per body-second (one tracked body for one simulated second); "
           "loading timed as the best of 3.", "",
           f"Machine: {d['machine']}; {d['worlds']} worlds per bank.", "",
           "| scene | COM polylines | e_com | bytes / body-second | COM bytes | qpos bytes | other | "
           "whole bank / qpos stream | load ms |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
  head = []
  for scene, r in d["scenes"].items():
    for label in ("float32", "grid"):
      x = r[label]
      e = "–" if x["e_com_m"] is None else f"{x['e_com_m'] * 1e3:g} mm"
      disk = x["disk_bytes"]
      lines.append(f"| {scene} | {label} | {e} | {x['bytes_per_body_second']:,.0f} | {disk['com']:,} | "
                   f"{disk['qpos']:,} | {disk['other'] + disk['manifest']:,} | "
                   f"{x['bank_over_qpos_stream']:.2f} | {x['load_s'] * 1e3:.0f} |")
    head.append(f"{scene} {r['float32']['bytes_per_body_second']:,.0f} → {r['grid']['bytes_per_body_second']:,.0f} "
                f"bytes per body-second ({r['grid']['bank_over_qpos_stream']:.2f}× its qpos stream)")
  return lines, [f"**bank on disk**: {'; '.join(head)}"]


def browse_bank(d: dict) -> tuple[list[str], list[str]]:
  ms = lambda x: f"{x['median']:.0f} / {x['p95']:.0f} ms" if x else "–"
  split = d["splitting_box_to_counts_ms"]
  lines = [f"## Browsing {d['worlds']:,} worlds on disk", "",
           f"`scripts/bench_browse.py --bank {d['bank']}`: {d['worlds']:,} worlds of {d['bodies']} bodies opened "
           "in the page as `mwbx browse` opens them (lazily, from their shards); screen boxes through the "
           "scene camera, each put on the query stack alone; the boxes that split the bank (keep 5–95 % of "
           "its worlds) are counted apart from those that keep all or none. Baseline in the same run: the "
           f"`mwbx query` round trip for one box. Machine: {d['machine']}, load average {d['load_average']:.1f}.",
           "",
           "| page ready | first box | box → counts median / p95 | splitting boxes | re-sort | click → poses sent "
           "| `mwbx query` round trip |",
           "|---:|---:|---:|---:|---:|---:|---:|",
           f"| {d['page_ready_s']:.1f} s | {d['first_box_s']:.1f} s | {ms(d['box_to_counts_ms'])} "
           f"({d['box_to_counts_ms']['n']} boxes) | {ms(split)} ({split['n'] if split else 0} boxes) | "
           f"{ms(d['resort_ms'])} | {ms(d['click_to_poses_sent_ms'])} | {d['cli_query_round_trip_s']:.1f} s |", "",
           "The first box answers from the stored path boxes and the worlds they leave open; the next ones "
           "from the bank's decoded paths, indexed once (kept while the page is open)."]
  b = d.get("browser_click_to_playing_ms")
  if b:
    lines += ["", f"In headless Chromium, a click on a sorter row → the page says the world plays: "
              f"{b['median']:.0f} ms median, p95 {b['p95']:.0f} ms ({b['clicks']} clicks; on the page's own clock, "
              f"press → text shown {b['in_page_shown_median']:.0f} ms, → next frame drawn "
              f"{b['in_page_drawn_median']:.0f} ms)."]
  return lines, []


def browse(d: dict) -> tuple[list[str], list[str]]:
  a, r = d["box_to_update_ms"], d["resort_ms"]
  lines = ["## Browse", "",
           "`scripts/bench_browse.py`: a real pachinko bank repeated to the size below; per drawn screen "
           "box, the time from the rect-select event to the updated counts, path colours, frustums and "
           "sorter sent to the page, and the same for a metric re-sort. Baseline in the same run: the "
           "`mwbx query` round trip (a new process) for the same queries.", "",
           f"Machine: {d['machine']}.", "",
           "| worlds | bodies | boxes | box → update median / p95 (ms) | re-sort median / p95 (ms) | "
           "`mwbx query` round trip (s) | round trip / page update |",
           "|---:|---:|---:|---:|---:|---:|---:|",
           f"| {d['worlds']} | {d['bodies']} | {d['boxes']} | {a['median']:.0f} / {a['p95']:.0f} | "
           f"{r['median']:.0f} / {r['p95']:.0f} | {d['cli_query_round_trip_s']:.2f} | {d['cli_over_page']:.0f}× |"]
  if d.get("browser"):
    b = d["browser"]
    lines += ["", f"In headless Chromium (software WebGL): the page loads in {b['page_load_s']:.1f} s "
              f"({b['initial_bytes'] / 1e6:.1f} MB over the websocket); one box update sends "
              f"{b['bytes_per_box_update'] / 1e6:.2f} MB (paths recoloured, counts, frustum, sorter)."]
  head = [f"**browse**: a drawn box updates {d['worlds']} worlds in {a['median']:.0f} ms (median; p95 "
          f"{a['p95']:.0f} ms), {d['cli_over_page']:.0f}× faster than the `mwbx query` round trip"]
  if d.get("geometry_box_to_update_ms"):
    g = d["geometry_box_to_update_ms"]
    com_box = g.get("com_box_median_same_run", a["median"])  # a later run of the geometry part has its own
    lines += ["", f"Whole-geometry boxes (`shape: geometry`, {g['boxes']} boxes): box → update median "
              f"{g['median']:.0f} ms, p95 {g['p95']:.0f} ms ({g['median'] / com_box:.1f}× the COM box"
              + (f" of the same run, {com_box:.0f} ms; commit {g['commit']}, load {g['load_average']:.1f}"
                 if "com_box_median_same_run" in g else "")
              + f"); the first one builds the bank's geometry index ({g['first_with_index_build_s']:.0f} s, once)."]
    head[0] += f"; a whole-geometry box in {g['median']:.0f} ms"
  if d.get("play"):
    p = d["play"]
    lines += ["", f"Play (a sorter click, {p['bodies']}-body scene `tests/scenes/twenty.yaml`, {p['clicks']} clicks): "
              f"decode + forward kinematics {p['decode_fk_ms']:.1f} ms, click → poses sent to the page "
              f"{p['play_ms']:.1f} ms median (p95 {p['play_p95_ms']:.1f}); a slot's {p['meshes_per_slot']} meshes "
              "go to the page once and are reused."]
    if "path_segments_drawn" in p:
      lines[-1] += (f" The page redraws the paths' {p['path_segments_drawn']:,} segments every frame (of "
                    f"{p['path_segments_recorded']:,} recorded; `display.simplify_polylines`).")
    b = p.get("browser_click_to_playing_ms")
    if b and "locator_click_median" in b:
      lines += ["", f"In headless Chromium (software WebGL on the shared CPUs), a mouse click on a sorter row → the "
                f"page says the world plays: {b['median']:.0f} ms median (p95 {b['p95']:.0f}; the click reaches "
                f"the server after {b['click_to_server_median']:.0f} ms); Playwright's locator click, which first "
                f"waits for two stable animation frames: {b['locator_click_median']:.0f} ms. The page draws "
                f"{b['idle_frames_per_s']:.1f} frames/s idle and {b['playing_frames_per_s']:.1f} while a world plays "
                f"({b['playing_messages_per_s']:.0f} websocket messages/s): what is left is WebGL drawing time."
                + (f" Load average {p['load_average']:.1f} at the start, commit {p['commit']}." if "load_average" in p
                   else "")]
      if "in_page_shown_median" in b:
        drawn = b["in_page_drawn_median"]
        lines += ["", "Timed in the page, on its own clock (a pointer-press listener, a MutationObserver on the "
                  "panel's text, and the animation frame after it; Playwright's waits check the page at intervals "
                  "from outside it, so the wall clock above is coarse): press → \"playing world N\" shown "
                  f"{b['in_page_shown_median']:.0f} ms median (p95 {b['in_page_shown_p95']:.0f}); press → the "
                  f"next frame begins (the world drawn) {drawn:.0f} ms (p95 {b['in_page_drawn_p95']:.0f}). "
                  f"Goal ≤ 200 ms to the world drawn: {'met' if drawn <= 200 else 'missed'} in this run "
                  "(runs differ: [browser](browser.md#on-the-page)). Software WebGL shares the two cores, so a "
                  f"frame takes ~{1e3 / b['playing_frames_per_s']:.0f} ms while a world plays, and the answer "
                  "waits for the one in progress."]
      elif "load_average" in p:
        lines[-1] += (f" Goal ≤ 200 ms ({'met' if b['median'] <= 200 else 'missed'}). On busy cores the same "
                      "click takes several times as long: software WebGL shares them.")
    elif b:
      lines += ["", f"In headless Chromium (software WebGL on the shared CPUs): click → the page says the world "
                f"plays {b['median']:.0f} ms median (p95 {b['p95']:.0f}), of which {b['click_to_server_median']:.0f} ms "
                "pass before the click's event reaches the server: the browser's own time on this machine."]
    head[0] += f"; a sorter click plays a {p['bodies']}-body world in {p['play_ms']:.0f} ms on the server"
  c = d.get("play_cloth")
  if c:
    b = c.get("browser_click_to_playing_ms") or {}
    lines += ["", f"Play of a cloth world (`{c['scene']}`, {c['bodies']} tracked bodies, the flex surface drawn "
              f"and moved each frame; {c['clicks']} clicks): decode + forward kinematics {c['decode_fk_ms']:.1f} ms, "
              f"click → poses and surface sent {c['play_ms']:.1f} ms median (p95 {c['play_p95_ms']:.1f})"
              + (f"; in headless Chromium a mouse click → \"playing world N\" shown {b['in_page_shown_median']:.0f} ms, "
                 f"→ the world drawn {b['in_page_drawn_median']:.0f} ms median (p95 {b['in_page_drawn_p95']:.0f}; "
                 f"goal ≤ 200 ms: {'met' if b['in_page_drawn_median'] <= 200 else 'missed'}), "
                 f"{b['playing_frames_per_s']:.1f} frames/s while it plays (goal ≥ 10: "
                 f"{'met' if b['playing_frames_per_s'] >= 10 else 'missed'}; {b['idle_frames_per_s']:.1f} idle)"
                 if "in_page_drawn_median" in b else "")
              + (f". Load average {c['load_average']:.1f} at the start, commit {c['commit']}." if "load_average" in c
                 else ".")]
  return lines, head


def geometry(d: dict) -> tuple[list[str], list[str]]:
  c, g = d["com_query_ms"], d["geometry_query_ms"]
  inc, exc = d["include_matches"], d["exclude_matches"]
  o = d.get("orientation", {})
  lines = ["## Geometry", "",
           "`scripts/bench_geometry.py`: the browse bench's bank (a real pachinko bank repeated to the size "
           "below); for each of its drawn screen boxes (include and exclude in turn) the same query on the "
           "bodies' whole geometry and, as the baseline measured in the same run, on their COM paths "
           "(`mwbx.queries.evaluate_each`, after a warm-up that compiles and builds the indexes).", "",
           f"Machine: {d['machine']}; commit {d.get('commit', '?')}; load average "
           f"{d.get('load_average', float('nan')):.1f} when it ended"
           + ("; resolved " + ", ".join(f"{k} {v}" for k, v in d["versions"].items()) if "versions" in d else "")
           + ".", "",
           "| worlds | bodies | boxes | COM query median / p95 (ms) | geometry query median / p95 (ms) | "
           "geometry / COM | geometry index build (s) | include matches COM → geometry | "
           "exclude matches COM → geometry |",
           "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
           f"| {d['worlds']} | {d['bodies']} | {d['boxes']} | {c['median']:.0f} / {c['p95']:.0f} | "
           f"{g['median']:.0f} / {g['p95']:.0f} | {d['geometry_over_com']:.1f}× | "
           f"{d['geometry_index_build_s']:.0f} | {inc['com']} → {inc['geometry']} | {exc['com']} → {exc['geometry']} |"]
  if "first_geometry_query_s" in d:
    lines += ["", f"The first geometry query after the index took {d['first_geometry_query_s']:.1f} s: it builds "
              "the poses at every stored frame that settle borderline worlds (once per bank)."]
  if o:
    lines += ["", "Orientation queries on the same bank (cached orientations): " + "; ".join(
        f"{k.replace('_', ' ')} {v['ms']:.0f} ms ({v['worlds']} worlds)" for k, v in o.items()) + "."]
  head = [f"**geometry**: a whole-geometry query on {d['worlds']} worlds in {g['median']:.0f} ms (median), "
          f"{d['geometry_over_com']:.1f}× the COM query"]
  p = d.get("page")
  if p:
    pc, pg = p["com_box_to_update_ms"], p["geometry_box_to_update_ms"]
    lines += ["", f"In the page ({pg['boxes']} boxes of each kind drawn in turn on a stack of at most 3 queries, "
              f"as `scripts/bench_browse.py` draws them): box → update median / p95 {pc['median']:.0f} / "
              f"{pc['p95']:.0f} ms for COM boxes, {pg['median']:.0f} / {pg['p95']:.0f} ms for whole-geometry "
              f"boxes ({p['geometry_over_com']:.1f}×); the geometry index keeps its latest answers, so a stack "
              "re-evaluated after a new box computes only that box."]
    head[0] += f"; in the page a whole-geometry box updates in {pg['median']:.0f} ms median"
  return lines, head


def geometry_tightness(d: dict) -> tuple[list[str], list[str]]:
  s, b = d["settled"], d["kept_frames_only"]
  q = d["query_ms"]

  def row(label: str, t: dict) -> str:
    x = t["extra_distance_mm"]
    return (f"| {label} | {t['answers']} | {t['false_negatives']} | {t['extras']} ({100 * t['extras_share']:.1f} %) | "
            f"{x['median']:.1f} / {x['p90']:.1f} / {x['max']:.1f} | {t['beyond_margin_reference']} "
            f"({100 * t['beyond_margin_share']:.1f} %) |")

  lines = ["## Geometry tightness", "",
           "`scripts/bench_geometry_tightness.py`: a scene no test uses (16 crates and 4 balls dropped onto a "
           f"tilted board, {d['worlds']} worlds, stored at {d['record_fps']:g} fps, kept at {d['query_fps']:g} fps); "
           f"{d['boxes']} region boxes (half-sizes 5–30 mm) centred on crate surface points late in some world's "
           "run, each a whole-geometry include query over the whole run. References from the decoded frames "
           "with MuJoCo's kinematics and plain geometry, independent of the query code: *exact* (a geom meets "
           "the box at a stored frame; "
           f"{d['exact_reference_hits']} hits) and *with margin* (a geom within the codec's bound of the box at "
           "a stored frame: the stated bound). An extra is an answer the exact reference does not have; its distance is "
           "how near its geoms came to the box.", "",
           f"Machine: {d['machine']}; commit {d.get('commit', '?')}; load average "
           f"{d.get('load_average', float('nan')):.1f} when it ended"
           + ("; resolved " + ", ".join(f"{k} {v}" for k, v in d["versions"].items()) if "versions" in d else "")
           + ".", "",
           "| answers | include answers | false negatives | extras | extra distance median / p90 / max (mm) | "
           "beyond the margin reference |",
           "|---|---:|---:|---:|---:|---:|",
           row("settled on the stored frames (mwbx)", s),
           row("kept frames' margins alone (before)", b), "",
           f"Query time on these {d['worlds']} worlds: {q['first_median']:.0f} ms median the first time (worlds to "
           f"settle decoded on demand; max {q['first_max']:.0f} ms), {q['again_median']:.0f} ms again with their "
           "stored frames kept."]
  head = [f"**geometry tightness**: {100 * s['extras_share']:.1f} % of answers beyond the exact reference "
          f"({s['beyond_margin_reference']} beyond the stated margin, {s['false_negatives']} missed)"]
  return lines, head


def setup(d: dict) -> tuple[list[str], list[str]]:
  home = "a fresh HOME (no pip, numba, JAX or Warp caches)" if d.get("fresh_home", True) else "this machine's HOME"
  lines = ["## Setup", "",
           "`scripts/bench_setup.py`: a fresh clone of the commit below, with " + home + "; `make run` twice "
           "(the second, which installs and compiles nothing, is the baseline)"
           + (", then `make test`" if "make_test_s" in d else "") + ".", "",
           f"Machine: {d['machine']}; commit {d.get('commit', '?')}; load average "
           f"{d.get('load_average', float('nan')):.1f} when it ended"
           + ("; resolved " + ", ".join(f"{k} {v}" for k, v in d["versions"].items()) if "versions" in d else "")
           + ".", "",
           "| first `make run` (s) | second `make run` (s) | first / second |"
           + (" `make test` (min) |" if "make_test_s" in d else ""),
           "|---:|---:|---:|" + ("---:|" if "make_test_s" in d else ""),
           f"| {d['first_make_run_s']:.0f} | {d['second_make_run_s']:.0f} | {d['first_over_second']:.1f}× |"
           + (f" {d['make_test_s'] / 60:.1f} |" if "make_test_s" in d else "")]
  return lines, []  # the README shows its own set-up commands


def _index_share(z: dict) -> str:
  """", of which N for its stored path boxes (P % of the rest)" where measured."""
  if not z.get("index_bytes"):
    return ""
  rest = z["bank_bytes"] - z["index_bytes"]
  return (f", of which {z['index_bytes'] / z['bank_bytes'] * z['bank_bytes_per_world']:,.0f} its stored path boxes, "
          f"{z['index_bytes'] / rest:.0%} of the rest")


def scale(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Scale", "",
           "`scripts/bench_scale.py`: the paper's trebuchet and 192-block tower "
           "(`configs/trebuchet_tower.yaml`) at its dataset size, a synthetic 100 k-world "
           "pachinko-size bank, and (where measured) a bank of short quickstart worlds every one of "
           "which mwbx sampled. Peak memory is each child process's max RSS.", ""]
  head = []
  if "sample" in d:
    x = d["sample"]
    m = x["machine"]
    lines += [f"**Sampling** ({m['cpus']} CPU cores, {m['machine']}, no GPU; commit {m['commit']}; load "
              f"average {x['load_average_before']:.1f} before, {x['load_average_after']:.1f} after: other "
              "work ran on the machine meanwhile):", "",
              "| worlds | wall | world-steps/s | plain `mj_step` × threads (baseline) | ratio | peak memory | "
              "bank on disk | per world |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|",
              f"| {x['worlds']} | {x['wall_minutes']:.1f} min | {x['world_steps_per_second']:,.0f} | "
              f"{x['plain_mj_step_per_second_one_thread']:,.0f} × {x['threads']} | "
              f"{x['ratio_to_physics_floor']:.2f} | {x['peak_rss_mb'] / 1024:.1f} GiB | "
              f"{x['bank_bytes'] / 1e6:.1f} MB | {x['bank_bytes_per_world'] / 1e3:.1f} KB |", "",
              "The paper took 14 cluster-hours with ODE for its 1549 samples. This benchmark ran on "
              "the CPU only; the tower's batched step on a GPU against native on that machine's cores: "
              "[Batched engines (GPU)](#batched-engines-gpu).", ""]
    head.append(f"{x['worlds']} trebuchet-tower worlds in {x['wall_minutes']:.0f} min on {x['threads']} cores "
                f"({x['ratio_to_physics_floor']:.2f}× the plain `mj_step` rate)")

  def rows(r, label):
    out = []
    for mode in ("eager", "lazy", "streamed"):
      if mode in r:
        o, q = r[mode]["open"], r[mode]["query"]
        how = mode + (", from its boxes" if q.get("from_boxes") else "")
        out.append(f"| {label} | {how} | {o['open_seconds']:.2f} | {o['peak_rss_mb']:,.0f} | "
                   f"{q['query_seconds']:.2f} | {q['query_again_seconds']:.2f} | {q['peak_rss_mb']:,.0f} | "
                   f"{q['all_match']:,} of {q['worlds']:,} |")
    return out

  table = ["| bank | opened | open (s) | open peak (MB) | query (s) | again (s) | query peak (MB) | "
           "match all |", "|---|---|---:|---:|---:|---:|---:|---:|"]
  if "tower" in d:
    table += rows(d["tower"], "tower, 1549 worlds")
  if "synthetic" in d:
    table += rows(d["synthetic"], f"synthetic pachinko, {d['synthetic']['worlds']:,} worlds")
  if "hundred_k" in d:
    table += rows(d["hundred_k"], f"sampled quickstart, {d['hundred_k']['worlds']:,} worlds of 4 s")
  if "million" in d:
    table += rows(d["million"], f"sampled quickstart, {d['million']['worlds']:,} worlds")
  if len(table) > 2:
    lines += ["**Opening and querying** (each in a fresh process; *eager*: `Bank.load(path, lazy=False)`, "
              "the baseline; *lazy*: the default, indexed whole below `IN_MEMORY_COM_BYTES`; *streamed*: "
              "a shard at a time; the answers are identical in every mode). *query* includes reading the "
              "shards and compiling; *again* is a second evaluation in the same process. *From its boxes*: the "
              "first evaluation starts from the bank's stored path boxes and decodes only the worlds they leave "
              "open (the whole bank, indexed, where that is most of a bank that fits in memory, as the 100,000 "
              "4-s worlds' ball grazing a box is); a lazy bank's second evaluation then decodes and indexes it "
              "whole, for the evaluations after it (the page's next boxes).", ""] + table + [""]
  t = d.get("tower", {})
  if "query" in t and "index_bytes" in t:
    lines += [f"The tower bank as a user queries it, each in a fresh process: `mwbx info` "
              f"{t['info']['wall_seconds']:.1f} s (peak {t['info']['peak_rss_mb']:,.0f} MB), `mwbx query BANK "
              f"configs/queries/trebuchet_tower.yaml` {t['query']['wall_seconds']:.1f} s (peak "
              f"{t['query']['peak_rss_mb']:,.0f} MB; commit {t['machine']['commit']}). Its stored path boxes "
              f"(the first level of a volume query, [queries](queries.md#stored-path-boxes)) take "
              f"{t['index_bytes'] / 1e6:.1f} MB, {t['index_bytes'] / (t['bank_bytes'] - t['index_bytes']):.0%} "
              "of the rest of the bank.", ""]
  if "synthetic" in d:
    y = d["synthetic"]
    lines += [f"The synthetic bank: {y['bank_bytes'] / 1e6:.0f} MB on disk, "
              f"{y['bank_bytes_per_world']:,.0f} bytes per world; its COM polylines alone would be "
              f"{y['com_float32_bytes'] / 1e9:.2f} GB as float32 (streamed query peak / that: "
              f"{y['peak_memory_ratio_streamed_to_float32_com']:.2f}).", ""]
    head.append(f"a {y['worlds']:,}-world bank opens in {y['lazy']['open']['open_seconds']:.2f} s and is "
                f"queried a shard at a time in {y['streamed']['query']['peak_rss_mb'] / 1024:.1f} GiB")
  def sampled(z, phase, after):
    info, query = z["info"], z["query"]
    return [f"The sampled bank (`--phases {phase}`): {z['worlds']:,} quickstart worlds of {z['end_time']:g} s, "
            f"every one sampled by `mwbx sample` in {z['sample_wall_seconds'] / 60:.1f} min "
            f"({z['world_steps_per_second']:,.0f} world-steps/s, peak {z['sample_peak_rss_mb'] / 1024:.1f} GiB; "
            f"commit {z.get('sampled_at_commit', z['machine']['commit'])}, load average "
            f"{z['load_average_before']:.1f} before, {z['load_average_after']:.1f} after), "
            f"{z['bank_bytes'] / 1e6:,.0f} MB on disk in {z['shards']:,} shards ({z['bank_bytes_per_world']:,.0f} "
            f"bytes a world{_index_share(z)}). As a user runs them at commit {z['machine']['commit']}, each in a "
            f"fresh process: `mwbx info` {info['wall_seconds']:.1f} s (peak {info['peak_rss_mb']:,.0f} MB), "
            f"`mwbx query BANK configs/queries/quickstart.yaml` {query['wall_seconds']:.1f} s "
            f"(peak {query['peak_rss_mb']:,.0f} MB).{after}", ""]

  if "hundred_k" in d:
    lines += sampled(d["hundred_k"], "hundred_k", "")
  if "million" in d:
    lines += sampled(d["million"], "million", " Its first query's window starts at 3.5 s, after these worlds "
                     "end: none matches all three, each is evaluated over every world all the same.")
    # No README headline for it: the README stays within 12 KB.
  return lines, ([f"**scale**: {'; '.join(head)}"] if head else [])


def scenes(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Paper scenes", "",
           "`scripts/scene_counts.py`: every shipped scene sampled on native, mjx:jax (contact budget) and "
           f"mjx:warp (MuJoCo Warp), seed 0, {d['machine']}: valid, unstable and over-the-contact-budget "
           "worlds, and how many meet each query of its query file. World counts and simulated seconds "
           "are chosen per backend so every run finishes on 2 shared CPU cores (MJX on a CPU is slow); "
           "the ones used are in each row. Counts of different world numbers are compared as rates.", "",
           "| scene | backend | worlds | simulated s | valid | unstable | over budget | MuJoCo errors | "
           "all queries met | per query | wall s | commit |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---|"]
  for r in d["rows"]:
    per = ", ".join(f"{k} {v}" for k, v in r["per_query"].items()) or "(no query file)"
    all_met = "–" if r.get("all_met") is None else r["all_met"]
    lines.append(f"| {r['scene']} | {r['backend']} | {r['worlds']} | {r.get('end_time', '–')} | {r['valid']} | "
                 f"{r['unstable']} | {r.get('over_budget', '–')} | {r['sim_errors']} | {all_met} | {per} | "
                 f"{r.get('wall_seconds', 0):.0f} | {r.get('commit', '-')} |")
  planned = d.get("planned") or {"scenes": list(dict.fromkeys(r["scene"] for r in d["rows"])),
                                 "backends": sorted({r["backend"] for r in d["rows"]})}
  missing = [f"{s} on {b}" for s in planned["scenes"] for b in planned["backends"]
             if not any(r["scene"] == s and r["backend"] == b for r in d["rows"])]
  if missing:
    lines += ["", f"Not sampled yet: {', '.join(missing)} (the run had not reached them when these "
              "figures were committed; `scripts/scene_counts.py --scenes S --backends B` adds them)."]
  return lines + [""], []


def _engine_table(d: dict) -> list[str]:
  lines = ["| scene | engine | batch | steps | world-steps/s | vs native | compile s | worlds flagged | "
           "flops / world-step | bytes / world-step | H200 roofline bound, world-steps/s |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
  for scene, s in d["scenes"].items():
    for r in s["rows"]:
      cost = r.get("cost") or {}
      if r["engine"].startswith("mjx:warp"):  # custom calls: XLA's figures would count only the glue around them
        cost = {}
      bound = cost.get("roofline_steps_per_s")
      ratio = "1" if r["engine"].startswith("native") else f"{r['ratio_to_native']:.3g}"
      compile_s = "–" if r["compile_s"] is None else f"{r['compile_s']:.0f}"
      lines.append(f"| {scene} | {r['engine']} ({r['what']}) | {r['batch']} | {r['steps']} | "
                   f"{r['world_steps_per_s']:,.0f} | {ratio} | "
                   f"{compile_s} | "
                   f"{r.get('flagged', '–')} | {_n(cost['flops']) if cost.get('flops') else '–'} | "
                   f"{_n(cost['bytes_accessed']) if cost.get('bytes_accessed') else '–'} | "
                   f"{f'{bound:,.0f}' if bound else '–'} |")
  return lines


def _previous_and_stages(d: dict) -> list[str]:
  """Each scene's mjx:jax against an earlier commit's, and where its step's time goes."""
  lines = []
  for scene, s in d["scenes"].items():
    now = next((r for r in s["rows"] if r["engine"] == "mjx:jax"), None)
    old = (s.get("previous") or {}).get("mjx:jax")
    if now and old:
      pm, pb = s["previous"]["machine"], s["previous"]["budget"]
      # Runs before solver limits were recorded ran MJX's own step with the model's 100 / 50.
      ps = s["previous"].get("mjx_solver") or {"iterations": 100, "ls_iterations": 50}
      lines += ["", f"{scene}, mjx:jax at an earlier commit and now (same batch, states and start time): "
                f"{old['world_steps_per_s']:,.0f} world-steps/s at commit {pm['commit']} ({old['what']}, "
                f"max_geom_pairs {pb['max_geom_pairs']}, max_contact_points {pb['max_contact_points']}, solver "
                f"limits {ps['iterations']} / {ps['ls_iterations']}; load {pm['load_average']:.1f}; "
                f"{old['ratio_to_native']:.3g}× native in its run) → "
                f"{now['world_steps_per_s']:,.0f} now (load {s['machine']['load_average']:.1f}; "
                f"{now['ratio_to_native']:.3g}× native): {now['ratio_to_native'] / old['ratio_to_native']:.1f}× "
                "against native measured alongside (the load differed between the runs)."]
    stages = (now or {}).get("stages_ms")
    if stages:
      solver = s.get("mjx_solver", {})
      apart = {"whole step", "solver (every row)"}  # not parts of the step
      parts = ", ".join(f"{k} {v:,.1f}" for k, v in stages.items() if k not in apart)
      top = max((k for k in stages if k not in apart), key=stages.get)
      in_scan = 1e3 * now["batch"] / now["world_steps_per_s"]
      lines += ["", f"Where a {scene} mjx:jax step goes (ms per batched step of {now['batch']}, each part "
                f"jitted apart on the timed states; solver limits {solver.get('iterations')} / "
                f"{solver.get('ls_iterations')}): {parts}; together "
                f"{sum(v for k, v in stages.items() if k not in apart):,.0f}, against {in_scan:,.0f} per "
                f"step in the timed scan. The largest part is the {top}. The whole step jitted alone, "
                f"outside a scan, took {stages['whole step']:,.0f} ms"
                + (": far more than in the scan, not understood, and not what a run pays."
                   if stages["whole step"] > 2 * in_scan else ".")]
      detail = now.get("solver_detail")
      if detail:
        lines[-1] += (f" The solver's input has {detail['rows']} constraint rows per world, of which "
                      f"{detail['nonzero_rows_mean']:.0f} (mean over the batch) have a non-zero Jacobian: "
                      "the others are budget slots without a contact. One dense Hessian build over all "
                      f"rows ({detail['rows']} × {detail['nv']}², every world) takes "
                      f"{detail['hessian_build_ms']:.1f} ms and its Cholesky {detail['cholesky_ms']:.1f} ms "
                      "per batched step.")
      if "solver (every row)" in stages:
        lines[-1] += (" The step solves each world over its own rows in use (`mjx_packed_solve`); MJX's solve "
                      f"over every row (`sim.mjx.pack_rows: false`) takes {stages['solver (every row)']:,.1f} ms "
                      "on the same states.")
  return lines


def _what_limits(s: dict, r: dict) -> str:
  """One paragraph: what holds SIGGRAPH's mjx:jax step back, from its budget and stage times."""
  b, stages = s["budget"], r.get("stages_ms") or {}
  rows = 4 * b["max_contact_points"]
  text = ("What limits it: MJX's arrays have fixed shapes, so every step of every world pays for its whole "
          f"budget, not for the contacts it has: the narrow phase of up to {b['max_geom_pairs']} pairs in each "
          f"collision-function group (box-box, capsule-box) and the constraint rows of "
          f"{b['max_contact_points']} contact slots × 4 pyramidal rows ({rows} rows), while MuJoCo C runs "
          "only the contacts present, sparsely.")
  if "solver (every row)" in stages:
    text += (" The step solves each world over its own rows in use only, packed first: "
             f"{stages.get('solver', 0):,.0f} ms against {stages['solver (every row)']:,.0f} ms over every row; "
             f"each Newton iteration still factors a {s.get('nv', 'nv')}-square Hessian per world.")
  if stages:
    text += (f" Of a {1e3 * r['batch'] / r['world_steps_per_s']:,.0f} ms batched step ({r['batch']} worlds) the solver takes "
             f"{stages.get('solver', 0):,.0f} ms and collision {stages.get('collision', 0):,.0f} ms "
             f"(parts timed apart); at {r['world_steps_per_s']:,.0f} world-steps/s the goal needs the step "
             f"{1500 / r['world_steps_per_s']:.1f}× cheaper on these {s['machine']['cores']} shared cores. The budget is what the "
             "scene needs at its most crowded (letters heaped in the slots at the end), and a smaller one "
             "flags worlds instead. What was tried and measured, and the active contacts per phase against the "
             "budget: [sampling](sampling.md#contact-budgets-mjx).")
  return text


def backends(d: dict) -> tuple[list[str], list[str]]:
  m = d["machine"]
  lines = ["## Batched engines (CPU)", "",
           "`scripts/bench_backends.py`: per scene, in one run and from the same randomized initial "
           "states (un-perturbed), bare `mujoco.rollout` on all cores (*native*), `jax.vmap(mjx.step)` "
           "without a contact budget (*mjx:bare*, dense contacts: MJX as mwbx ran it before budgets), "
           "MJX with the scene's contact budget (*mjx:jax*: mwbx's step, MJX's with geom pairs culled by "
           "world bounding boxes, `mwbx/batch_sim/mjx_collision.py`, and the solver's iterations capped) "
           "and MuJoCo Warp through MJX with pools sized "
           "from the same budget (*mjx:warp*). Rates exclude compile time; runs alternate and each keeps "
           "its best. *worlds flagged*: worlds whose step may have dropped a contact (over the budget) "
           "in the timed steps. Where a scene names a start time, every engine is timed from the states "
           "after that many seconds of un-perturbed MuJoCo C (bodies in contact, not still falling).", "",
           f"Machine: {m['platform']}, {m['cores']} cores, JAX {m['jax']} on {m['jax_backend']}, MuJoCo "
           f"{m['mujoco']}; load average {m['load_average']:.1f} at the start (shared: absolute rates "
           f"drift, ratios in one run hold); commit {m['commit']}.", ""]
  lines += _engine_table(d)
  lines += ["", "Load average at the start of each scene's run: " + ", ".join(
      f"{scene} {s['machine']['load_average']:.1f} (commit {s['machine']['commit']}"
      + (f", timed from t = {s['start_time']:g} s" if s.get("start_time") else "") + ")"
      for scene, s in d["scenes"].items() if "machine" in s) + "."]
  lines += _previous_and_stages(d)
  lines += ["", "Contact budgets used (from the native pilot unless the config sets them):", ""]
  for scene, s in d["scenes"].items():
    b = s["budget"]
    lines.append(f"* {scene}: max_contact_points {b['max_contact_points']}, max_geom_pairs "
                 f"{b['max_geom_pairs']}; nconmax {b['nconmax']}, njmax {b['njmax']} ({b['source']}; "
                 f"pilot {s['pilot_s']:.0f} s)")
  gpu = d["gpu_roofline"]
  lines += ["", "**On paper, for a GPU (estimates, not measurements).** *flops* and *bytes* per world-step "
            "are XLA's own cost analysis of one compiled batched step (`jax.jit(step).lower(d).compile()"
            ".cost_analysis()`, divided by the batch) as compiled for the device above; the roofline bound "
            f"is 1 / max(flops / {gpu['fp32_flops_per_s'] / 1e12:.0f} TFLOP/s fp32, bytes / "
            f"{gpu['hbm_bytes_per_s'] / 1e12:.1f} TB/s HBM) on an {gpu['name']}: a ceiling no kernel "
            "reaches (XLA's CPU cost model is not the GPU's, every access is counted as HBM traffic, and "
            "launch and synchronisation costs are ignored). MuJoCo Warp's kernels are custom calls XLA "
            "does not see into, so its cost is not counted. Published figures for scale:", ""]
  for p in d["published"]:
    lines.append(f"* {p['what']}: {p['steps_per_s']:,.0f} steps/s on an {p['device']} ({p['source']}).")
  # No README headline: the README stays within 12 KB.
  sig = d["scenes"].get("siggraph")
  if sig and "mjx:jax" in {r["engine"] for r in sig["rows"]}:
    r = next(r for r in sig["rows"] if r["engine"] == "mjx:jax")
    bare = next((x for x in sig["rows"] if x["engine"] == "mjx:bare"), None)
    goal = "meets" if r["world_steps_per_s"] >= 1500 else "misses"
    lines += ["", f"Goal: SIGGRAPH on mjx:jax ≥ 1500 world-steps/s at batch 64 on this CPU: "
              f"{r['world_steps_per_s']:,.0f} at batch {r['batch']} ({goal} it)"
              + (f", {r['world_steps_per_s'] / bare['world_steps_per_s']:.0f}× bare MJX "
                 f"({bare['world_steps_per_s']:,.0f})." if bare else ".")]
    every = next((x for x in sig["rows"] if x["engine"] == "mjx:jax every row"), None)
    if every:
      lines[-1] += (f" With MJX's solve over every budget row (`sim.mjx.pack_rows: false`, the step before each "
                    f"world was solved over its rows in use): {every['world_steps_per_s']:,.0f} in the same run "
                    f"(the default step is {r['world_steps_per_s'] / every['world_steps_per_s']:.2f}× as fast).")
    if goal == "misses":
      lines += ["", _what_limits(sig, r)]
  timing = d.get("sample_timing")
  if timing:
    lines += ["", f"`{timing['command']}`: {timing['wall_s'] / 60:.1f} min wall, as a user first runs it (a fresh"
              f" process with an empty compilation cache: pilot and compile included; {timing['valid']} valid, "
              f"{timing['over_budget']} over the budget; load average {timing['load_average']:.1f}; goal ≤ 10 min)."]
  return lines, []


def gpu(d: dict) -> tuple[list[str], list[str]]:
  m = d["machine"]
  if m["jax_backend"] == "cpu":
    lines = ["## Batched engines (GPU)", "", "Not measured: no GPU was available. `scripts/gpu_check.sh` "
             "measures it on one (see the README)."]
    return lines + [""], []
  lines = ["## Batched engines (GPU)", "",
           "`scripts/gpu_check.sh` (`bench_backends.py` at a GPU batch, mjx:jax and mjx:warp against "
           "native on the same machine's cores, each engine in its own process with native measured "
           "alongside: *vs native* is to that). Machine: "
           f"{m.get('device', m['jax_backend'])}, {m['cores']} CPU cores, JAX {m['jax']}, MuJoCo {m['mujoco']}; "
           f"commit {m['commit']}.", ""]
  lines += _engine_table(d) + [""]
  for scene, s in d["scenes"].items():
    b = s["budget"]
    natives = ", ".join(f"{r['engine']} at {r['batch']} worlds: {r['native_world_steps_per_s']:,.0f}"
                        for r in s["rows"] if r.get("native_world_steps_per_s"))
    lines.append(f"* {scene}: timed from t = {s.get('start_time', 0):g} s; budget max_contact_points "
                 f"{b['max_contact_points']}, max_geom_pairs {b['max_geom_pairs']}, nconmax {b['nconmax']}, "
                 f"njmax {b['njmax']} ({b['source']}); native alongside each engine ({natives} world-steps/s).")
  # gpu_check.sh's one timed run, or runs recorded one by one (each with its commit and how it was run)
  runs = d.get("sample_runs") or ([d["sample_timing"]] if d.get("sample_timing") else [])
  if runs:
    lines += ["", "`mwbx sample` on this machine:", ""]
  for timing in runs:
    lines.append(f"* `{timing['command']}`" + (f" (commit {timing['commit']})" if timing.get("commit") else "")
                 + f": {timing['wall_s']:.0f} s wall for {timing['worlds']} worlds ({timing['valid']} valid, "
                 f"{timing['over_budget']} over the budget)"
                 + (f"; the sampler's summary: {timing['engine']}, {timing['sampler_world_steps_per_s']:,} "
                    f"world-steps/s over {timing['simulate_s']:.1f} s of stepping, compile {timing['compile_s']:.1f} s, "
                    f"compression {timing['compression_s']:.1f} s; budget {timing['budget']}"
                    if "sampler_world_steps_per_s" in timing else "")
                 + (f"; {timing['note']}" if timing.get("note") else "") + ".")
  codec = d.get("codec_fit")
  if codec:
    each = lambda where: ", ".join(f"{r['seconds']:.2f}" for r in codec["runs"] if r["fit_on"] == where)
    size = lambda where: next(r["bytes"] for r in codec["runs"] if r["fit_on"] == where)
    lines += ["", f"The codec (`scripts/bench_codec_device.py`: {codec['worlds']} worlds × {codec['frames']} "
              f"frames of {codec['bodies']} boxes, `encode_batch_checked`, alternating, the first of each loading "
              f"its code): with JAX's default device {codec['default_device']} {each('default')} s; with the host "
              f"CPU the default {each('host cpu')} s. The streams "
              + ("are the same: the fit is compiled host code (`mwbx.codec.fit_kernels`), whatever the default."
                 if codec["same_streams"] else
                 f"differ ({size('default'):,} against {size('host cpu'):,} bytes): a bank's streams must not "
                 "depend on the accelerator.")]
  return lines + [""], []


def _chain(d: dict) -> list[str]:
  """The chain-reaction solves (bench_solve part chain), if measured."""
  c = d.get("chain")
  if not c:
    return []
  m = c["machine"]
  solved = sum(r["solved"] for r in c["runs"])
  lines = ["", "### Chain reaction (contact events in order)", "",
           f"`configs/chain_reaction.yaml` with `configs/queries/chain_reaction.yaml` (the seven touches in "
           "order, two touch queries, the cup as a region): 16 worlds sampled per seed, the worlds already "
           f"meeting every query dropped, then `mwbx.solve` within {c['budget_seconds']:.0f} s. Machine: "
           f"{m['cpus']}-core {m['machine']} CPU, commit {m['commit']}. Solved in {solved} of {len(c['runs'])} seeds.",
           "", "| seed | sampled worlds meeting all (dropped) | result | refinements | world-steps | solve s |",
           "|---:|---:|---|---:|---:|---:|"]
  for r in c["runs"]:
    result = "all met" if r["solved"] else f"{r['satisfied']} of {r['n_queries']} met"
    lines.append(f"| {r['seed']} | {r['dropped_before_solving']} | {result} | {r['refinements']} | "
                 f"{r['world_steps']:,} | {r['solve_seconds']:.0f} |")
  return lines


def flex(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Flexes (cloth, soft solids)", "",
           "`scripts/bench_flex.py`: the mwbx sampler (native) against bare `mujoco.rollout` of the same "
           "model from the same initial states in the same run (the baseline), and the bank's stored qpos "
           "per flex vertex-second against float32 vertex positions and SZ3 (`pysz`) at the same absolute "
           f"bound on the flex's coordinates (the codec's `e_scalar`). Machine: {d['machine']}, MuJoCo "
           f"{d['mujoco']}. The mwbx bytes are the whole stored qpos (flex and rigid objects), so an upper "
           "bound for the flex's share; a trilinear soft solid's vertices are its 8 node bodies.", "",
           "| scene | worlds | world-steps/s (mwbx) | bare rollout | ratio | flex | vertices | mwbx B/vertex-s | "
           "vs float32 | SZ3 B/vertex-s | SZ3 / mwbx |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
  for r in d["scenes"]:
    for name in r["flexes"]:
      f = r[name]
      sz3 = (f"{f['sz3_bytes_per_vertex_second']:.1f} | {f['sz3_over_mwbx']:.2f}×" if f["sz3_bytes_per_vertex_second"]
             else "– | –")
      lines.append(f"| {r['scene']} | {r['worlds']} | {r['mwbx_world_steps_per_s']:,.0f} | "
                   f"{r['rollout_world_steps_per_s']:,.0f} | {r['ratio_vs_rollout']:.2f}× | {name} | {f['vertices']} | "
                   f"{f['mwbx_qpos_bytes_per_vertex_second']:.1f} | {f['mwbx_vs_float32']:.3f}× | {sz3} |")
  blocks = [r for r in d["scenes"] if "block" in r]
  if blocks:
    lines += ["", "mwbx and the rollout ran in turn, a block of worlds at a time ("
              + ", ".join(f"{r['scene']}: {r['block']}" for r in blocks)
              + "), so that load on the shared machine falls on both alike; the ratio is of the totals."]
  jitter = [(r, name, r["shape_jitter"][name]) for r in d["scenes"] if "shape_jitter" in r for name in r["flexes"]]
  if jitter:
    lines += ["", "A flex is perturbed as a whole ([sampling](sampling.md#how-it-works)): perturbations per world "
              + ", ".join(f"{r['scene']} {r['perturbations_per_world']:.0f}" for r in blocks if
                          "perturbations_per_world" in r)
              + ". Its shape's shaking (RMS second difference of its vertices about their mean, per recorded "
              "frame²) with its perturbations against the same worlds with the flex excluded from them: "
              + "; ".join(f"{r['scene']} {name} {j['perturbed'] * 1e3:.3f} against {j['not_perturbed'] * 1e3:.3f} "
                          f"mm/frame² ({j['ratio']:.2f}×)" for r, name, j in jitter)
              + ": a uniform kick moves the whole flex and leaves its shape alone."]
  return lines, []


def events(d: dict) -> tuple[list[str], list[str]]:
  c, lat = d["cost"], d["latency"]
  lines = ["## Contact events", "",
           "`scripts/bench_events.py`: the same quickstart worlds sampled with their contact events found at "
           "every physics step inside the native loop, and found afterwards on the stored frames (MuJoCo "
           "collision at every frame: the baseline); the bytes events add to the bank's shards; event queries "
           f"against a COM screen box on the same bank (the baseline). Machine: {d['machine']}, MuJoCo "
           f"{d['mujoco']}.", "",
           "| events found at | worlds | wall s | simulation s | events afterwards s | episodes | event bytes | "
           "bytes an episode | of shard bytes | of the bank's bytes |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
  for how, r in c.get("how", {}).items():
    of_bank = f"{r['event_fraction_of_bank']:.1%}" if "event_fraction_of_bank" in r else "—"
    lines.append(f"| {how} | {c['worlds']} | {r['wall_seconds']:.2f} | {r['simulation_seconds']:.2f} | "
                 f"{r['events_seconds']:.2f} | {r['episodes']:,} | {r['event_bytes']:,} | "
                 f"{r['event_bytes'] / max(r['episodes'], 1):.1f} | {r['event_fraction']:.1%} | {of_bank} |")
  if "wall_ratio" in c:
    step, frames = c["how"]["every physics step"], c["how"]["stored frames (baseline)"]
    lines += ["", f"Wall with events at every step / on the stored frames: {c['wall_ratio']:.2f}; the simulation "
              f"alone {step['simulation_seconds'] / frames['simulation_seconds']:.2f}× (reading each step's "
              "contacts). The episodes are about as many (a break shorter than a query point does not end one); "
              "their bytes hold each episode's largest force and impulse as well."]
  for r in d.get("loop_cost", []):
    sim = r["simulation_seconds"]
    lines += ["", f"{r['scene']}, {r['worlds']} worlds, the simulation alone (best of {r['repeats']}, alternating, "
              f"same process): {sim['every physics step']:.2f} s reading every step's contacts, "
              f"{sim['none in the loop']:.2f} s without: **{r['ratio']:.3f}×**."]
  m = d.get("mjx_loop_cost")
  if m:
    sim = m["simulation_seconds"]
    lines += ["", f"{m['scene']}, {m['worlds']} worlds on MJX ({m['backend']}, {m['machine']}), the simulation alone "
              f"(best of {m['repeats']}, alternating, same process): {sim['every physics step']:.2f} s with the "
              f"contact episodes tracked inside the scan at every step, {sim['none in the scan']:.2f} s without: "
              f"**{m['ratio']:.3f}×**."]
  f = d.get("fast")
  if f:
    lines += ["", f"Fast impacts: a ball dropped from 12.5–13.5 m onto a stiff, bouncy floor (about "
              f"{f['impact_speed']:.0f} m/s, a few milliseconds in contact), {f['worlds']} worlds: its stored path "
              f"turns back up at the floor in {f['bounced']}; the events say it touched the floor in "
              f"{f['touch_every_step']} found at every physics step, in {f['touch_stored_frames']} found on the "
              f"stored frames. Impulse of the hardest touch: median {f['impulse_median']:.2f} N·s "
              f"({f['impulse_min']:.2f}–{f['impulse_max']:.2f})."]
  lines += ["", f"Query latency on {lat['worlds']} worlds (the event records of {lat['distinct_worlds']} sampled "
            "worlds repeated), median:", "",
            "| query | ms | vs COM box | worlds met |", "|---|---:|---:|---:|"]
  for name, r in lat["queries"].items():
    lines.append(f"| {name} | {r['ms']:.2f} | {r['vs_baseline']:.2f}× | {r['matches']} |")
  head: list[str] = []  # (the README's front page is full)
  t = d.get("tower")
  if t:
    lines += ["", f"Trebuchet tower, {t['worlds']} worlds ({t['valid']} valid): `rock_hits_tower` (the rock's "
              f"bounding sphere enters the tower's box) {t['box']}, `rock_touches_tower` (a contact event) "
              f"{t['event']}, both {t['both']}; `rock_then_blocks_hit_bystander_0` (in order) "
              f"{t['order_rock_then_bystander_0']}. Events {t['events_seconds']:.1f} s against simulation "
              f"{t['simulation_seconds']:.1f} s."]
  return lines, head


# Seeds from here on were never used while the search was designed; those below were.
FIRST_UNSEEN_SEED = 100


def _solve_time(r: dict) -> float:
  """A run's solve time: its wall time, or, where it ran on a world-step
  budget, its world-steps at the reference rate of a solve alone."""
  return r["world_steps"] / r["reference_rate"] if "reference_rate" in r else r["solve_seconds"]


def _seed_summary(runs: list) -> list[str]:
  """Per scene: solved, median and worst solve time, over the seeds the search
  was never tuned on and, apart, over those it was."""
  lines = []
  for scene in sorted({r["scene"] for r in runs}):
    parts = []
    for label, pick in ((f"unseen seeds (≥ {FIRST_UNSEEN_SEED})", lambda r: r["seed"] >= FIRST_UNSEEN_SEED),
                        ("tuning seeds", lambda r: r["seed"] < FIRST_UNSEEN_SEED)):
      rs = [r for r in runs if r["scene"] == scene and pick(r)]
      if not rs:
        continue
      times = sorted(_solve_time(r) for r in rs if r["solved"])
      when = f", median {statistics.median(times):.0f} s, worst {times[-1]:.0f} s" if times else ""
      budgets = sorted({r["budget_seconds"] for r in rs if "budget_seconds" in r})
      # A search stops after the refinement that crosses its budget: solved in time only within it.
      in_time = sum(r["solved"] and _solve_time(r) <= r["budget_seconds"] + 1e-6 for r in rs if "budget_seconds" in r)
      within = (f" ({in_time} within {', '.join(f'{b:.0f}' for b in budgets)} s)" if budgets and in_time < len(times)
                else f" within {', '.join(f'{b:.0f}' for b in budgets)} s" if budgets else "")
      parts.append(f"{label}: {len(times)} of {len(rs)} solved{within}{when}")
    lines.append(f"* {scene}: " + "; ".join(parts) + ".")
  return lines + [""] if lines else []


def tower(d: dict) -> tuple[list[str], list[str]]:
  off, on, a = d["sample_sleep_off"], d["sample_sleep_on"], d["agreement"]
  r, b = d["refine"], d["refine_baseline"]
  lines = ["## The tower: sleep and refinement", "",
           f"`scripts/bench_tower.py`: `configs/trebuchet_tower.yaml` on the native engine, the same {d['worlds']} "
           "worlds (seed 1) with `sim.sleep: false` and with `sim.sleep: true`, then "
           f"`--objects rock --time 0.8 --samples {d['samples']}` of world 2 of the sleep-on bank, against the "
           "same request with inactive objects moved along the stored path every step instead of held asleep, "
           "and against that with every channel fitted anew and every contact pair tested on the stored frames "
           "as well (the baseline). Contact events are found inside the simulation's steps (their cost is in its "
           "wall time; the events column is what is left to do afterwards). The tower's blocks and bystanders start "
           "asleep (MuJoCo's sleep policy `init`, written by `scripts/make_trebuchet_tower.py`) where sleep is on. "
           f"Machine: {d['machine']}.", "",
           "| sampling | wall s | physics s | world-steps/s | compression s | contact events s | at rest |"
           " 1549 worlds (min, projected) |",
           "|---|---:|---:|---:|---:|---:|---:|---:|"]
  for label, t, key in (("sleep off", off, "sleep_off"), ("sleep on", on, "sleep_on")):
    lines.append(f"| {label} | {t['wall_seconds']:.1f} | {t['physics_seconds']:.1f} | "
                 f"{t['world_steps_per_second']:,.0f} | {t['compression_seconds']:.1f} | {t['events_seconds']:.1f} | "
                 f"{t['at_rest']} | {d['projected_1549_worlds_minutes'][key]} |")
  lines += ["", "The projection holds for worlds like these 64; a struck tower is awake, so it depends on how "
            "often the rock hits. The paper's 1549 worlds by the README's command: [Scale](#scale)."]
  lines += ["", f"Sleep: {d['sleep_speedup_physics']}× the world-steps/s, {d['sleep_speedup_wall']}× the wall. "
            f"Agreement of the outcomes, sleep on against off (Welch z of the means, Bonferroni over "
            f"{len(a['outcomes'])} outcomes at a family-wise 1 %: |z| < {a['z_crit']}): largest |z| "
            f"{a['max_abs_z']}, {'every z passes' if a['all_pass'] else 'NOT every z passes'}; KS below "
            f"{0.01 / len(a['outcomes']):.4f}: {', '.join(n for n, r in a['outcomes'].items() if r['ks_p'] < 0.01 / len(a['outcomes'])) or 'none'}. "
            "The paired columns compare each world with itself (same initial state and perturbation draws). "
            "The knocked-down blocks' path length and collisions are summed over the blocks that end more than "
            "5 cm from their start."]
  if "resting_jitter" in d:
    j = d["resting_jitter"]
    lines[-1] += (" The blocks left standing are not an outcome but are reported: awake they creep and rattle "
                  f"({j['sleep_off']['mean_path_length']} m of path and {j['sleep_off']['mean_collisions']} impacts "
                  f"per world, summed over them), asleep {j['sleep_on']['mean_path_length']} m and "
                  f"{j['sleep_on']['mean_collisions']}.")
  lines += ["",
            "| outcome | mean off | mean on | z | KS p | paired: mean, largest difference |",
            "|---|---:|---:|---:|---:|---:|"]
  for name, row in a["outcomes"].items():
    lines.append(f"| {name} | {row['mean_off']} | {row['mean_on']} | {row['z']} | {row['ks_p']} | "
                 f"{row['paired_mean_abs_diff']}, {row['paired_max_abs_diff']} |")
  lines += ["", "| refinement | wall s | physics s | compression s | contact events s | bytes per world |"
            " active objects (median, max) |", "|---|---:|---:|---:|---:|---:|---:|"]
  variants = [("inactive objects asleep, parent channels reused, active pairs only", r)]
  if "refine_inactive_awake" in d:
    variants.append(("inactive objects moved every step, parent channels reused, active pairs only",
                     d["refine_inactive_awake"]))
  variants.append(("baseline", b))
  if "refine_hit" in d:
    variants.append((f"world {d['refine_hit']['world']} (its rock knocks down most blocks), inactive objects asleep",
                     d["refine_hit"]))
  for label, t in variants:
    lines.append(f"| {label} | {t['wall_seconds']:.1f} | {t['physics_seconds']:.1f} | "
                 f"{t['compression_seconds']:.2f} | {t['events_seconds']:.2f} | {t['bytes_per_world']:,} | "
                 f"{t['active_objects']['median']:g}, {t['active_objects']['max']} |")
  lines += ["", f"Refinement wall: {d['refine_speedup_wall']}× faster than the baseline."]
  if "asleep_object_frames_per_world" in r:
    lines[-1] += (f" Inactive objects held asleep: {r['asleep_object_frames_per_world']:,} object-frames per "
                  "refined world (MuJoCo skips them in every step of those frames).")
  if "refine_hit" in d:
    h = d["refine_hit"]
    lines[-1] += (f" Where the rock hits the tower (world {h['world']}) activation spreads through it "
                  f"({h['active_objects']['median']:g} objects active): the interaction test activates what an "
                  "active object or its ghost may touch, and the tower's blocks rest on one another, so such a "
                  "refinement simulates the whole tower again.")
  return lines, []


def page_refine(d: dict) -> tuple[list[str], list[str]]:
  f, s2 = d["first"], d["second"]
  lines = ["## The tower refined from the page", "",
           f"`scripts/bench_page_refine.py`: a fresh process opens the {d['bank_worlds']}-world tower bank of "
           f"`scripts/bench_tower.py` in the page ({d['page_open_seconds']:.1f} s), plays world {d['world']}, seeks "
           f"to {d['t_min']} s, picks the rock and presses *Refine playing world* ({d['samples']} samples, the "
           "page's default). Timed from the press. Machine: " + d["machine"] + ".", "",
           "| press | new worlds listed (s) | first new world playing (s) |", "|---|---:|---:|",
           f"| first (compiles or cache loads included) | {f['listed_seconds']:.2f} | {f['first_plays_seconds']:.2f} |",
           f"| second | {s2['listed_seconds']:.2f} | {s2['first_plays_seconds']:.2f} |"]
  if "command" in d:
    c = d["command"]
    lines += ["", f"The README's `{c['argv']}` in a fresh process (imports, loading the bank, compiles and saving "
              f"included): {c['wall_seconds']:.1f} s wall (exit {c['exit']}); its report: "
              f"{'; '.join(c['report']) or '-'}."]
  return lines, []


def steps(d: dict) -> tuple[list[str], list[str]]:
  lines = ["## Larger steps with speculative contacts", "",
           "`scripts/bench_steps.py`: per scene and seed the same "
           f"{d['worlds']} worlds as shipped and with the physics step times a factor and MuJoCo's "
           "speculative contacts on; outcomes compared as in the tower's sleep test (Welch z, Bonferroni at a "
           "family-wise 1 %, and KS), and the deepest any body's COM went below the shipped step's lowest. "
           "A factor is safe on a seed only where everything agrees, nothing goes lower and the physics is faster, "
           "and a candidate for the scene's default only where it is safe on every seed measured (seed 1 chose "
           "the scenes to confirm; the others were measured after). The step also changes the perturbation "
           "process: perturbations are drawn per colliding step. The wall of the first run of a process includes "
           f"its warm-up. Scenes not listed are not measured yet. Machine: {d['machine']}.", "",
           "| scene | seed | step | wall s | physics s | world-steps | perturbations / world | largest abs z | "
           "KS fails | deepest below shipped (m) | safe? |", "|---|---:|---|---:|---:|---:|---:|---:|---|---:|---|"]
  verdict: dict[tuple[str, str], list[bool]] = {}
  first = {}
  for run in d["runs"]:
    first.setdefault(run["scene"], len(first))
  for run in sorted(d["runs"], key=lambda r: (first[r["scene"]], r["seed"])):
    name, seed, t = run["scene"], run["seed"], run["shipped"]
    lines.append(f"| {name} | {seed} | {t['timestep'] * 1000:.2f} ms (shipped) | {t['wall_seconds']:.1f} | "
                 f"{t['physics_seconds']:.1f} | {t['world_steps']:,} | {t['mean_perturbations']} | | | | |")
    for factor, t in run["factors"].items():
      verdict.setdefault((name, factor), []).append(t["safe"])
      lines.append(f"| {name} | {seed} | ×{float(factor):g}, speculative | {t['wall_seconds']:.1f} | "
                   f"{t['physics_seconds']:.1f} | {t['world_steps']:,} | {t['mean_perturbations']} | "
                   f"{t['agreement']['max_abs_z']} | {', '.join(t['ks_fails']) or 'none'} | "
                   f"{t['deepest_below_shipped_m']} ({t['deepest_body']}) | {'yes' if t['safe'] else 'no'} |")
  lines += ["", "| scene | factor | seeds safe | candidate for the default? |", "|---|---|---:|---|"]
  for (name, factor), safe in verdict.items():
    answer = "no" if not all(safe) else "one seed only" if len(safe) < 2 else "yes"
    if answer == "yes":
      mjcf = ROOT / "mwbx" / "assets" / f"{name}.xml"
      adopted = mjcf.exists() and 'speculative="enable"' in mjcf.read_text()
      answer += (f", the default (`mwbx/assets/{name}.xml`)" if adopted else
                 " on native; not the default: neither MJX engine has speculative contacts")
    lines.append(f"| {name} | ×{float(factor):g} | {sum(safe)} of {len(safe)} | {answer} |")
  return lines, []


SECTIONS = (("setup", setup), ("sampler", sampler), ("codec", codec), ("queries", queries), ("viewer", viewer),
            ("refine", refinement), ("bank", bank), ("browse", browse), ("browse_100k", browse_bank), ("browse_1m", browse_bank),
            ("geometry", geometry),
            ("geometry_tightness", geometry_tightness), ("scale", scale),
            ("scenes", scenes), ("backends", backends), ("gpu", gpu),
            ("solve", solve), ("events", events), ("flex", flex), ("tower", tower), ("page_refine", page_refine), ("steps", steps))


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--bench", type=pathlib.Path, default=ROOT / "out" / "bench")
  args = parser.parse_args()
  keep = ROOT / "docs" / "bench"
  keep.mkdir(parents=True, exist_ok=True)
  doc = ["# Benchmarks", "",
         "Generated by `scripts/make_benchmarks_doc.py` from the JSON the benchmarks write "
         "(copied to `docs/bench/`); do not edit by hand. Each benchmark measures its baseline in "
         "the same run on the machine named: the machines are shared, so ratios hold where absolute "
         "times drift. Run them all with `make bench`.", ""]
  headline = []
  for name, section in SECTIONS:
    data = _load(args.bench, name)
    if data is None and name == "gpu":
      doc += ["## Batched engines (GPU)", "", "Not measured: no GPU was available to these benchmarks. "
              "`scripts/gpu_check.sh` measures it in one command on a GPU machine (see the README).", ""]
      continue
    if data is None:
      doc += [f"## {name.capitalize()}", "", f"No `{name}.json` in {args.bench} yet.", ""]
      continue
    if args.bench.resolve() != keep.resolve():
      shutil.copy(args.bench / f"{name}.json", keep / f"{name}.json")
    lines, head = section(data)
    doc += lines + [""]
    headline += head
  for extra in ("codec_rd.png", "solve_siggraph.png", "solve_spiral_staircase.png"):
    if (args.bench / extra).exists() and args.bench.resolve() != keep.resolve():
      shutil.copy(args.bench / extra, keep / extra)
  (ROOT / "docs" / "benchmarks.md").write_text("\n".join(doc).rstrip() + "\n")
  readme = ROOT / "README.md"
  text = readme.read_text()
  block = "".join(f"* {h}\n" for h in headline)
  if HEADLINE.search(text):
    readme.write_text(HEADLINE.sub(lambda m: m.group(1) + block + m.group(2), text))
  print(f"wrote {ROOT / 'docs' / 'benchmarks.md'} ({len(headline)} headline figures)")


if __name__ == "__main__":
  main()
