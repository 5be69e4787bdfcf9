#!/usr/bin/env bash
# Measures mwbx's batched engines on one GPU against native MuJoCo on the same
# machine's cores, in one run: SIGGRAPH at 4096 worlds and the trebuchet tower
# at 512 on mjx:jax (contact budget) and mjx:warp (MuJoCo Warp), each timed
# from the states after 0.6 s of MuJoCo C (bodies in contact); then the tower
# on mjx:warp at 512 and 2048 worlds under MuJoCo Warp's solver variants
# (mwbx's choice, as shipped, tolerance clamped, Newton capped, CG). Writes
# out/bench/gpu.json; then `python scripts/make_benchmarks_doc.py` turns it
# into the GPU rows of docs/benchmarks.md. Needs an NVIDIA GPU with a CUDA 12
# or newer driver, and either the package index or --wheels. Time on one
# H200: the engines and mwbx sample took about 9 minutes before the variants
# (measured in parts: the engines 7 min, mwbx sample 1 min); the variants are
# NOT measured yet. To stay within 8 minutes the tower's 2048-world run repeats
# 512 advanced states (--distinct-states: no 2048-world advance on the CPU)
# and each world count's variants share one process (one pilot, one advance,
# one native baseline, the tower's mjx:warp row included); if a run still goes
# over, drop parts: --sample 0 (1 min), --variant-worlds 512, --variants "".
# Then the tower with island sleep on both sides (native MuJoCo C, and
# mjx:warp under Newton with nvmax from the native pilot), from t = 0 (its
# blocks start asleep) at --sleep-worlds, 50 steps a run: rows named "+sleep";
# NOT measured yet (--sleep-worlds 0 skips it).
#
#   scripts/gpu_check.sh [--worlds 4096] [--python PY | --wheels DIR] [--out FILE]
#                        [--scenes A,B] [--engines jax,warp] [--timeout S] [--append] [--sample N]
#                        [--variants shipped,clamped,capped,cg] [--variant-scene NAME] [--variant-worlds 512,2048]
#                        [--sleep-worlds 512]
#   scripts/gpu_check.sh --dry-run [--python PY]   # the same path, a tiny batch on the CPU
#
# --scenes: shipped scene names or config paths, each optionally NAME:WORLDS or
#   NAME:WORLDS:STEPS. The tower runs 512 worlds and 5 steps a timed run: its
#   dense constraint Jacobian alone is njmax x nv floats per world (7332 x 1185
#   x 4 bytes = 35 MB), so 4096 worlds would need 142 GB for it.
# --sample N: also time `mwbx sample configs/siggraph.yaml --backend mjx
#   --worlds N` as a user first runs it (pilot, compile, recording and
#   compression included; default 1024, 0 skips it; not in the dry run).
# --python PY: use this interpreter (mwbx and its gpu extra already installed)
#   instead of making the virtual environment .venv-gpu and installing into it.
# --wheels DIR: a machine without the package index (an offline cluster node):
#   use its own python3 and JAX (with JAX's CUDA plugin) and install only the
#   packages it lacks (mujoco, mujoco-mjx, warp-lang, pydantic, ...) from the
#   wheels in DIR into .gpu-site/ (pip --no-index --no-deps).
# --variants: mjx:warp's solver variants (scripts/bench_backends.py
#   WARP_VARIANTS: shipped = the model's own options, clamped = Newton with the
#   tolerance raised to 1e-6, capped = that with 10 iterations, cg = CG), run
#   with mwbx's own choice (the mjx:warp row) on --variant-scene (default
#   trebuchet_tower; the dry run: the first of --scenes) at each of
#   --variant-worlds, 5 steps a timed run; "" skips them. Only with warp among
#   --engines; the main loop then leaves that scene's mjx:warp row to them.
# Each scene and engine runs in its own process, under --timeout seconds
# (default 300; 1800 in the dry run, CPU compiles are slow) including its
# compile: one that runs long loses its own row, not the others. Rows land in
# FILE as each finishes; FILE starts empty unless --append (then the rows of
# engines not run now stay).
set -euo pipefail

ROOT="$(cd "${BASH_SOURCE[0]%/*}/.." && pwd)"
DRY=0
WORLDS=4096
PY=""
WHEELS=""
OUT=""
SCENES="siggraph,trebuchet_tower:512:5"
ENGINES="jax,warp"
TIMEOUT=""
APPEND=0
SAMPLE=1024
VARIANTS="shipped,clamped,capped,cg"
VARIANT_SCENE=""
VARIANT_WORLDS="512,2048"
SLEEP_WORLDS=512
fail() { echo "gpu_check: $*" >&2; exit 1; }
while [ $# -gt 0 ]; do
  case "$1" in
    --dry-run) DRY=1 ;;
    --worlds) WORLDS="$2"; shift ;;
    --python) PY="$2"; shift ;;
    --wheels) WHEELS="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --scenes) SCENES="$2"; shift ;;
    --engines) ENGINES="$2"; shift ;;
    --timeout) TIMEOUT="$2"; shift ;;
    --append) APPEND=1 ;;
    --sample) SAMPLE="$2"; shift ;;
    --variants) VARIANTS="$2"; shift ;;
    --variant-scene) VARIANT_SCENE="$2"; shift ;;
    --variant-worlds) VARIANT_WORLDS="$2"; shift ;;
    --sleep-worlds) SLEEP_WORLDS="$2"; shift ;;
    *) fail "unknown argument $1 (use --dry-run, --worlds N, --python PY, --wheels DIR, --out FILE, --scenes A,B, --engines jax,warp, --timeout S, --append, --sample N, --variants A,B, --variant-scene NAME, --variant-worlds N,M, --sleep-worlds N)" ;;
  esac
  shift
done

# The dry run never overwrites a GPU measurement.
[ -n "$OUT" ] || { [ "$DRY" = 1 ] && OUT="$ROOT/out/bench/gpu_dry_run.json" || OUT="$ROOT/out/bench/gpu.json"; }

if [ "$DRY" = 0 ]; then
  command -v nvidia-smi >/dev/null 2>&1 || fail "no NVIDIA GPU here (nvidia-smi not found); this check needs one GPU with a CUDA 12 or newer driver"
  nvidia-smi -L >/dev/null 2>&1 || fail "nvidia-smi finds no GPU (driver not loaded?)"
fi

if [ -n "$WHEELS" ]; then
  [ -d "$WHEELS" ] || fail "--wheels $WHEELS is not a folder of wheels"
  [ -n "$PY" ] || PY="$(command -v python3 || true)"
  [ -n "$PY" ] || fail "python3 not found (Python 3.12 needed)"
  SITE="$ROOT/.gpu-site"
  "$PY" -m pip install -q --no-index --no-deps --no-compile --upgrade --target "$SITE" "$WHEELS"/*.whl \
    || fail "pip could not install the wheels in $WHEELS (see above)"
  export PYTHONPATH="$SITE${PYTHONPATH:+:$PYTHONPATH}"
elif [ -z "$PY" ]; then
  VENV="$ROOT/.venv-gpu"
  command -v python3 >/dev/null 2>&1 || fail "python3 not found (Python 3.12 needed)"
  [ -x "$VENV/bin/python" ] || python3 -m venv "$VENV" || fail "could not make the virtual environment $VENV"
  PY="$VENV/bin/python"
  # The dry run stays on the CPU: the package and MuJoCo Warp, without JAX's CUDA wheels.
  EXTRA=".[gpu]"; [ "$DRY" = 1 ] && EXTRA="."
  "$PY" -m pip install -q --upgrade pip >/dev/null || fail "pip could not reach the package index"
  "$PY" -m pip install -q -e "$ROOT$EXTRA" || fail "pip install -e '$EXTRA' failed (see above)"
  [ "$DRY" = 1 ] && { "$PY" -m pip install -q "warp-lang==1.18.0" || fail "pip install warp-lang failed"; }
fi
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
NEED="mwbx"; [[ ",$ENGINES," != *,warp,* ]] || NEED="mwbx, warp"
"$PY" -c "import $NEED" 2>/dev/null || fail "$PY cannot import $NEED (pip install -e '.[gpu]', or --wheels DIR)"

if [ "$DRY" = 1 ]; then
  export JAX_PLATFORMS=cpu
  # A tiny batch and few steps: every part runs, nothing is measured.
  WORLDS=8 STEPS=2
  ARGS=(--native-steps 4 --repeats 1)
  TIMEOUT="${TIMEOUT:-1800}"
else
  "$PY" - <<'PY' || fail "JAX sees no GPU (jax.default_backend() is not gpu): JAX's CUDA wheels (pip install -e '.[gpu]') or a CUDA 12 or newer driver are missing"
import jax, sys
sys.exit(0 if jax.default_backend() == "gpu" else 1)
PY
  # XLA's cost analysis is left to the CPU benchmark (a second compile per engine).
  STEPS=50
  ARGS=(--native-steps 50 --repeats 2 --no-cost --start-time 0.6)
  TIMEOUT="${TIMEOUT:-300}"
fi

# The solver variants run where mjx:warp does, on the tower (the dry run: its first scene, tiny batch).
if [[ ",$ENGINES," != *,warp,* ]]; then VARIANTS=""; fi
FIRST_SCENE="${SCENES%%,*}"; FIRST_SCENE="${FIRST_SCENE%%:*}"
[ -n "$VARIANT_SCENE" ] || { [ "$DRY" = 1 ] && VARIANT_SCENE="$FIRST_SCENE" || VARIANT_SCENE="trebuchet_tower"; }
[ "$DRY" = 0 ] || VARIANT_WORLDS="$WORLDS"
[ "$DRY" = 0 ] || [ "$SLEEP_WORLDS" = 0 ] || SLEEP_WORLDS="$WORLDS"
if [[ ",$ENGINES," != *,warp,* ]]; then SLEEP_WORLDS=0; fi

cd "$ROOT"
[ "$APPEND" = 1 ] || rm -f "$OUT"
missing=()
# measure LABEL COMMAND...: runs one part under the time limit; a failure is
# named at the end instead of stopping the others.
measure() {
  local label="$1" status=0
  shift
  timeout "$TIMEOUT" "$@" || status=$?
  # (the substitution must succeed: an assignment's status is its substitution's, and set -e)
  [ "$status" = 0 ] || missing+=("$label (exit $status$([ "$status" != 124 ] || echo ", over ${TIMEOUT} s"))")
}
for engine in ${ENGINES//,/ }; do
  for spec in ${SCENES//,/ }; do
    IFS=: read -r scene worlds steps <<< "$spec"
    [ "$DRY" = 0 ] || worlds="" steps=""  # the dry run: always the tiny batch
    worlds="${worlds:-$WORLDS}" steps="${steps:-$STEPS}"
    if [ "$engine" = warp ] && [ -n "$VARIANTS" ] && [ "$scene" = "$VARIANT_SCENE" ]; then
      continue  # its mjx:warp row comes with the solver variants below
    fi
    echo "gpu_check: $scene on mjx:$engine, $worlds worlds, $steps steps a run (at most ${TIMEOUT} s)"
    measure "$scene on mjx:$engine" "$PY" scripts/bench_backends.py --scenes "$scene" --engines "$engine" \
      --keep-engines --batch "$worlds" --steps "$steps" "${ARGS[@]}" --out "$OUT"
  done
done
if [ -n "$VARIANTS" ]; then
  for worlds in ${VARIANT_WORLDS//,/ }; do
    # 5 timed steps as the tower's other rows; native timed over 10 steps (at 2048 worlds, 50 would cost ~30 s).
    vsteps=5 vnative=(--native-steps 10); [ "$DRY" = 0 ] || { vsteps="$STEPS"; vnative=(); }
    echo "gpu_check: $VARIANT_SCENE on mjx:warp, solver variants auto,$VARIANTS, $worlds worlds, $vsteps steps a run (at most ${TIMEOUT} s)"
    measure "$VARIANT_SCENE on mjx:warp at $worlds worlds (solver variants)" "$PY" scripts/bench_backends.py \
      --scenes "$VARIANT_SCENE" --engines warp --warp-variants "auto,$VARIANTS" --keep-engines --batch "$worlds" \
      --steps "$vsteps" --distinct-states 512 "${ARGS[@]}" "${vnative[@]}" --out "$OUT"
  done
fi
if [ "$SLEEP_WORLDS" != 0 ]; then
  echo "gpu_check: $VARIANT_SCENE with island sleep on native and mjx:warp, $SLEEP_WORLDS worlds from t = 0 (at most ${TIMEOUT} s)"
  measure "$VARIANT_SCENE with sleep" "$PY" scripts/bench_backends.py --scenes "$VARIANT_SCENE" --engines warp \
    --sleep --keep-engines --batch "$SLEEP_WORLDS" --steps "$STEPS" "${ARGS[@]}" --start-time 0 --no-cost --out "$OUT"
fi
if [ "$DRY" = 0 ] && [ "$SAMPLE" != 0 ]; then
  echo "gpu_check: mwbx sample configs/siggraph.yaml --backend mjx --worlds $SAMPLE (at most ${TIMEOUT} s)"
  measure "mwbx sample" "$PY" scripts/bench_backends.py --scenes "" --time-sample "$SAMPLE" --out "$OUT"
fi
echo "gpu_check: the codec with the GPU and the host CPU as JAX's default (at most ${TIMEOUT} s)"
CODEC=(--worlds 256 --frames 600); [ "$DRY" = 0 ] || CODEC=(--worlds 8 --frames 60 --repeats 1)
measure "the codec's fit" "$PY" scripts/bench_codec_device.py "${CODEC[@]}" --out "$OUT"
[ -f "$OUT" ] || fail "nothing measured; see above"
echo "gpu_check: wrote $OUT; now: $PY scripts/make_benchmarks_doc.py"
[ ${#missing[@]} = 0 ] || fail "not measured: ${missing[*]}"
