"""mwbx's floors: imports point down its layers, never in a circle, and
`import mwbx` stays light (scripts/check_imports.py, docs/layout.md)."""

import pathlib
import subprocess
import sys
import textwrap

REPO = pathlib.Path(__file__).parent.parent
CHECK = REPO / "scripts" / "check_imports.py"


def _check(root: pathlib.Path) -> subprocess.CompletedProcess:
  return subprocess.run([sys.executable, str(CHECK), "--root", str(root)], capture_output=True, text=True,
                        timeout=300)


def test_mwbx_imports_have_no_cycle_and_point_down():
  out = _check(REPO)
  assert out.returncode == 0, out.stdout + out.stderr
  assert "; 0 problem(s)" in out.stdout


def _package(root: pathlib.Path, files: dict[str, str]) -> None:
  for name, text in files.items():
    path = root / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))


def test_the_check_finds_cycles_upward_and_unexplained_lazy_imports(tmp_path):
  """A made-up mwbx with one of each problem: the check names every one and
  fails; explained lazy imports and downward imports pass."""
  _package(tmp_path, {
      "mwbx/__init__.py": "from mwbx.bank import core\n",
      "mwbx/errors.py": "",
      "mwbx/scene.py": """\
          def f():
            from mwbx.batch_sim import sampler  # lazy: made up
          """,
      "mwbx/bank/__init__.py": "",
      "mwbx/bank/core.py": "from mwbx.bank import shards\nfrom mwbx import errors\n",
      "mwbx/bank/shards.py": "from mwbx.bank.core import thing\n",
      "mwbx/batch_sim/__init__.py": "",
      "mwbx/batch_sim/sampler.py": "from mwbx.batch_sim import budget\nimport mwbx.bank\n",
      "mwbx/batch_sim/budget.py": """\
          def pilot():
            from mwbx.batch_sim.sampler import Sampler
          """,
      "mwbx/cli.py": """\
          import mwbx.scene

          def view():
            # Lazy on purpose: made up.
            import mwbx.viewer
          """,
      "mwbx/viewer/__init__.py": "",
  })
  out = _check(tmp_path)
  assert out.returncode == 1, out.stdout
  lines = out.stdout.splitlines()
  assert "cycle among top-level imports: mwbx.bank.core, mwbx.bank.shards" in lines
  assert ("cycle closed by function-level imports: mwbx.batch_sim.budget, mwbx.batch_sim.sampler" in lines)
  assert any(l.startswith("upward import (function): mwbx.scene:2 [scene and kernels] imports "
                          "mwbx.batch_sim.sampler [simulation]") for l in lines)
  unexplained = [l for l in lines if l.startswith("function-level import without a reason")]
  assert len(unexplained) == 1 and "mwbx.batch_sim.budget:2 imports mwbx.batch_sim.sampler" in unexplained[0]
  assert "; 4 problem(s)" in out.stdout
  assert not any("mwbx.cli" in l or "mwbx.viewer" in l for l in lines)


def test_import_mwbx_leaves_the_viewer_page_search_and_mjx_unloaded():
  """`import mwbx` and the CLI module do not pay for meshcat, viser, optax or
  mujoco.mjx; `mwbx.view` and `mwbx.solve` load theirs on first use (the page
  imports viser when it starts serving)."""
  code = ("import sys, mwbx, mwbx.cli; heavy = ('meshcat', 'viser', 'optax', 'mujoco.mjx');"
          "print(sorted(m for m in heavy if m in sys.modules));"
          "mwbx.solve; mwbx.view; print(sorted(m for m in heavy if m in sys.modules))")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600)
  before, after = out.stdout.splitlines()
  assert before == "[]"
  assert "meshcat" in after and "optax" in after


def test_import_and_the_command_leave_the_collector_working():
  """`import mwbx` holds the garbage collector only while it imports (and
  leaves it off if it was off); the `mwbx` command freezes what the imports
  made, so its objects are still collected."""
  code = textwrap.dedent("""
      import gc, sys
      was = gc.isenabled()
      import mwbx
      print(was, gc.isenabled())
      gc.disable()
      import importlib; importlib.reload(mwbx)
      print(gc.isenabled())
      gc.enable()
      from mwbx import cli
      sys.argv = ["mwbx", "--version"]
      try:
        cli.run()
      except SystemExit as stop:
        print(stop.code in (0, None), gc.isenabled(), gc.get_freeze_count() > 100_000)
      """)
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
  assert out.returncode == 0, out.stderr
  assert out.stdout.splitlines() == ["True True", "False", "mwbx 0.1.0", "True True True"], out.stdout
