#!/usr/bin/env bash
# Measures mwbx's batched engines on one GPU against native MuJoCo on the same
# machine's cores, in one run: SIGGRAPH and the trebuchet tower at 4096 worlds
# on mjx:jax (contact budget) and mjx:warp (MuJoCo Warp), with XLA's cost
# analysis per world-step. Writes out/bench/gpu.json; then
# `python scripts/make_benchmarks_doc.py` turns it into the GPU rows of
# docs/benchmarks.md. Needs an NVIDIA GPU with a CUDA 12 driver and the package
# index (nothing else from the internet); about 5 minutes on one GPU.
#
#   scripts/gpu_check.sh [--worlds 4096] [--python PY] [--out FILE]
#   scripts/gpu_check.sh --dry-run [--python PY]   # the same path, a tiny batch on the CPU
#
# --python: use this interpreter (mwbx and its gpu extra already installed)
# instead of making the virtual environment .venv-gpu and installing into it.
set -euo pipefail

ROOT="$(cd "${BASH_SOURCE[0]%/*}/.." && pwd)"
DRY=0
WORLDS=4096
PY=""
OUT=""
SCENES="siggraph,trebuchet_tower"
fail() { echo "gpu_check: $*" >&2; exit 1; }
while [ $# -gt 0 ]; do
  case "$1" in
    --dry-run) DRY=1 ;;
    --worlds) WORLDS="$2"; shift ;;
    --python) PY="$2"; shift ;;
    --out) OUT="$2"; shift ;;
    --scenes) SCENES="$2"; shift ;;
    *) fail "unknown argument $1 (use --dry-run, --worlds N, --python PY, --out FILE, --scenes A,B)" ;;
  esac
  shift
done

# The dry run never overwrites a GPU measurement.
[ -n "$OUT" ] || { [ "$DRY" = 1 ] && OUT="$ROOT/out/bench/gpu_dry_run.json" || OUT="$ROOT/out/bench/gpu.json"; }

if [ "$DRY" = 0 ]; then
  command -v nvidia-smi >/dev/null 2>&1 || fail "no NVIDIA GPU here (nvidia-smi not found); this check needs one GPU with a CUDA 12 driver"
  nvidia-smi -L >/dev/null 2>&1 || fail "nvidia-smi finds no GPU (driver not loaded?)"
fi

if [ -z "$PY" ]; then
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
"$PY" -c "import mwbx, warp" 2>/dev/null || fail "$PY cannot import mwbx and warp (pip install -e '.[gpu]')"

if [ "$DRY" = 1 ]; then
  export JAX_PLATFORMS=cpu
  # A tiny batch and few steps: every part runs, nothing is measured.
  ARGS=(--batch 8 --steps 2 --native-steps 4 --repeats 1)
else
  "$PY" - <<'PY' || fail "JAX sees no GPU (jax.default_backend() is not gpu): the CUDA 12 wheels (pip install -e '.[gpu]') or a CUDA 12 driver are missing"
import jax, sys
sys.exit(0 if jax.default_backend() == "gpu" else 1)
PY
  ARGS=(--batch "$WORLDS" --steps 50 --native-steps 50 --repeats 2)
fi

cd "$ROOT"
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
"$PY" scripts/bench_backends.py --scenes "$SCENES" --engines jax,warp "${ARGS[@]}" --out "$OUT"
echo "gpu_check: wrote $OUT; now: $PY scripts/make_benchmarks_doc.py"
