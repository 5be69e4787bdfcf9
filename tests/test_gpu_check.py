"""scripts/gpu_check.sh: its dry run (the GPU path on the CPU, tiny batch) end
to end into the benchmarks doc, and its one-line failure without a GPU."""

import json
import os
import subprocess
import sys

import pytest

from conftest import REPO, TESTS, load_script

SCRIPT = REPO / "scripts" / "gpu_check.sh"


def test_gpu_check_without_a_gpu_fails_with_one_line(tmp_path):
  # A PATH without nvidia-smi: what a machine without an NVIDIA driver looks like.
  env = {**os.environ, "PATH": str(tmp_path)}
  result = subprocess.run(["/bin/bash", str(SCRIPT), "--out", str(tmp_path / "gpu.json")], env=env,
                          capture_output=True, text=True, timeout=60)
  assert result.returncode == 1
  lines = result.stderr.strip().splitlines()
  assert len(lines) == 1 and lines[0].startswith("gpu_check: no NVIDIA GPU"), result.stderr
  assert not (tmp_path / "gpu.json").exists()


def test_gpu_check_rejects_an_unknown_argument():
  result = subprocess.run(["/bin/bash", str(SCRIPT), "--wrlds", "8"], capture_output=True, text=True, timeout=60)
  assert result.returncode == 1 and "unknown argument --wrlds" in result.stderr


def test_gpu_check_names_a_missing_wheel_folder(tmp_path):
  missing = tmp_path / "no-wheels"
  result = subprocess.run(["/bin/bash", str(SCRIPT), "--dry-run", "--wheels", str(missing)],
                          capture_output=True, text=True, timeout=60)
  assert result.returncode == 1
  assert result.stderr.strip() == f"gpu_check: --wheels {missing} is not a folder of wheels"


def test_gpu_check_names_a_part_that_failed_and_runs_the_rest(tmp_path):
  # A scene that cannot load fails its own part; the codec's part still runs and lands in the file.
  missing, out = tmp_path / "nosuch.yaml", tmp_path / "gpu.json"
  result = subprocess.run(
      ["/bin/bash", str(SCRIPT), "--dry-run", "--python", sys.executable, "--engines", "jax",
       "--scenes", str(missing), "--out", str(out)],
      capture_output=True, text=True, timeout=900, env={**os.environ, "PYTHONPATH": str(REPO)})
  assert result.returncode == 1
  assert result.stderr.strip().splitlines()[-1] == f"gpu_check: not measured: {missing} on mjx:jax (exit 1)"
  assert set(json.loads(out.read_text())) == {"codec_fit"}


@pytest.mark.slow
def test_gpu_check_dry_run_end_to_end(tmp_path):
  # Minutes of CPU (compiling the jax step and the warp steps of each solver variant of the tiny scene):
  # 69 s user time on a 2-core machine before the variants, though 12 min wall there under a load average
  # of 15-20.
  pytest.importorskip("warp")
  out = tmp_path / "gpu.json"
  result = subprocess.run(
      ["/bin/bash", str(SCRIPT), "--dry-run", "--python", sys.executable, "--scenes",
       str(TESTS / "scenes" / "tiny.yaml"), "--out", str(out)],
      capture_output=True, text=True, timeout=900, env={**os.environ, "PYTHONPATH": str(REPO)})
  assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
  d = json.loads(out.read_text())
  assert d["machine"]["jax_backend"] == "cpu" and d["batch"] == 8
  rows = {r["engine"]: r for r in d["scenes"]["tiny"]["rows"]}
  # mjx:warp (mwbx's solver choice) and its solver variants came from one process (the dry run's first scene).
  variants = {"mjx:warp shipped", "mjx:warp clamped", "mjx:warp capped", "mjx:warp cg"}
  asleep = {"native+sleep", "mjx:warp+sleep"}  # island sleep on both sides, from t = 0
  assert set(rows) == {"native", "mjx:jax", "mjx:warp"} | variants | asleep
  for engine, r in rows.items():
    assert r["world_steps_per_s"] > 0, engine
  solvers = {engine: rows[engine]["warp_solver"] for engine in variants | {"mjx:warp"}}
  assert solvers["mjx:warp shipped"]["tolerance"] == 1e-8 and solvers["mjx:warp"]["tolerance"] == 1e-6
  assert solvers["mjx:warp cg"]["solver"] == "cg" and solvers["mjx:warp capped"]["iterations"] == 10
  # tiny's nv (12) takes Newton: "clamped" is mwbx's own choice, reported without a second run.
  assert solvers["mjx:warp"]["solver"] == "newton" and rows["mjx:warp clamped"]["same_as"] == "mjx:warp"
  assert rows["mjx:warp+sleep"]["warp_solver"]["solver"] == "newton" and "island sleep" in rows["mjx:warp+sleep"]["what"]
  assert rows["mjx:warp+sleep"]["ratio_to_native"] == pytest.approx(
      rows["mjx:warp+sleep"]["world_steps_per_s"] / rows["native+sleep"]["world_steps_per_s"])
  for engine in ("mjx:jax", "mjx:warp", "mjx:warp cg", "mjx:warp+sleep"):
    assert rows[engine]["finite"] and rows[engine]["compile_s"] > 0
    # Each engine ran in its own process: its ratio is to the native rate measured there.
    assert rows[engine]["ratio_to_native"] == pytest.approx(
        rows[engine]["world_steps_per_s"] / rows[engine]["native_world_steps_per_s"])
  assert "error" in rows["mjx:warp"]["cost"]  # XLA does not see into its kernels
  # XLA's cost analysis of the jax step sees real work; the roofline follows from it.
  cost = rows["mjx:jax"]["cost"]
  assert cost["flops"] > 0 and cost["bytes_accessed"] > 0
  assert cost["roofline_steps_per_s"] == pytest.approx(
      1 / max(cost["flops"] / 67e12, cost["bytes_accessed"] / 4.8e12))
  # The doc generator turns it into rows: the CPU section, and the GPU one says it was not measured on a GPU.
  doc = load_script("make_benchmarks_doc")
  lines, _ = doc.backends(d)
  assert sum(line.startswith("| tiny |") for line in lines) == len(rows)
  gpu_lines, _ = doc.gpu(d)
  assert any("Not measured: no GPU" in line for line in gpu_lines)
  on_gpu = {**d, "machine": {**d["machine"], "jax_backend": "gpu", "device": "NVIDIA H200"}}
  gpu_lines, _ = doc.gpu(on_gpu)
  assert sum(line.startswith("| tiny |") for line in gpu_lines) == len(rows) and "NVIDIA H200" in gpu_lines[2]
  # The codec with either device the default (one device here: the same streams).
  codec = d["codec_fit"]
  assert {r["fit_on"] for r in codec["runs"]} == {"default", "host cpu"} and codec["same_streams"]
  assert any(line.startswith("The codec (") and "are the same" in line for line in gpu_lines)
