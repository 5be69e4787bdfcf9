"""Query and ranking latency: mwbx (culled hierarchy) vs brute force.

For banks of growing size (synthetic ballistic COM paths, and optionally a
real sampled bank) it times one include and one exclude screen-box query for
  mwbx        mwbx.queries.evaluate (chunk-box culling + exact float64 test)
  numpy       brute force over every segment, vectorised numpy, float64
  jax-brute   brute force over every segment, one jitted JAX kernel
checks that the three answer sets are identical, and times ranking all
worlds by a metric (mwbx.queries.rank, top-k) against a numpy argsort.
Prints a table and writes JSON to out/bench/queries.json.

  .venv/bin/python scripts/bench_queries.py [--sizes 256,1024,4096] [--real N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import jax
import numpy as np

from mwbx.queries import Camera, Query, ScreenBox, evaluate, load_queries, rank
from mwbx.queries import index as index_lib
from mwbx.queries import paths as query_lib

METRIC_NAMES = ("angular_travel", "rest_time", "collisions", "orientation_error",
                "path_length", "max_height")
FPS = 30.0


class SyntheticBank:
  """The bank attributes queries read, over synthetic arrays."""

  def __init__(self, com: np.ndarray, seed: int = 0):
    w, _, b, _ = com.shape
    rng = np.random.default_rng(seed)
    self.com = com
    self.com_count = np.full(w, com.shape[1], np.int32)
    self.flags = np.ones(w, np.uint8)
    self.flags[rng.random(w) < 0.01] |= 4  # a few unstable worlds
    self.metrics = rng.uniform(0, 5, size=(w, b, len(METRIC_NAMES))).astype(np.float32)
    self.metric_names = METRIC_NAMES
    self.body_names = tuple(f"body{i}" for i in range(b))
    self.body_ids = np.arange(1, b + 1, dtype=np.int32)
    self.world_ids = np.arange(w, dtype=np.int64)
    self.query_fps = FPS

  @property
  def n_worlds(self) -> int:
    return self.com.shape[0]

  @property
  def valid(self) -> np.ndarray:
    return (self.flags & 4) == 0

  def select_bodies(self, names):
    return np.array([self.body_names.index(n) for n in names], np.int32)


def ballistic_paths(w: int, p: int, b: int, seed: int = 0) -> np.ndarray:
  """f32[W, P, B, 3]: thrown bodies falling and bouncing, in a 2 m room."""
  rng = np.random.default_rng(seed)
  t = (np.arange(p, dtype=np.float32) / FPS)[None, :, None]
  out = np.empty((w, p, b, 3), np.float32)
  p0 = rng.uniform([-1, -1, 1], [1, 1, 2], size=(w, 1, b, 3)).astype(np.float32)
  v = rng.normal(0, 1, size=(w, 1, b, 3)).astype(np.float32)
  out[..., :2] = p0[..., :2] + v[..., :2] * t[..., None]
  z = p0[..., 2] + v[..., 2] * t - 4.905 * t * t
  out[..., 2] = np.abs(z) * np.exp(-0.3 * t)
  return out


def numpy_hits(bank, query, chunk_worlds: int = 128) -> np.ndarray:
  """bool[W, B] brute force in numpy with the kernels' float64 arithmetic."""
  normals, offsets, mask, window = query_lib.resolve(bank, query)
  n = normals.astype(np.float64)
  valid = bank.valid
  w_count, p_count, b_count, _ = bank.com.shape
  k = np.arange(p_count - 1, dtype=np.float64)
  u0, u1 = window[0] - k, window[1] - k
  overlap = (u1 >= 0) & (u0 <= 1)
  s0 = np.maximum(u0, 0.0)[None, :, None]
  s1 = np.minimum(u1, 1.0)[None, :, None]
  hits = np.zeros((w_count, b_count), bool)
  for start in range(0, w_count, chunk_worlds):
    p = bank.com[start:start + chunk_worlds][:, :, mask].astype(np.float64)[..., None, :]
    d = ((p[..., 0] * n[:, 0] + p[..., 1] * n[:, 1]) + p[..., 2] * n[:, 2]) - offsets[mask]
    da, db = d[:, :-1], d[:, 1:]
    out_a, out_b = da > 0, db > 0
    entering, exiting = out_a & ~out_b, ~out_a & out_b
    with np.errstate(divide="ignore", invalid="ignore"):
      s = da / np.where(entering | exiting, da - db, 1.0)
    enter = np.maximum(s0, np.max(np.where(entering, s, -np.inf), axis=-1))
    exit_ = np.minimum(s1, np.min(np.where(exiting, s, np.inf), axis=-1))
    hit = ~np.any(out_a & out_b, axis=-1) & (enter <= exit_) & overlap[None, :, None]
    hits[start:start + chunk_worlds, mask] = np.any(hit, axis=1)
  return hits & valid[:, None]


def jax_brute_hits(bank, query) -> np.ndarray:
  normals, offsets, mask, window = query_lib.resolve(bank, query)
  state = query_lib.bank_state(bank)
  return np.asarray(index_lib.brute_force_hits(state.index, normals, offsets, mask, window))


def answer(bank, query, hits) -> np.ndarray:
  mask = query_lib.selection_mask(bank, query.bodies)
  return query_lib.combine(hits, mask, query) & bank.valid


def timed(fn, repeats: int) -> tuple[float, object]:
  """Median seconds of `repeats` calls after one warm-up call."""
  result = fn()
  times = []
  for _ in range(repeats):
    t = time.perf_counter()
    result = fn()
    times.append(time.perf_counter() - t)
  return statistics.median(times), result


def bench_bank(bank, label: str, queries: dict[str, Query], numpy_repeats: int) -> list[dict]:
  rows = []
  t = time.perf_counter()
  jax.block_until_ready(query_lib.path_index(bank))
  build_s = time.perf_counter() - t
  n_segments = bank.n_worlds * bank.com.shape[2] * (bank.com.shape[1] - 1)
  for kind, query in queries.items():
    t_mwbx, a_mwbx = timed(lambda: evaluate(bank, [query]), 7)
    t_jax, a_jax = timed(lambda: answer(bank, query, jax_brute_hits(bank, query)), 2)
    t_np, a_np = timed(lambda: answer(bank, query, numpy_hits(bank, query)), numpy_repeats)
    identical = bool(np.array_equal(a_mwbx, a_np) and np.array_equal(a_mwbx, a_jax))
    rows.append(dict(bank=label, worlds=bank.n_worlds, bodies=bank.com.shape[2],
                     points=bank.com.shape[1], segments=n_segments, query=kind,
                     matches=int(a_mwbx.sum()), mwbx_ms=t_mwbx * 1e3, numpy_ms=t_np * 1e3,
                     jax_brute_ms=t_jax * 1e3, speedup_vs_numpy=t_np / t_mwbx,
                     speedup_vs_jax_brute=t_jax / t_mwbx, identical=identical,
                     index_build_s=build_s))
  t_rank, _ = timed(lambda: rank(bank, "path_length:sum", top=10), 20)
  t_sort, _ = timed(lambda: np.argsort(
      -np.where(bank.valid, bank.metrics[:, :, 4].sum(axis=1), -np.inf), kind="stable")[:10], 20)
  for r in rows:
    r.update(rank_ms=t_rank * 1e3, numpy_argsort_ms=t_sort * 1e3)
  return rows


def scene_queries(camera: Camera, bodies: tuple[str, ...]) -> dict[str, Query]:
  """One include and one exclude box on one body, and an include box on any
  of all bodies (every path of the bank is then a candidate)."""
  return {
      "include": Query.screen(camera, ScreenBox(0.55, 0.55, 0.7, 0.75), bodies=bodies[:1]),
      "exclude": Query.screen(camera, ScreenBox(0.2, 0.3, 0.45, 0.5), bodies=bodies[1:2],
                              sign="exclude"),
      "incl-all": Query.screen(camera, ScreenBox(0.62, 0.2, 0.64, 0.22)),
  }


def real_bank(n_worlds: int):
  import mwbx  # the sampler; only needed for --real
  return mwbx.sample(mwbx.load_config("configs/quickstart.yaml"), n_worlds=n_worlds,
                     key=jax.random.key(0))


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--sizes", default="256,1024,4096", help="world counts (16 bodies, 300 points)")
  parser.add_argument("--bodies", type=int, default=16)
  parser.add_argument("--points", type=int, default=300)
  parser.add_argument("--real", type=int, default=0, help="also a real quickstart bank of N worlds")
  parser.add_argument("--out", default="out/bench/queries.json")
  args = parser.parse_args()

  camera = Camera.look_at([0.0, -4.0, 1.5], [0.0, 0.0, 0.8], fovy=50, aspect=4 / 3)
  rows = []
  for w in [int(s) for s in args.sizes.split(",")]:
    bank = SyntheticBank(ballistic_paths(w, args.points, args.bodies, seed=w))
    rows += bench_bank(bank, "synthetic", scene_queries(camera, bank.body_names),
                      1 if w >= 2048 else 3)
    del bank
    query_lib._CACHE.clear()
  if args.real:
    bank = real_bank(args.real)
    example = load_queries("configs/queries/quickstart.yaml", bank)
    queries = {q.name.split("_")[0] + "-" + q.name.split("_")[-1]: q for q in example.queries}
    rows += bench_bank(bank, "quickstart", queries, 3)

  header = (f"{'bank':<10} {'W':>5} {'B':>3} {'P':>4} {'segments':>9} {'query':<8} {'match':>5} "
            f"{'mwbx ms':>8} {'numpy ms':>9} {'jax-brute':>9} {'vs numpy':>8} {'vs jax':>7} "
            f"{'same':>5} {'rank ms':>7} {'argsort':>7}")
  print(header)
  for r in rows:
    print(f"{r['bank']:<10} {r['worlds']:>5} {r['bodies']:>3} {r['points']:>4} {r['segments']:>9} "
          f"{r['query']:<8} {r['matches']:>5} {r['mwbx_ms']:>8.1f} {r['numpy_ms']:>9.0f} "
          f"{r['jax_brute_ms']:>9.0f} {r['speedup_vs_numpy']:>7.0f}x {r['speedup_vs_jax_brute']:>6.0f}x "
          f"{str(r['identical']):>5} {r['rank_ms']:>7.2f} {r['numpy_argsort_ms']:>7.2f}")
  machine = f"{os.cpu_count()}-core {platform.machine()} CPU, {jax.devices()[0].platform}"
  load = os.getloadavg()
  print(f"machine: {machine}, load average {load[0]:.1f} (shared); "
        f"baseline: brute-force numpy (float64, same arithmetic)")
  largest = max(r["segments"] for r in rows if r["bank"] == "synthetic")
  big = [r for r in rows if r["segments"] == largest]
  print(f"largest bank ({largest:,} segments): slowest query {max(r['mwbx_ms'] for r in big):.1f} ms"
        f" (target <= 50), least speed-up vs numpy {min(r['speedup_vs_numpy'] for r in big):.0f}x"
        f" (target >= 5), ranking {big[0]['rank_ms']:.2f} ms (target <= 5),"
        f" answers identical: {all(r['identical'] for r in rows)}")
  os.makedirs(os.path.dirname(args.out), exist_ok=True)
  with open(args.out, "w") as f:
    json.dump(dict(machine=machine, load_average=load, jax=jax.__version__, rows=rows), f,
              indent=1)
  print(f"wrote {args.out}")
  if not all(r["identical"] for r in rows):
    raise SystemExit("answers differ between mwbx and the brute-force references")


if __name__ == "__main__":
  main()
