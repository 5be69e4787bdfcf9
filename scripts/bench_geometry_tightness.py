"""How tight whole-geometry answers are: small region boxes on a crate pile.

A scene the tests never use: 16 crates and 4 balls dropped onto a tilted
board (``--worlds`` worlds). ``--boxes`` axis-aligned region boxes (half-sizes
5-30 mm) are centred on crate surface points late in the run of some world,
and each is asked as a whole-geometry include query over the whole run.

References, computed here from the decoded frames with MuJoCo's kinematics
and plain geometry (box against box by the separating-axis test, sphere
against box by the distance), independent of mwbx's query code:
  * exact: some crate or ball meets the box at some stored frame;
  * with margin: some geom comes within the codec's bound of the box at
    some stored frame (the bound the answers state); box-geom distances from surface points
    1 mm apart (at the frames the separating-axis gap leaves open).
Counted for mwbx's answers, and for the kept frames' margins alone (the
answers before hits were settled on the stored frames): false negatives
against the exact reference, extras (answers the exact reference does not
have) with how far their geoms stayed from the box, and extras beyond the
reference with margin. Also the query times (first, settling decoded on
demand; then afresh with the stored frames kept).

Writes out/bench/geometry_tightness.json. Usage:

  .venv/bin/python scripts/bench_geometry_tightness.py [--worlds 24] [--boxes 40]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import platform
import time

import jax
import mujoco
import numpy as np

import mwbx
from mwbx import queries as mq
from mwbx.queries import geometry as geometry_lib
from mwbx.queries import geometry_query

from bench_geometry import _commit  # the geometry bench's commit stamp (scripts/ is on the path)

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPACING = 0.001  # m between surface points of the distance reference
CLOSEST = 4  # frames of least separating-axis gap per world and crate measured by surface points
N_CRATES, N_BALLS = 16, 4


def scene_files(folder: pathlib.Path) -> pathlib.Path:
  """Writes the crate scene's MJCF and config; returns the config's path."""
  rng = np.random.default_rng(7)
  bodies = []
  for i in range(N_CRATES):
    x, y = -0.24 + 0.16 * (i % 4), -0.24 + 0.16 * (i // 4)
    half = rng.uniform(0.025, 0.06, 3)
    bodies.append(f'<body name="crate_{i}" pos="{x:.3f} {y:.3f} {0.7 + 0.05 * (i % 3):.3f}" '
                  f'euler="{rng.uniform(0, 40):.1f} {rng.uniform(0, 40):.1f} 0"><freejoint/>'
                  f'<geom type="box" size="{half[0]:.3f} {half[1]:.3f} {half[2]:.3f}" mass="0.3" rgba=".7 .5 .3 1"/></body>')
  for i in range(N_BALLS):
    bodies.append(f'<body name="ball_{i}" pos="{-0.2 + 0.13 * i:.3f} 0.05 1.0"><freejoint/>'
                  f'<geom type="sphere" size="{0.03 + 0.005 * i:.3f}" mass="0.2" rgba=".2 .4 .8 1"/></body>')
  mjcf = f"""<mujoco model="crate_pile">
  <option timestep="0.002"/>
  <worldbody>
    <light pos="0 0 3"/>
    <camera name="front" pos="0 -2.2 1.2" xyaxes="1 0 0 0 0.5 0.87"/>
    <geom type="plane" size="2 2 0.1" rgba=".8 .8 .8 1"/>
    <geom name="board" type="box" size="0.5 0.5 0.02" pos="0 0 0.25" euler="0 14 0" rgba=".4 .6 .4 1"/>
    {chr(10).join('    ' + b for b in bodies)}
  </worldbody>
</mujoco>
"""
  folder.mkdir(parents=True, exist_ok=True)
  (folder / "crate_pile.xml").write_text(mjcf)
  crates = ", ".join(f"crate_{i}" for i in range(N_CRATES))
  balls = ", ".join(f"ball_{i}" for i in range(N_BALLS))
  (folder / "crate_pile.yaml").write_text(f"""scene:
  mjcf: crate_pile.xml
  groups:
    crates: [{crates}]
    balls: [{balls}]
randomize:
  crates:
    position: {{dist: uniform, scale: [0.02, 0.02, 0.0]}}
    rotation: {{dist: normal, scale: 0.1}}
  balls:
    position: {{dist: uniform, scale: [0.03, 0.03, 0.0]}}
sim:
  end_time: 3.0
  backend: native
perturb:
  alpha: 0.1
""")
  return folder / "crate_pile.yaml"


@dataclasses.dataclass
class Geoms:
  """Decoded geom poses of every world at every stored frame (the last held past a world's end)."""

  body: np.ndarray  # i64[G] tracked body index of each geom
  kind: np.ndarray  # i64[G] mjGEOM_BOX or mjGEOM_SPHERE
  size: np.ndarray  # f64[G, 3] half-sizes (sphere: radius first)
  pos: np.ndarray  # f64[W, T, G, 3]
  mat: np.ndarray  # f64[W, T, G, 3, 3]


def geom_poses(bank) -> Geoms:
  model = bank.model
  data = mujoco.MjData(model)
  body_index = {int(b): i for i, b in enumerate(bank.body_ids)}
  geoms = np.array([g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in body_index])
  n_frames = int(np.max(bank.frame_count))
  pos = np.zeros((bank.n_worlds, n_frames, len(geoms), 3))
  mat = np.zeros((bank.n_worlds, n_frames, len(geoms), 3, 3))
  for w in range(bank.n_worlds):
    q = bank.qpos_store.row_frames(w)
    for j in range(n_frames):
      data.qpos[:] = q[min(j, len(q) - 1)]
      mujoco.mj_kinematics(model, data)
      pos[w, j] = data.geom_xpos[geoms]
      mat[w, j] = data.geom_xmat[geoms].reshape(-1, 3, 3)
  return Geoms(np.array([body_index[int(model.geom_bodyid[g])] for g in geoms]), model.geom_type[geoms].astype(int),
               model.geom_size[geoms].astype(np.float64), pos, mat)


def box_gap(centre, half, pos, mat, size) -> np.ndarray:
  """Separating-axis gap of an axis-aligned box and oriented boxes: f64[...],
  the largest separation along the 15 axes (0 where they meet; never more
  than their distance)."""
  d = pos - centre  # [..., 3]
  axes = [np.broadcast_to(np.eye(3)[a], d.shape) for a in range(3)]
  axes += [mat[..., :, a] for a in range(3)]
  axes += [np.cross(np.eye(3)[a], mat[..., :, b]) for a in range(3) for b in range(3)]
  gap = np.zeros(d.shape[:-1])
  for axis in axes:
    norm = np.linalg.norm(axis, axis=-1)
    ok = norm > 1e-9
    u = axis / np.where(ok, norm, 1.0)[..., None]
    r_box = np.abs(u) @ half
    r_geom = np.sum(np.abs(np.einsum("...ia,...i->...a", mat, u)) * size, axis=-1)
    gap = np.maximum(gap, np.where(ok, np.abs(np.sum(d * u, axis=-1)) - r_box - r_geom, 0.0))
  return gap


def point_box_distance(points, centre, half) -> np.ndarray:
  return np.linalg.norm(np.maximum(np.abs(points - centre) - half, 0.0), axis=-1)


def box_surface(size) -> np.ndarray:
  """Points on a box's surface, SPACING apart (box frame)."""
  out = []
  for a in range(3):
    b, c = [x for x in range(3) if x != a]
    u = np.linspace(-size[b], size[b], max(2, int(np.ceil(2 * size[b] / SPACING)) + 1))
    v = np.linspace(-size[c], size[c], max(2, int(np.ceil(2 * size[c] / SPACING)) + 1))
    uu, vv = np.meshgrid(u, v, indexing="ij")
    for sgn in (-1.0, 1.0):
      p = np.zeros((uu.size, 3))
      p[:, a], p[:, b], p[:, c] = sgn * size[a], uu.ravel(), vv.ravel()
      out.append(p)
  return np.concatenate(out)


def box_distances(geoms: Geoms, centre, half, margin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """(meets bool[W]: some geom meets the box at some stored frame; within
  bool[W]: some geom comes within its frame's margin f64[W, T, G] (+ SPACING);
  closest f64[W]: how near the geoms came). Spheres exactly; boxes by the
  separating-axis gap (a lower bound on the distance) and, at the frames that
  gap cannot decide and the CLOSEST frames of least gap, surface points
  SPACING apart."""
  n_worlds = geoms.pos.shape[0]
  meets = np.zeros(n_worlds, bool)
  within = np.zeros(n_worlds, bool)
  closest = np.full(n_worlds, np.inf)
  for g in range(len(geoms.kind)):
    p, m = geoms.pos[:, :, g], geoms.mat[:, :, g]
    if geoms.kind[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
      dist = np.maximum(point_box_distance(p, centre, half) - geoms.size[g, 0], 0.0)
      meets |= (dist <= 0.0).any(axis=1)
      within |= (dist <= margin[:, :, g] + SPACING).any(axis=1)
      closest = np.minimum(closest, dist.min(axis=1))
      continue
    gap = box_gap(centre, half, p, m, geoms.size[g])
    meets |= (gap <= 0.0).any(axis=1)
    surf = box_surface(geoms.size[g])

    def distance(w: int, j: int) -> float:
      return float(point_box_distance(p[w, j] + surf @ m[w, j].T, centre, half).min())

    for w in range(n_worlds):
      if (gap[w] <= 0.0).any():
        within[w] = True
        closest[w] = 0.0
        continue
      for j in np.flatnonzero(gap[w] <= margin[w, :, g] + SPACING):  # the gap cannot decide these
        if not within[w] and distance(w, j) <= margin[w, j, g] + SPACING:
          within[w] = True
      for j in np.argsort(gap[w])[:CLOSEST]:
        closest[w] = min(closest[w], distance(w, j))
  return meets, within, closest


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--worlds", type=int, default=24)
  parser.add_argument("--boxes", type=int, default=40)
  parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "bench" / "geometry_tightness.json")
  args = parser.parse_args()
  config = scene_files(ROOT / "out" / "bench" / "crate_pile")
  t0 = time.perf_counter()
  bank = mwbx.sample(mwbx.load_config(config), args.worlds, jax.random.key(0))
  sample_s = time.perf_counter() - t0
  geoms = geom_poses(bank)
  valid = np.asarray(bank.valid, bool)
  index = geometry_lib.geometry_index(bank)
  n_frames = geoms.pos.shape[1]
  # The stated bound at every stored frame: the codec's, plus the float tolerance of the index's poses.
  margin = np.broadcast_to(index.codec[geoms.body] + index.tol, (bank.n_worlds, n_frames, len(geoms.body)))

  rng = np.random.default_rng(1)
  crates = np.flatnonzero(geoms.kind == mujoco.mjtGeom.mjGEOM_BOX)
  rows = []
  kept_only = dataclasses.replace(index, stored=None, answers={})
  first_ms, again_ms = [], []
  for k in range(args.boxes):
    w, g = int(rng.integers(bank.n_worlds)), int(rng.choice(crates))
    j = int(rng.integers(int(0.7 * (bank.frame_count[w] - 1)), int(bank.frame_count[w])))
    local = box_surface(geoms.size[g])
    centre = geoms.pos[w, j, g] + geoms.mat[w, j, g] @ local[rng.integers(len(local))]
    half = np.full(3, rng.uniform(0.005, 0.03))
    query = mq.Query.region(centre - half, centre + half, shape="geometry")
    t = time.perf_counter()
    ours = mq.evaluate_each(bank, [query])[:, 0]
    first_ms.append(1e3 * (time.perf_counter() - t))
    index.answers.clear()
    t = time.perf_counter()
    again = mq.evaluate_each(bank, [query])[:, 0]
    again_ms.append(1e3 * (time.perf_counter() - t))
    assert np.array_equal(ours, again)
    frustum = mq.Frustum.box(centre - half, centre + half)
    kept = geometry_query.geometry_hits(kept_only, frustum, np.ones(len(bank.body_names), bool), None).any(axis=1)
    exact, within_margin, closest = box_distances(geoms, centre, half, margin)
    rows.append({"ours": ours, "kept": kept, "exact": exact & valid, "margin": within_margin & valid,
                 "closest": closest})
    print(f"box {k + 1}/{args.boxes}: {int(ours.sum())} answers, {int(exact.sum())} exact, {int(kept.sum())} with"
          f" the kept frames' margins; {first_ms[-1]:.0f} ms", flush=True)

  def tally(key: str) -> dict:
    answers = np.stack([r[key] for r in rows])
    exact = np.stack([r["exact"] for r in rows])
    extra = answers & ~exact
    closest = np.stack([r["closest"] for r in rows])[extra]
    beyond = answers & ~np.stack([r["margin"] for r in rows])
    return {"answers": int(answers.sum()), "false_negatives": int((exact & ~answers).sum()),
            "extras": int(extra.sum()), "extras_share": float(extra.sum() / max(answers.sum(), 1)),
            "extra_distance_mm": {"median": float(np.median(closest) * 1e3) if closest.size else 0.0,
                                  "p90": float(np.percentile(closest, 90) * 1e3) if closest.size else 0.0,
                                  "max": float(closest.max() * 1e3) if closest.size else 0.0},
            "beyond_margin_reference": int(beyond.sum()),
            "beyond_margin_share": float(beyond.sum() / max(answers.sum(), 1))}

  result = {
      "machine": f"{platform.machine()}, {os.cpu_count()} cores", "commit": _commit(),
      "load_average": os.getloadavg()[0], "worlds": bank.n_worlds, "boxes": args.boxes,
      "bodies": len(bank.body_names), "record_fps": float(bank.record_fps), "query_fps": float(bank.query_fps),
      "sample_s": sample_s, "exact_reference_hits": int(sum(r["exact"].sum() for r in rows)),
      "settled": tally("ours"), "kept_frames_only": tally("kept"),
      "query_ms": {"first_median": float(np.median(first_ms)), "first_max": float(np.max(first_ms)),
                   "again_median": float(np.median(again_ms))},
  }
  s, b = result["settled"], result["kept_frames_only"]
  print(f"{bank.n_worlds} worlds, {args.boxes} boxes: {result['exact_reference_hits']} exact hits; settled answers"
        f" {s['answers']} ({s['false_negatives']} missed, {s['extras']} extra = {100 * s['extras_share']:.1f} %,"
        f" median {s['extra_distance_mm']['median']:.1f} mm away, {s['beyond_margin_reference']} beyond the margin"
        f" reference); kept frames alone {b['answers']} ({b['false_negatives']} missed, {b['extras']} extra ="
        f" {100 * b['extras_share']:.1f} %, median {b['extra_distance_mm']['median']:.1f} mm, p90"
        f" {b['extra_distance_mm']['p90']:.1f} mm); query median {result['query_ms']['first_median']:.1f} ms first,"
        f" {result['query_ms']['again_median']:.1f} ms again")
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(result, indent=2))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
