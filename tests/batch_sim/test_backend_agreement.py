"""Perturbed sampling on MJX (impl jax, under the pilot's contact budget) and
MuJoCo Warp answers queries like the native backend: per-query match rates
agree within a two-proportion confidence interval, on pachinko and SIGGRAPH.

Cost: minutes of CPU (marked slow; it runs in ``make test``): on 2 cores
shared with other work (load average 7-12), pachinko took 6 min on mjx:jax
and 2.5 min on mjx:warp, SIGGRAPH 5 and 2 min, plus 1-2 min of native per
scene (mostly XLA compiling the block).

The test: for each query, the two-proportion z-test of H0 "same match rate"
(pooled variance, normal approximation), Bonferroni-corrected over the
queries of a scene at a family-wise level of 1 %: |z| < z(1 - 0.005 / Q).
The backends sample independent runs (different seeds), so a failure means
a difference in distribution, not in a shared draw.

Two stages. Stage 1 is that test on n worlds per engine (seeds 1 native,
2 mjx). Only if it fails, stage 2 runs the same test on 2n fresh worlds per
engine (seeds 3 and 4; the same samplers, so no new compile or pilot), and
only a failure there too fails. The stages are independent draws, so under
H0 a false failure has probability <= 1 % x 1 %. Why: the outcome on one
machine is fixed by its seeds, and MJX-on-CPU trajectories differ by machine
(float rounding, then chaos: here the same 48 worlds gave letter_G1 z 2.86
in this test's batch of 48 and 3.18 as the first 48 of a bench's batches of
64, the batch shape or sampler commits between the runs), so a single 48-world draw that lands at the edge (z 3.27
against 3.23 on one machine, in both its runs) fails there every time; a
second, larger draw decides such cases.

Power: each query splits the native outcomes near their median (a threshold
on a body's x at the end, measured once on a separate native run, seed 99:
``python tests/batch_sim/test_backend_agreement.py <scene>`` prints them), so p ~ 0.5.
With n worlds per backend stage 1 detects, with 80 % power, a difference of
about (z_crit + 0.84) * sqrt(0.5 / n): 0.36 for pachinko (n = 64) and 0.42
for SIGGRAPH (n = 48), with 8 queries each (z_crit = 3.23). Stage 2 (2n
worlds) then fails for that difference with probability
Phi(d / sqrt(0.5 / 2n) - 3.23) = Phi(5.8 - 3.23) = 0.995, so the two stages
together still catch it with 80 % power (0.80 x 0.995; the difference caught
at 80 % moves from 0.42 to 0.423 on SIGGRAPH, 0.36 to 0.363 on pachinko). It
catches a backend that drops or doubles contacts (letters that stop on pegs
instead of passing, balls that stick), not subtle biases;
tests/batch_sim/test_mjx.py compares distributions of tiny's metrics more
finely.

A bias it found, fixed (``scripts/bench_agreement.py``, 512 worlds per
engine, docs/sampling.md "Engine agreement"): on SIGGRAPH mjx:jax left
letter_G1 left of its median in 0.38 of worlds against native's 0.51 (z 4.1),
and this test failed on some machines at 48 worlds. The cause was MJX's
capsule-box contacts (pegs let into the letters' corners:
``batch_sim/mjx_capsule_box.py``); with mwbx's, G1 is at 0.45 against 0.51
(z 1.9) and every query's |z| < 2, so stage 1 fails rarely and a stage 2
more rarely still.

Cost: a passing stage 1 costs what the one-stage test cost. A stage-2 run
adds 2n worlds per engine on the samplers already compiled (chunks of n
worlds, the shape stage 1 compiled): on SIGGRAPH mjx:jax about 1 min of
stepping on 2 cores (96 x 484 world-steps at ~1,000 world-steps/s) and
seconds of native. Measured (2-core x86_64, load ~3): ``-k siggraph`` took
99 s with both cases passing stage 1; the jax case with stage 2 forced (a
temporary family level of 0.9) 101 s alone.
"""

import pathlib

import jax
import numpy as np
import pytest
from scipy import stats

import mwbx
from mwbx.queries import Query
from mwbx.queries.query import evaluate_each

REPO = pathlib.Path(__file__).parents[2]

# Per scene: simulated time (s), worlds per backend, and each body's median x
# at the end time on the native backend (128 worlds of seed 99), m, as
# ``python tests/batch_sim/test_backend_agreement.py <scene>`` prints them (SIGGRAPH
# measured on the scene with the letters spelled upright; pachinko re-measured
# then, unchanged to 1 mm).
SCENES = {
    "pachinko": (1.0, 64, {"ball_0": -0.404, "ball_1": -0.404, "cube_2": -0.33, "ball_3": -0.248,
                           "ball_4": -0.013, "cube_5": 0.088, "ball_6": 0.384, "ball_7": 0.106}),
    "siggraph": (1.0, 48, {"letter_S": -0.458, "letter_I": -0.346, "letter_G1": -0.029, "letter_G2": -0.186,
                           "letter_R": 0.106, "letter_A": 0.098, "letter_P": 0.141, "letter_H": 0.252}),
}
# Compiled as users compile them: these run minutes of MJX steps (their jax
# cases 1.4-1.6x slower with XLA's optimizations mostly off), and the rates
# checked are the shipped code's.
pytestmark = pytest.mark.usefixtures("xla_optimized")
FAMILY_ALPHA = 0.01  # per stage
STAGE2_FACTOR = 2  # stage 2: this many times the scene's worlds per engine, fresh seeds
SEEDS = ((1, 2), (3, 4))  # (native, mjx) run seeds of stage 1 and of stage 2


def _config(name: str, impl: str):
  end_time, n, _ = SCENES[name]
  config = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  # One chunk of n worlds: a stage-2 run (2n worlds) steps the same compiled batch.
  return config.model_copy(update={"sim": config.sim.model_copy(update={
      "end_time": end_time, "mjx_impl": impl, "chunk_size": n})})


def _queries(name: str):
  end_time, _, medians = SCENES[name]
  return [Query.region((-10.0, -10.0, -10.0), (x, 10.0, 10.0), bodies=(body,), window=(end_time - 0.05, None),
                       name=f"{body}_left_of_{x}") for body, x in medians.items()]


def _rates(sampler, name: str, n: int, seed: int):
  """(matches i64[Q], valid worlds, bank) of n worlds of a run."""
  bank, _ = sampler.run(n, jax.random.key(seed))
  answers = evaluate_each(bank, _queries(name))  # bool[W, Q], False for invalid worlds
  return answers.sum(axis=0), int(bank.valid.sum()), bank


def _z(a, b):
  """Per-query two-proportion z (pooled variance) of runs a and b, and the
  Bonferroni-corrected critical value."""
  (ka, na), (kb, nb) = a, b
  z_crit = stats.norm.ppf(1 - FAMILY_ALPHA / 2 / len(ka))
  pooled = (ka + kb) / (na + nb)
  se = np.sqrt(np.maximum(pooled * (1 - pooled), 1e-12) * (1 / na + 1 / nb))
  return (ka / na - kb / nb) / se, z_crit


@pytest.fixture(scope="module", params=["pachinko", "siggraph"])
def native(request):
  """The scene's native stage-1 run, and its stage-2 run on demand (shared by
  the mjx impls, sampled at most once)."""
  name = request.param
  n = SCENES[name][1]
  with mwbx.Sampler(_config(name, "jax"), "native") as sampler:
    matches, valid, _ = _rates(sampler, name, n, seed=SEEDS[0][0])
    stage2 = {}

    def second():
      if not stage2:
        stage2["run"] = _rates(sampler, name, STAGE2_FACTOR * n, seed=SEEDS[1][0])[:2]
      return stage2["run"]

    yield name, (matches, valid), second


@pytest.mark.slow
@pytest.mark.parametrize("impl", ["jax", "warp"])
def test_mjx_match_rates_agree_with_native(native, impl):
  if impl == "warp":
    pytest.importorskip("warp")
  name, native_1, native_2 = native
  n = SCENES[name][1]
  with mwbx.Sampler(_config(name, impl), "mjx") as sampler:
    matches, valid, bank = _rates(sampler, name, n, seed=SEEDS[0][1])
    # Flagged worlds (over budget, unstable) are a minority: under the default
    # budget (8 pilot worlds, headroom 1.5) mjx:jax flagged 7 of 48 SIGGRAPH
    # worlds in their first second (measured; 9 of 512 in scripts/bench_agreement.py),
    # none of pachinko's.
    assert valid >= 0.75 * n, (name, impl, bank.summary())
    assert bank.run["contact_budget"]["source"].startswith("pilot")
    # The queries are informative: native rates away from 0 and 1.
    pa = native_1[0] / native_1[1]
    assert ((pa > 0.15) & (pa < 0.85)).mean() >= 0.5, (name, pa)
    z1, z_crit = _z(native_1, (matches, valid))
    if (np.abs(z1) < z_crit).all():
      return
    # Stage 2: fresh seeds, twice the worlds, the same test; only a second failure fails.
    matches2, valid2, bank2 = _rates(sampler, name, STAGE2_FACTOR * n, seed=SEEDS[1][1])
  assert valid2 >= 0.75 * STAGE2_FACTOR * n, (name, impl, "stage 2", bank2.summary())
  native_matches2, native_valid2 = native_2()
  z2, _ = _z((native_matches2, native_valid2), (matches2, valid2))
  assert (np.abs(z2) < z_crit).all(), (
      f"{name} mjx:{impl}", "stage 1", (native_1[0] / native_1[1]).round(2), (matches / valid).round(2), z1.round(2),
      "stage 2", (native_matches2 / native_valid2).round(2), (matches2 / valid2).round(2), z2.round(2), z_crit)


def native_medians(name: str) -> dict[str, float]:
  """Each query body's median x at the scene's end time over 128 native
  worlds of seed 99 (what SCENES holds), m."""
  end_time, _, medians = SCENES[name]
  bank = mwbx.sample(_config(name, "jax"), 128, jax.random.key(99), backend="native")
  rows = np.flatnonzero(bank.valid)
  last = np.minimum(round(end_time * bank.query_fps), bank.com_count[rows] - 1)  # the frame at end_time
  x = bank.com[rows, last][:, [bank.body_names.index(b) for b in medians], 0]
  return {body: round(float(v), 3) for body, v in zip(medians, np.median(x, axis=0))}


if __name__ == "__main__":
  import sys
  print(native_medians(sys.argv[1]))
