#!/usr/bin/env bash
# Installs a lock file (requirements.lock or requirements-dev.lock) into a virtual
# environment, as `make run` and `make test` do:
#
#   bash scripts/install_lock.sh .venv/bin/python requirements.lock
#
# The lock pins every package with its hash, so each entry installs without
# resolving (--no-deps) and `pip check` then confirms the set is whole. pip
# fetches and unpacks one package after another; two pips on halves of the lock
# take about half the time (each package is in one half only, pip itself is
# installed first and alone). pip's byte-compiling of every file (half of its
# time) is skipped: Python writes a module's bytecode at its first import (the
# Makefile lets it, even where PYTHONDONTWRITEBYTECODE is set).
set -euo pipefail
PY=$1
LOCK=$2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# Each entry is its "name==version" line and the hash and comment lines under it.
awk -v dir="$tmp" '
  /^[A-Za-z0-9._-]+==/ { out = ($0 ~ /^pip==/) ? dir "/pip.txt" : dir "/part" (n++ % 2) ".txt" }
  out { print > out }
' "$LOCK"

install() { "$PY" -m pip install -q --no-compile --no-deps --require-hashes -r "$1"; }

if [[ -f "$tmp/pip.txt" ]]; then
  install "$tmp/pip.txt"
fi
pids=()
for part in "$tmp"/part*.txt; do
  install "$part" &
  pids+=("$!")
done
failed=0
for pid in "${pids[@]}"; do  # every pip finishes before a failure is reported
  wait "$pid" || failed=1
done
if [[ $failed != 0 ]]; then
  echo "install_lock: installing $LOCK failed (pip's message above)" >&2
  exit 1
fi
"$PY" -m pip check >/dev/null || { "$PY" -m pip check >&2; echo "install_lock: $LOCK is not a whole set of packages; rewrite it with \`make lock\`" >&2; exit 1; }
