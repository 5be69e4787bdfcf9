"""Bad input gets one short, clear line naming the file, field or value: YAML
alias bombs, non-finite and huge config values, query windows no frame index
holds (from files and from Python), out-of-range CLI counts and world ids, id
ranges far past a bank, and runs that cannot fit in memory. Errors about a
file name its fields, never what the file holds."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys

import jax
import numpy as np
import pytest

import mwbx
from conftest import REPO, TESTS
from mwbx.batch_sim import memory
from mwbx.batch_sim.sampler import MAX_WORLD_ID, world_keys
from mwbx.queries import load_queries
from mwbx.world_ids import parse_world_ids

TINY = TESTS / "scenes" / "tiny.yaml"


def run_cli(*args, env=None):
  return subprocess.run([sys.executable, "-m", "mwbx.cli", *args], capture_output=True, text=True, cwd=REPO,
                        timeout=600, env={**os.environ, **(env or {})})


def assert_one_line(result, *needles):
  """Exit status 2 and one line on stderr holding every needle, no traceback."""
  lines = result.stderr.strip().splitlines()
  assert result.returncode == 2, result.stderr[-2000:]
  assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
  assert len(lines[0]) < 400, lines[0][:400]
  for needle in needles:
    assert needle in lines[0], lines[0]


def alias_bomb(levels: int, width: int = 9) -> str:
  """Anchors each repeating the previous one ``width`` times: ``width ** levels``
  leaves in a few hundred bytes."""
  lines = [f"a0: &a0 [{', '.join(['x'] * width)}]"]
  for i in range(1, levels):
    lines.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]")
  return "\n".join(lines) + "\n"


# --- YAML ----------------------------------------------------------------------

def test_config_alias_bomb_is_refused_with_a_short_message(tmp_path):
  # 9**6 = 531 441 leaves echoed as sim.end_time made a 2.6 MB error line.
  bomb = alias_bomb(6)
  path = tmp_path / "bomb.yaml"
  path.write_text("scene: {mjcf: tiny.xml}\nx:\n" + "".join("  " + line + "\n" for line in bomb.splitlines())
                  + "sim: {end_time: *a5}\n")
  assert len(path.read_bytes()) < 450
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  assert len(str(err.value)) < 300 and str(path) in str(err.value) and "aliases" in str(err.value)


def test_query_file_alias_bomb_is_refused_with_a_short_message(tmp_path):
  path = tmp_path / "q.yaml"
  path.write_text("queries: []\nx:\n" + "".join("  " + line + "\n" for line in alias_bomb(6).splitlines())
                  + "top: *a5\n")
  with pytest.raises(mwbx.MwbxError) as err:
    load_queries(path)
  assert len(str(err.value)) < 300 and str(path) in str(err.value)


def test_recursive_and_deep_yaml_are_one_clear_error(tmp_path):
  for text, needle in (("scene: &a {mjcf: tiny.xml, x: *a}\n", "contains it"),
                       ("scene: " + "[" * 3000 + "]" * 3000 + "\n", "nested too deeply")):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(mwbx.MwbxError, match=needle):
      mwbx.load_config(path)


def test_echoed_values_are_bounded(tmp_path):
  # Under the alias limit, but a value of 180 words echoed whole was 2 kB per error.
  path = tmp_path / "big.yaml"
  path.write_text("scene: {mjcf: tiny.xml}\nv: &v [" + ", ".join(["long_word"] * 60) + "]\n"
                  "randomize: {cube: {position: {scale: [*v, *v, *v]}}}\nsim: {end_time: *v}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  lines = str(err.value).splitlines()
  assert any("sim.end_time" in line for line in lines)
  assert all(len(line) < 450 for line in lines), max(map(len, lines))
  # Many bad items: a bounded number of lines.
  path.write_text("scene: {mjcf: tiny.xml}\ncontrols: {" + ", ".join(f"m{i}: x" for i in range(40)) + "}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  assert len(str(err.value).splitlines()) <= 11 and "more errors" in str(err.value)


def test_config_alias_bomb_on_the_command_line(tmp_path):
  path = tmp_path / "bomb.yaml"
  path.write_text("scene: {mjcf: tiny.xml}\n" + alias_bomb(7) + "sim: {end_time: *a6}\n")
  assert_one_line(run_cli("sample", str(path), "--out", str(tmp_path / "out")), str(path), "aliases")


# --- config values ---------------------------------------------------------------

@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_non_finite_config_values_are_refused(tmp_path, value):
  path = tmp_path / "c.yaml"
  path.write_text(f"scene: {{mjcf: tiny.xml}}\nrandomize: {{cube: {{position: {{scale: {value}}}}}}}\n")
  with pytest.raises(mwbx.MwbxError, match=r"randomize\.cube\.position\.scale: .*finite") as err:
    mwbx.load_config(path)
  assert "\n" not in str(err.value)  # one line, not one per branch of the field's union
  path.write_text(f"scene: {{mjcf: tiny.xml}}\nrandomize: {{cube: {{position: {{scale: [0, {value}, 0]}}}}}}\n")
  with pytest.raises(mwbx.MwbxError, match=r"randomize\.cube\.position\.scale\.1: .*finite") as err:
    mwbx.load_config(path)
  assert "\n" not in str(err.value)
  path.write_text(f"scene: {{mjcf: tiny.xml}}\nrandomize: {{cube: {{rotation: {{mean: [0, {value}, 0]}}}}}}\n")
  with pytest.raises(mwbx.MwbxError, match=r"randomize\.cube\.rotation\.mean.*finite"):
    mwbx.load_config(path)


@pytest.mark.parametrize("sim, needle", [
    ("end_time: 1" + "0" * 5000, "cannot convert"),  # past Python's 4300-digit int limit
    ("chunk_size: 1" + "0" * 400, "sim.chunk_size"),
    ("threads: 1" + "0" * 400, "sim.threads"),
])
def test_huge_numbers_are_one_short_error(tmp_path, sim, needle):
  path = tmp_path / "c.yaml"
  path.write_text(f"scene: {{mjcf: tiny.xml}}\nsim: {{{sim}}}\n")
  with pytest.raises(mwbx.MwbxError, match=needle) as err:
    mwbx.load_config(path)
  assert len(str(err.value)) < 400


@pytest.mark.parametrize("end_time, needle", [(".inf", "finite"), ("1e7", "physics steps")])
def test_unbounded_end_time_is_one_line(tmp_path, end_time, needle):
  path = tmp_path / "c.yaml"
  path.write_text(f"scene: {{mjcf: {TESTS / 'scenes' / 'tiny.xml'}}}\nsim: {{end_time: {end_time}}}\n")
  assert_one_line(run_cli("sample", str(path), "--worlds", "2", "--out", str(tmp_path / "out")),
                  "sim.end_time", needle)


# --- command-line counts, ids --------------------------------------------------------

@pytest.mark.parametrize("args, needles", [
    (("--chunk-size", "-1"), ("--chunk-size", "-1")),
    (("--chunk-size", "0"), ("--chunk-size", "0")),
    (("--worlds", "5000000000"), ("--worlds", "5000000000")),
    (("--seed", "99999999999999999999"), ("--seed", "99999999999999999999")),
])
def test_sample_counts_out_of_range_are_one_line(tmp_path, args, needles):
  assert_one_line(run_cli("sample", str(TINY), *args, "--out", str(tmp_path / "out")), *needles)
  assert not (tmp_path / "out").exists()


def test_a_billion_worlds_that_cannot_fit_are_refused_with_the_figure(tmp_path):
  # 1e9 ids alone are ~60 GB; the run asked for them before anything else.
  result = run_cli("sample", str(TINY), "--worlds", "1000000000", "--out", str(tmp_path / "out"),
                   env={memory.ENV_AVAILABLE: str(8 << 30)})
  assert_one_line(result, "--worlds 1000000000", "GiB of memory", "8.0 GiB is available")


def test_a_chunk_that_cannot_fit_leaves_no_bank_behind(tmp_path):
  # It was refused after the bank directory and the run record were written:
  # the same --out then held "a bank of a different config".
  path = tmp_path / "c.yaml"
  path.write_text(f"scene: {{mjcf: {TESTS / 'scenes' / 'tiny.xml'}}}\nsim: {{end_time: 3000.0}}\n")
  result = run_cli("sample", str(path), "--worlds", "256", "--chunk-size", "256", "--out", str(tmp_path / "out"),
                   env={memory.ENV_AVAILABLE: str(1 << 30)})
  assert_one_line(result, "a chunk of 256 worlds", "sim.end_time 3000", "1.0 GiB is available")
  assert not (tmp_path / "out").exists()


def test_a_refinement_that_cannot_fit_is_refused_with_the_figure(tiny_native_bank):
  # It ended in numpy's MemoryError traceback (the start states of 1e9 worlds).
  bank = tiny_native_bank
  world = int(bank.world_ids[np.flatnonzero(bank.valid)[0]])
  with pytest.raises(mwbx.MwbxError, match=r"refine: n_samples 1,000,000,000: a bank of 1,000,000,000 worlds"
                                           r" in memory.*GiB of memory") as err:
    mwbx.refine(bank, world, next(iter(bank.objects)), t_min=0.1, n_samples=10**9, backend="native")
  assert len(str(err.value)) < 400


def test_world_ids_past_32_bits_are_refused(tiny_native):
  # fold_in reads 32 bits: id 2**32 drew the key of id 0.
  key = jax.random.key(0)
  with pytest.raises(mwbx.MwbxError, match="world id 4294967296"):
    world_keys(key, [5, 2**32])
  with pytest.raises(mwbx.MwbxError, match="world id -1"):
    world_keys(key, [-1])
  with pytest.raises(mwbx.MwbxError, match="4294967296"):
    tiny_native.run(1, key, first_world=2**32)
  top, _ = tiny_native.run(1, key, first_world=MAX_WORLD_ID)  # the last id still samples
  assert int(top.world_ids[0]) == MAX_WORLD_ID


@pytest.fixture(scope="module")
def bank_dir(tiny_native, tmp_path_factory):
  path = tmp_path_factory.mktemp("bad_input") / "bank"
  bank, _ = tiny_native.run(6, jax.random.key(0))
  bank.save(path)
  return path


def test_drop_a_range_far_past_the_bank(bank_dir, tmp_path):
  result = run_cli("drop", str(bank_dir), "2..1000000000", "--out", str(tmp_path / "kept"))
  assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr[-2000:]
  assert "dropped worlds      2..5" in result.stdout
  assert list(mwbx.Bank.load(tmp_path / "kept").world_ids) == [0, 1]
  assert_one_line(run_cli("drop", str(bank_dir), "100..1000000000", "--out", str(tmp_path / "none")),
                  "IDS", "100..1000000000")


def test_id_ranges_are_bounded():
  assert parse_world_ids("3, 7..9") == [3, 7, 8, 9]
  assert parse_world_ids("0..1000000000", known=[4, 2, 9]) == [2, 4, 9]
  assert parse_world_ids("5, 1..3", known=[2, 4]) == [5, 2]  # single ids stay: unknown ones fail later
  with pytest.raises(mwbx.MwbxError, match="spans 1,000,000,001 ids"):
    parse_world_ids("0..1000000000")
  with pytest.raises(mwbx.MwbxError) as err:
    parse_world_ids("x" * 100_000)
  assert len(str(err.value)) < 400
  # From Python the message names the argument, from a command line the flag it passes.
  with pytest.raises(mwbx.MwbxError, match=r"^text: ") as err:
    parse_world_ids("3, x")
  assert "--" not in str(err.value)
  with pytest.raises(mwbx.MwbxError, match=r"^--worlds: "):
    parse_world_ids("3, x", flag="--worlds")


# --- memory --------------------------------------------------------------------------

def test_runs_that_cannot_fit_in_memory_are_refused_with_the_figure(tiny_config, monkeypatch):
  monkeypatch.setenv(memory.ENV_AVAILABLE, str(1 << 18))
  with pytest.raises(mwbx.MwbxError, match=r"a bank of 64 worlds in memory.*needs about .* but 0\.2 MiB is"
                                           r" available"):
    mwbx.sample(tiny_config, 64, jax.random.key(0), backend="native")
  long = tiny_config.with_overrides(end_time=3000.0)
  monkeypatch.setenv(memory.ENV_AVAILABLE, str(4 << 30))
  with mwbx.Sampler(long, backend="native", chunk_size=256) as sampler:
    with pytest.raises(mwbx.MwbxError, match=r"a chunk of 256 worlds of 360,001 frames.*sim\.end_time 3000"):
      next(sampler.run_chunks(300, jax.random.key(0)))
  assert memory.chunk_bytes(256, 360_001, 14, 2, 4, nbody=3, nstate=28, nsensordata=0,
                            steps_per_frame=4) > 4 << 30


def test_available_memory_comes_from_the_machine(monkeypatch):
  monkeypatch.delenv(memory.ENV_AVAILABLE, raising=False)
  assert memory.available_bytes() > 1 << 20
  monkeypatch.setenv(memory.ENV_AVAILABLE, "lots")
  with pytest.raises(mwbx.MwbxError, match=memory.ENV_AVAILABLE):
    memory.available_bytes()


# --- query windows -----------------------------------------------------------------

@pytest.mark.parametrize("entry, needles", [
    ("{touch: [cube, floor], window: [0, .inf]}", ("window t1", "inf")),
    ("{touch: [cube, floor], window: [1e300, null]}", ("window t0", "1e+300")),
    ("{touch: [cube, floor], sign: exclude, window: [0, .inf]}", ("window t1", "inf")),
    ("{touch: [cube, floor], window: [-1, 1]}", ("window t0", "-1.0")),
    ("{then: [[cube, floor], [ball, floor]], window: [1e300, null]}", ("window t0", "1e+300")),
    ("{then: [[cube, floor], [ball, floor]], window: [null, .inf]}", ("window t1", "inf")),
    ("{region: {min: [0, 0, 0], max: [1, 1, 1]}, window: [0, .inf]}", ("window t1", "inf")),
    ("{joint: hinge, turn: [0.5, null], window: [1e300, null]}", ("window t0", "1e+300")),
])
def test_query_windows_are_checked_where_they_enter(tmp_path, entry, needles):
  # An event window of [0, .inf] or [1e300, null] ended in an OverflowError
  # traceback at evaluation; every kind now refuses it on loading, in one line.
  path = tmp_path / "q.yaml"
  path.write_text(f"queries:\n  - {entry}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    load_queries(path)
  message = str(err.value)
  assert message.startswith(f"{path}: queries[0]") and "\n" not in message and len(message) < 400, message
  for needle in needles:
    assert needle in message, message


def test_an_event_window_past_any_frame_is_one_line_on_the_command_line(bank_dir, tmp_path):
  path = tmp_path / "q.yaml"
  path.write_text("queries:\n  - {touch: [cube, floor], window: [1e300, null]}\n")
  assert_one_line(run_cli("query", str(bank_dir), str(path)), str(path), "queries[0]", "window t0", "1e+300")


def test_query_windows_from_python_are_checked_in_the_constructor():
  # mwbx.TouchQuery(window=(0, inf)) was accepted and failed at evaluation.
  for make, needle in (
      (lambda: mwbx.TouchQuery("cube", "floor", window=(0, math.inf)), "window t1"),
      (lambda: mwbx.TouchQuery("cube", "floor", window=(1e300, None), sign="exclude"), "window t0"),
      (lambda: mwbx.OrderQuery([("cube", "floor"), ("ball", "floor")], window=(None, math.inf)), "window t1"),
      (lambda: mwbx.Query.region([0, 0, 0], [1, 1, 1], window=(-0.5, None)), "window t0"),
      (lambda: mwbx.OrientationQuery(bodies="cube", axis="z", window=(0, math.inf)), "window t1"),
      (lambda: mwbx.TouchQuery("cube", "floor", window=(math.nan, 1.0)), "window must not be NaN"),
      (lambda: mwbx.TouchQuery("cube", "floor", window=(2.0, 1.0)), "window is empty"),
  ):
    with pytest.raises(mwbx.MwbxError, match=needle) as err:
      make()
    assert "\n" not in str(err.value) and str(err.value).startswith("query")
  assert mwbx.TouchQuery("cube", "floor", window=(0, 1e9)).window == (0.0, 1e9)  # the largest time taken


def test_event_functions_check_the_window_they_are_given(tiny_native_bank):
  from mwbx.queries.event import first_touch, touch_seconds
  for function in (first_touch, touch_seconds):
    with pytest.raises(mwbx.MwbxError, match="window t1"):
      function(tiny_native_bank, ("cube",), ("floor",), (0.0, math.inf))
  assert first_touch(tiny_native_bank, ("cube",), ("floor",), (0.0, 1e9)).shape == (tiny_native_bank.n_worlds,)


@pytest.mark.parametrize("entry, field", [
    ("{then: null}", "then"),
    ("{touch: null}", "touch"),
    ("{joint: null, turn: [0.5, null]}", "joint"),
    ("{box: null}", "box"),
])
def test_a_kind_key_set_to_null_is_named(tmp_path, entry, field):
  # `then: null` read as no `then` and was answered "give exactly one of 'box' or 'region'".
  path = tmp_path / "q.yaml"
  path.write_text(f"queries:\n  - {entry}\n")
  with pytest.raises(mwbx.MwbxError, match=rf"^{re.escape(str(path))}: queries\[0\]\.{field}: must be .*got null$"):
    load_queries(path)


# --- errors name files and fields, never what they hold ------------------------------

SECRET = "sk-live-0a1b2c3d4e5f"  # lower case: PyYAML lowers some scalars before echoing them


def test_config_errors_name_fields_not_values(tmp_path):
  # A file of secrets read as a config echoed them: `scene: Field required (got {'api_key': ...})`.
  path = tmp_path / "secret.yaml"
  path.write_text(f"api_key: {SECRET}\ndb: {{user: admin, password: {SECRET}}}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  assert f"{path}: scene: Field required" in str(err.value) and SECRET not in str(err.value), str(err.value)
  path.write_text(f"scene: {{mjcf: {SECRET}}}\nsim: {{end_time: {SECRET}}}\nrandomize: {SECRET}\n")
  with pytest.raises(mwbx.MwbxError) as err:
    mwbx.load_config(path)
  assert "sim.end_time" in str(err.value) and "randomize" in str(err.value) and SECRET not in str(err.value)


def test_query_file_errors_name_fields_not_values(tmp_path):
  path = tmp_path / "q.yaml"
  for text, field in ((f"queries: {{api_key: {SECRET}}}\n", "queries"),
                      (f"queries:\n  - {{box: {SECRET}}}\n", "queries[0].box"),
                      (f"queries: []\ntop: {SECRET}\n", "top")):
    path.write_text(text)
    with pytest.raises(mwbx.MwbxError) as err:
      load_queries(path)
    assert str(err.value).startswith(f"{path}: {field}: ") and SECRET not in str(err.value), str(err.value)


def test_yaml_errors_name_the_place_not_the_content(tmp_path):
  # A tagged scalar that did not convert was echoed (`invalid literal for
  # int() with base 10: '...'`), or was a KeyError traceback (`!!bool`).
  path = tmp_path / "c.yaml"
  for text in (f"sim: {{end_time: !!int {SECRET}}}\n",
               f"sim: {{end_time: !!float {SECRET}}}\n",
               f"sim: {{end_time: !!bool {SECRET}}}\n",
               f"scene: [{SECRET}\nsim: {{end_time: 1}}\n",  # malformed: the place, not the line
               f"scene: \"{SECRET}\\q\"\n"):
    path.write_text(text)
    for load in (mwbx.load_config, load_queries):
      with pytest.raises(mwbx.MwbxError) as err:
        load(path)
      assert str(err.value).startswith(str(path)) and SECRET not in str(err.value), str(err.value)
      assert "\n" not in str(err.value)
