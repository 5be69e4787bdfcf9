"""The paper's workflow on its §6 scenes, with the public API.

For a scene (``siggraph``, ``spiral_staircase``, ``refrigerator_toy``, and
``chain_reaction``, a shipped contraption rather than a paper scene, and the
flex scenes ``tablecloth`` and ``soft_steps``):
sample worlds, run the scene's query file, report how many worlds satisfy
each query and all of them, then repair the best world as the paper's user
does (§5-6), here unattended with `mwbx.solve`: refine the objects of its
unmet queries from a time before they go wrong, keep the best children,
back-track when stuck. Optionally writes a picture of the best world through
the viewer (the HTML export, screenshotted by headless Chromium).

  .venv/bin/python scripts/paper_scenes.py siggraph --worlds 256 --rounds 12
  .venv/bin/python scripts/paper_scenes.py spiral_staircase --worlds 128 --picture docs/scene_staircase.png
  .venv/bin/python scripts/paper_scenes.py refrigerator_toy --backend mjx --worlds 16 --rounds 0
  .venv/bin/python scripts/paper_scenes.py siggraph --bank out/bench/solve_siggraph_seed0 --picture docs/scene_siggraph.png

With ``--bank`` a saved bank (e.g. one that scripts/bench_solve.py
--save-banks kept) is pictured instead: ``--world`` or its world meeting the
most queries (the latest of equals: the solver's newest).
"""

import argparse
import pathlib
import tempfile
import time

import jax
import numpy as np

import mwbx
from mwbx.progress import reporter

REPO = pathlib.Path(__file__).resolve().parents[1]
# Where each scene's paths are drawn from in the picture (meshcat view direction).
VIEW = {"siggraph": (0.0, -1.0, 0.15), "refrigerator_toy": (0.0, -1.0, 0.15),
        "spiral_staircase": (1.0, -1.4, 1.0), "chain_reaction": (0.0, -1.0, 0.15),
        "tablecloth": (0.3, -1.0, 0.7), "soft_steps": (0.2, -1.0, 0.4)}


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("scene", choices=sorted(VIEW))
  parser.add_argument("--worlds", type=int, default=128)
  parser.add_argument("--rounds", type=int, default=8, help="refinements mwbx.solve may make")
  parser.add_argument("--samples", type=int, default=32, help="refined worlds per round")
  parser.add_argument("--backend", default="native")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", type=pathlib.Path, help="save the bank here")
  parser.add_argument("--picture", type=pathlib.Path, help="write a PNG of the best world here")
  parser.add_argument("--bank", type=pathlib.Path, help="picture this saved bank's world (no sampling)")
  parser.add_argument("--world", type=int, help="with --bank: the world to picture")
  args = parser.parse_args()
  if args.bank:
    bank = mwbx.Bank.load(args.bank)
    queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{args.scene}.yaml", bank=bank)
    met = mwbx.evaluate_each(bank, queries).sum(axis=1)
    world = args.world if args.world is not None else int(bank.world_ids[np.flatnonzero(met == met.max())[-1]])
    print(f"world {world}: {int(met[bank.row_of(world)])} of {len(queries.queries)} queries met")
    if args.picture:
      picture(bank, world, args.scene, args.picture)
    return

  config = mwbx.load_config(REPO / "configs" / f"{args.scene}.yaml")
  start = time.perf_counter()
  with mwbx.Sampler(config, backend=args.backend) as sampler:
    bank, stats = sampler.run(args.worlds, jax.random.key(args.seed), progress=reporter("sample"))
  print(f"sampled {bank.n_worlds} worlds on {stats.backend} in {stats.wall_seconds:.1f} s:"
        f" {int(bank.valid.sum())} valid, {int((~bank.valid).sum())} unstable or stopped by MuJoCo errors")
  queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{args.scene}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  for q, n in zip(queries.queries, each.sum(axis=0)):
    print(f"  {q.name:<32} {int(n):>6} of {bank.n_worlds}")
  print(f"  {'all of them':<32} {int(each.all(axis=1).sum()):>6} of {bank.n_worlds}")
  per_query = each[bank.valid].mean(axis=0)
  print(f"  independent-query estimate of plain sampling: {np.prod(per_query):.2e} per world")

  # The repair (§5-6), unattended: mwbx.solve refines the objects of the best
  # world's unmet queries from before they go wrong, keeps the best children
  # and back-tracks when stuck.
  world = int(bank.world_ids[np.argmax(each.sum(axis=1))])
  if args.rounds > 0:
    with reporter("solve") as update:
      result = mwbx.solve(bank, queries, budget=args.rounds, key=jax.random.key(1000), samples=args.samples,
                          backend=args.backend, progress=update)
    bank, world = result.bank, result.world
    print(result.message)
  print(f"best world {world}; {time.perf_counter() - start:.0f} s wall in all")
  if args.out:
    bank.save(args.out)
    print(f"bank written to {args.out}")
  if args.picture:
    picture(bank, world, args.scene, args.picture)


def picture(bank: mwbx.Bank, world: int, scene: str, path: pathlib.Path) -> None:
  """A PNG of ``world`` at its last frame through the viewer (HTML export,
  screenshotted by headless Chromium)."""
  from PIL import Image
  from mwbx.testing.headless import screenshot

  with tempfile.TemporaryDirectory() as tmp:
    page = mwbx.export_html(bank, pathlib.Path(tmp) / "scene.html", worlds=[world],
                            paths=None, view_dir=VIEW[scene])
    end = (int(bank.frame_count[bank.row_of(world)]) - 1) / bank.record_fps
    Image.fromarray(screenshot(page.as_uri(), seek_s=end, size=(640, 480))).save(path)
  print(f"picture of world {world} written to {path}")


if __name__ == "__main__":
  main()
