#!/usr/bin/env bash
# Writes requirements.lock (what `make run` installs: pyproject.toml's dependencies)
# and requirements-dev.lock (what `make test` installs: those and the dev extras) from
# pyproject.toml. Each lists every package pip resolves, pip itself and the build
# backend (setuptools, to install mwbx without build isolation) at an exact version,
# with the sha256 of the file pip downloads for it on linux x86_64, CPython 3.12.
#
#   make lock                  # keeps the locked versions, adds what is new
#   make lock UPGRADE=1        # the newest versions pyproject.toml allows
#   bash scripts/lock.sh -c FILE   # further arguments go to pip (here: constraints)
#
# Keeping fails when pyproject.toml's new bounds exclude a locked version: then UPGRADE=1.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

keep=()
if [[ "${UPGRADE:-0}" != 1 && -f requirements-dev.lock ]]; then
  grep -E '^[A-Za-z0-9._-]+==' requirements-dev.lock | cut -d' ' -f1 >"$tmp/keep.txt"
  keep=(-c "$tmp/keep.txt")
fi
build=$("$PY" -c 'import tomllib; print(*tomllib.load(open("pyproject.toml", "rb"))["build-system"]["requires"])')

# pip's own resolution (dry run, as on an empty environment), written out as a JSON report.
resolve() {
  local report=$1
  shift
  # shellcheck disable=SC2086  # $build: one argument per requirement
  "$PY" -m pip install -q --dry-run --ignore-installed --report "$report" "$@" pip $build
}

# The report → a requirements file with hashes; the project itself is left out.
write() {
  "$PY" - "$@" <<'EOF'
import hashlib, json, sys, tomllib, urllib.parse, urllib.request

report, out, what = sys.argv[1:]
project = tomllib.load(open("pyproject.toml", "rb"))["project"]["name"]
lines = [f"# {what}, for CPython 3.12 on linux x86_64.",
         "# Written by `make lock` (scripts/lock.sh) from pyproject.toml: edit that, not this file.", ""]
for item in sorted(json.load(open(report))["install"], key=lambda i: i["metadata"]["name"].lower()):
    name, version = item["metadata"]["name"], item["metadata"]["version"]
    if name.lower() == project:
        continue
    info = item["download_info"]
    if "archive_info" not in info:
        sys.exit(f"lock: {name} comes from {info['url']}, not a package file: it cannot be locked")
    archive = info["archive_info"]
    digest = archive.get("hashes", {}).get("sha256")
    if not digest and archive.get("hash", "").startswith("sha256="):
        digest = archive["hash"].split("=", 1)[1]
    if not digest and info["url"].startswith("file:"):
        with urllib.request.urlopen(info["url"]) as f:
            digest = hashlib.sha256(f.read()).hexdigest()
    if not digest:
        sys.exit(f"lock: the index gives no sha256 for {info['url']}")
    filename = urllib.parse.unquote(info["url"].rsplit("/", 1)[-1])
    lines += [f"{name}=={version} \\", f"    --hash=sha256:{digest}", f"    # {filename}"]
open(out, "w").write("\n".join(lines) + "\n")
EOF
}

resolve "$tmp/dev.json" "${keep[@]}" "$@" ".[dev]"
write "$tmp/dev.json" "$tmp/requirements-dev.lock" "What \`make test\` installs: pyproject.toml's dependencies and dev extras"
# The runtime set at the dev set's versions, so that the two locks agree.
grep -E '^[A-Za-z0-9._-]+==' "$tmp/requirements-dev.lock" | cut -d' ' -f1 >"$tmp/dev-pins.txt"
resolve "$tmp/run.json" -c "$tmp/dev-pins.txt" "$@" "."
write "$tmp/run.json" "$tmp/requirements.lock" "What \`make run\` installs: pyproject.toml's dependencies"
for f in requirements.lock requirements-dev.lock; do  # untouched when unchanged: no reinstall
  cmp -s "$tmp/$f" "$f" || mv "$tmp/$f" "$f"
done
echo "lock: requirements.lock ($(grep -c '^[A-Za-z0-9]' requirements.lock) packages)," \
  "requirements-dev.lock ($(grep -c '^[A-Za-z0-9]' requirements-dev.lock) packages)"
