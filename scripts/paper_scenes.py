"""The paper's workflow on its §6 scenes, with the public API.

For a scene (``siggraph``, ``spiral_staircase``, ``refrigerator_toy``):
sample worlds, run the scene's query file, report how many worlds satisfy
each query and all of them, then repair the best world as the paper's user
does (§5-6): refine the objects of its unmet queries from a time before they
go wrong, keep the child that satisfies the most queries (fewest collisions
on ties), and repeat. Optionally writes a picture of the best world through
the viewer (the HTML export, screenshotted by headless Chromium).

  .venv/bin/python scripts/paper_scenes.py siggraph --worlds 256 --rounds 12
  .venv/bin/python scripts/paper_scenes.py spiral_staircase --worlds 128 --picture docs/scene_staircase.png
  .venv/bin/python scripts/paper_scenes.py refrigerator_toy --backend mjx --worlds 16 --rounds 0
"""

import argparse
import pathlib
import sys
import tempfile
import time

import jax
import numpy as np

import mwbx
from mwbx.progress import reporter

REPO = pathlib.Path(__file__).resolve().parents[1]
# Where each scene's paths are drawn from in the picture (meshcat view direction).
VIEW = {"siggraph": (0.0, -1.0, 0.15), "refrigerator_toy": (0.0, -1.0, 0.15),
        "spiral_staircase": (1.0, -1.4, 1.0)}


def involved_objects(bank, query) -> list[str]:
  """Objects whose motion decides a query: its bodies' objects, or the
  object a joint query's hinge belongs to."""
  if isinstance(query, mwbx.JointQuery):
    model = bank.model()
    body = model.jnt_bodyid[model.joint(query.joint).id]
    root = model.body(int(model.body_rootid[body])).name
    return [root]
  if query.bodies is None:
    return list(bank.objects)
  chosen = {bank.body_names[b] for b in bank.select_bodies(list(query.bodies)).tolist()}
  return [obj for obj, bodies in bank.objects.items() if chosen & set(bodies)]


def restart_time(bank, world: int, query, objects) -> float:
  """A time before the query's objects go wrong: half-way to the first entry
  of the query's region where there is one, else a third into the world."""
  end = (int(bank.frame_count[bank.row_of(world)]) - 1) / bank.record_fps
  if getattr(query, "frustum", None) is not None and query.include:
    t = mwbx.first_entry(bank, world, objects, query.frustum)
    if t is not None:
      return 0.5 * t
  return end / 3


def best(bank, met, rows) -> int:
  """World id among ``rows`` with the most queries met (``met``: i32[W]),
  fewest collisions on ties."""
  collisions = mwbx.queries.metric(bank, "collisions")[rows]
  order = np.lexsort((collisions, -met[rows]))
  return int(bank.world_ids[rows[order[0]]])


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("scene", choices=sorted(VIEW))
  parser.add_argument("--worlds", type=int, default=128)
  parser.add_argument("--rounds", type=int, default=8, help="refinement rounds on the best world")
  parser.add_argument("--samples", type=int, default=32, help="refined worlds per round")
  parser.add_argument("--backend", default="native")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", type=pathlib.Path, help="save the bank here")
  parser.add_argument("--picture", type=pathlib.Path, help="write a PNG of the best world here")
  args = parser.parse_args()

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

  met = each.sum(axis=1)  # queries met per world (0 if unstable), kept up to date with the bank
  world = best(bank, met, np.flatnonzero(bank.valid))
  n_queries = len(queries.queries)
  print(f"best sampled world {world}: {met[bank.row_of(world)]} of {n_queries} queries")
  refinements = 0
  for round_ in range(args.rounds):
    if met[bank.row_of(world)] == n_queries:
      break
    unmet = [q for q, ok in zip(queries.queries, each[bank.row_of(world)]) if not ok]
    query = unmet[round_ % len(unmet)]
    objects = involved_objects(bank, query)
    t_min = restart_time(bank, world, query, objects)
    before = bank.n_worlds
    bank = mwbx.refine(bank, world, objects, t_min=t_min, n_samples=args.samples,
                       key=jax.random.key(1000 + round_), backend=args.backend)
    refinements += 1
    each = mwbx.evaluate_each(bank, queries)
    met = each.sum(axis=1)
    children = np.arange(before, bank.n_worlds)
    children = children[bank.valid[children]]
    if children.size:
      child = best(bank, met, children)
      if met[bank.row_of(child)] >= met[bank.row_of(world)]:
        world = child
    print(f"round {round_ + 1}: refined {', '.join(objects)} from {t_min:.2f} s for {query.name}:"
          f" best world {world} meets {met[bank.row_of(world)]} of {n_queries}")
  wall = time.perf_counter() - start
  print(f"found world {world}: {met[bank.row_of(world)]} of {n_queries} queries after {refinements} refinements,"
        f" {wall:.0f} s wall in all")
  if args.out:
    bank.save(args.out)
    print(f"bank written to {args.out}")
  if args.picture:
    sys.path.insert(0, str(REPO / "tests"))
    from PIL import Image
    from viewer_render import screenshot

    with tempfile.TemporaryDirectory() as tmp:
      page = mwbx.export_html(bank, pathlib.Path(tmp) / "scene.html", worlds=[world],
                              paths=None, view_dir=VIEW[args.scene])
      end = (int(bank.frame_count[bank.row_of(world)]) - 1) / bank.record_fps
      Image.fromarray(screenshot(page.as_uri(), seek_s=end, size=(640, 480))).save(args.picture)
    print(f"picture of world {world} written to {args.picture}")


if __name__ == "__main__":
  main()
