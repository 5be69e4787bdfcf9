"""scripts/scene_counts.py's per-backend world counts and horizons, and the
doc rows made from its JSON (every scene and backend, the numbers used)."""

from conftest import load_script


def test_per_backend_values_scene_specific_first():
  counts = load_script("scene_counts")
  spec = "native=64,mjx:jax=16,trebuchet_tower/mjx:jax=8"
  assert counts.per_backend(spec, "siggraph", "native", 0) == 64
  assert counts.per_backend(spec, "siggraph", "mjx:jax", 0) == 16
  assert counts.per_backend(spec, "trebuchet_tower", "mjx:jax", 0) == 8
  assert counts.per_backend(spec, "siggraph", "mjx:warp", 0) == 0
  assert counts.per_backend(counts.END_TIME, "trebuchet_tower", "mjx:warp", None) == 1.0
  assert counts.per_backend(counts.END_TIME, "siggraph", "mjx:warp", None) is None  # the config's own
  assert set(counts.SCENES) == {"quickstart", "pachinko", "toss", "siggraph", "spiral_staircase",
                                "refrigerator_toy", "trebuchet_tower"}


def test_doc_rows_name_counts_horizon_and_missing_runs():
  doc = load_script("make_benchmarks_doc")
  row = dict(worlds=8, end_time=5.0, valid=6, unstable=1, over_budget=1, sim_errors=0, all_met=2,
             per_query={"a": 3}, wall_seconds=12.0, commit="abc")
  d = {"machine": "2-core x86_64, JAX on cpu",
       "rows": [dict(row, scene="siggraph", backend="native"), dict(row, scene="siggraph", backend="mjx:jax"),
                dict(row, scene="toss", backend="native", per_query={}, all_met=None)]}
  lines, _ = doc.scenes(d)
  assert "| siggraph | mjx:jax | 8 | 5.0 | 6 | 1 | 1 | 0 | 2 | a 3 | 12 | abc |" in lines
  assert any(line.startswith("| toss | native |") and "(no query file)" in line for line in lines)
  assert any(line.startswith("Not sampled yet: toss on mjx:jax (") for line in lines)
  d["planned"] = {"scenes": ["siggraph", "toss", "trebuchet_tower"], "backends": ["native", "mjx:jax"]}
  lines, _ = doc.scenes(d)
  assert any(line.startswith("Not sampled yet: toss on mjx:jax, trebuchet_tower on native, "
                             "trebuchet_tower on mjx:jax (") for line in lines)
