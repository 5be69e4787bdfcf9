"""Check that mwbx's imports point down its layers and never go round in a circle.

Builds the import graph of the `mwbx` package from its source (ast; nothing is
imported), keeping three kinds of edge apart:

  top:      executed when the module is imported (module level, also inside a
            module-level `try`/`if`);
  function: inside a function or method body, executed on first call;
  typing:   under `if TYPE_CHECKING:`, never executed.

It reports

  * every cycle among top-level imports (Python resolves those only by luck
    of the import order);
  * every cycle that function-level imports close (a circle hidden from the
    interpreter, not an absent one);
  * every import, of any kind, from a lower layer to a higher one (`LAYERS`,
    from DESIGN.md's layering: "imports point down");
  * every function-level import of an mwbx module without a comment saying
    why it is lazy (a comment naming "lazy" on its line or just above it):
    imports go at the top of files, except the few that keep `import mwbx`
    light (meshcat, viser, optax, mujoco.mjx behind them);

and exits 1 if it found any, else 0. `--graph` prints every edge.

Usage::

  python scripts/check_imports.py [--graph] [--root DIR]
"""

from __future__ import annotations

import argparse
import ast
import pathlib
import sys
from typing import NamedTuple

# Layers, lowest first; a module may import its own layer and those below.
# Prefixes are matched longest first, so `mwbx.bank` covers the package and
# `mwbx.qpos_store` the one file. `mwbx` (the package itself, which
# re-exports the public API) sits on top with the CLI.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundation", (
        "mwbx.errors", "mwbx.files", "mwbx.host_jit", "mwbx.host_device", "mwbx.joints",
        "mwbx.rotations", "mwbx.progress", "mwbx.yaml_input", "mwbx.distributed",
        "mwbx.world_ids", "mwbx.host_pool",
    )),
    ("scene and kernels", (
        "mwbx.config", "mwbx.rates", "mwbx.scene", "mwbx.controls", "mwbx.perturb",
        "mwbx.codec", "mwbx.events", "mwbx.queries",
    )),
    ("bank", ("mwbx.qpos_store", "mwbx.bank")),
    ("simulation", ("mwbx.batch_sim", "mwbx.refinement")),
    ("front ends", ("mwbx.viewer", "mwbx.browser", "mwbx.search", "mwbx.export", "mwbx.testing")),
    ("command", ("mwbx.cli", "mwbx")),
)

KINDS = ("top", "function", "typing")


class Edge(NamedTuple):
  """One import statement's dependency of `source` on `target`."""
  source: str
  target: str
  kind: str  # one of KINDS
  line: int
  reason: bool = False  # a comment says why it is lazy (function-level imports)


def module_files(root: pathlib.Path) -> dict[str, pathlib.Path]:
  """Maps every module of the `mwbx` package under `root` to its file."""
  modules = {}
  for path in sorted((root / "mwbx").rglob("*.py")):
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
      parts.pop()
    modules[".".join(parts)] = path
  return modules


def _is_type_checking(test: ast.expr) -> bool:
  return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
      isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module):
  """Yields (node, kind) for every import statement in a module."""
  def walk(node, kind):
    for child in ast.iter_child_nodes(node):
      if isinstance(child, (ast.Import, ast.ImportFrom)):
        yield child, kind
      elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
        yield from walk(child, "typing" if kind == "typing" else "function")
      elif isinstance(child, ast.If) and _is_type_checking(child.test):
        for stmt in child.body:
          yield from walk(ast.Module(body=[stmt], type_ignores=[]), "typing")
        for stmt in child.orelse:
          yield from walk(ast.Module(body=[stmt], type_ignores=[]), kind)
      else:
        yield from walk(child, kind)
  yield from walk(tree, "top")


def _resolve(name: str, modules: dict[str, pathlib.Path]) -> str | None:
  """The deepest module of mwbx that `name` (a dotted path) names, if any."""
  parts = name.split(".")
  while parts:
    candidate = ".".join(parts)
    if candidate in modules:
      return candidate
    parts.pop()
  return None


def _says_lazy(lines: list[str], node: ast.stmt) -> bool:
  """Whether a comment on the import's line, or on the comment line above it
  (above any imports right before it), names it lazy."""
  if "lazy" in lines[node.lineno - 1].partition("#")[2].lower():
    return True
  row = node.lineno - 2
  while row >= 0 and lines[row].strip().startswith(("import ", "from ")):
    row -= 1
  return row >= 0 and lines[row].strip().startswith("#") and "lazy" in lines[row].lower()


def import_edges(root: pathlib.Path) -> list[Edge]:
  """Every import among mwbx's own modules, one edge per imported module."""
  modules = module_files(root)
  edges = []
  for module, path in modules.items():
    is_package = path.name == "__init__.py"
    text = path.read_text()
    lines = text.splitlines()
    tree = ast.parse(text, filename=str(path))
    for node, kind in _imports(tree):
      if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
      else:
        if node.level:
          base = module.split(".")
          base = base[:len(base) - node.level + (1 if is_package else 0)]
          prefix = ".".join(base + ([node.module] if node.module else []))
        else:
          prefix = node.module or ""
        # `from pkg import name`: a submodule where `name` is one, else pkg.
        names = [f"{prefix}.{alias.name}" for alias in node.names]
      for name in names:
        target = _resolve(name, modules)
        if target is not None and target != module:
          edges.append(Edge(module, target, kind, node.lineno, _says_lazy(lines, node)))
  return sorted(set(edges), key=lambda e: (e.source, e.line, e.target))


def layer_of(module: str) -> int:
  """Index into LAYERS of the layer `module` belongs to."""
  best, best_len = None, -1
  for index, (_, prefixes) in enumerate(LAYERS):
    for prefix in prefixes:
      if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
        best, best_len = index, len(prefix)
  if best is None:
    raise SystemExit(f"check_imports: {module} is in no layer of LAYERS; add it")
  return best


def upward_imports(edges: list[Edge]) -> list[Edge]:
  """Edges from a lower layer to a higher one."""
  return [e for e in edges if layer_of(e.source) < layer_of(e.target)]


def cycles(edges: list[Edge]) -> list[list[str]]:
  """Strongly connected components (more than one module) of the edges, sorted."""
  graph: dict[str, set[str]] = {}
  for e in edges:
    graph.setdefault(e.source, set()).add(e.target)
    graph.setdefault(e.target, set())
  index, low, on_stack, stack, found = {}, {}, set(), [], []

  def visit(node):  # Tarjan; the graph has ~200 nodes, recursion is fine
    index[node] = low[node] = len(index)
    stack.append(node)
    on_stack.add(node)
    for succ in sorted(graph[node]):
      if succ not in index:
        visit(succ)
        low[node] = min(low[node], low[succ])
      elif succ in on_stack:
        low[node] = min(low[node], index[succ])
    if low[node] == index[node]:
      component = []
      while True:
        member = stack.pop()
        on_stack.discard(member)
        component.append(member)
        if member == node:
          break
      if len(component) > 1:
        found.append(sorted(component))

  for node in sorted(graph):
    if node not in index:
      visit(node)
  return sorted(found)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--root", type=pathlib.Path,
                      default=pathlib.Path(__file__).resolve().parent.parent,
                      help="repository root (holding mwbx/)")
  parser.add_argument("--graph", action="store_true", help="print every edge")
  args = parser.parse_args(argv)
  edges = import_edges(args.root)
  if args.graph:
    for e in edges:
      print(f"{e.kind:8s} {e.source} -> {e.target} (line {e.line})")
  top = [e for e in edges if e.kind == "top"]
  runtime = [e for e in edges if e.kind != "typing"]
  problems = 0
  top_cycles = cycles(top)
  hidden = [c for c in cycles(runtime) if c not in top_cycles]
  for title, found, graph in (("cycle among top-level imports", top_cycles, top),
                              ("cycle closed by function-level imports", hidden, runtime)):
    for component in found:
      problems += 1
      members = set(component)
      print(f"{title}: {', '.join(component)}")
      for e in graph:
        if e.source in members and e.target in members:
          print(f"  {e.source}:{e.line} imports {e.target} ({e.kind})")
  for e in upward_imports(edges):
    problems += 1
    print(f"upward import ({e.kind}): {e.source}:{e.line} "
          f"[{LAYERS[layer_of(e.source)][0]}] imports {e.target} "
          f"[{LAYERS[layer_of(e.target)][0]}]")
  for e in edges:
    if e.kind == "function" and not e.reason:
      problems += 1
      print(f"function-level import without a reason: {e.source}:{e.line} imports {e.target}"
            f" (move it to the top, or say why it is lazy in a comment)")
  kinds = {kind: sum(e.kind == kind for e in edges) for kind in KINDS}
  print(f"check_imports: {len(module_files(args.root))} modules, "
        + ", ".join(f"{n} {k}" for k, n in kinds.items())
        + f" imports; {problems} problem(s)")
  return 1 if problems else 0


if __name__ == "__main__":
  sys.exit(main())
