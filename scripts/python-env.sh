#!/usr/bin/env bash
# Creates the project's Python virtual environment if it is missing, installs the pinned
# requirements of requirements-dev.txt into it, and prints its path:
#   venv=$(scripts/python-env.sh) && "$venv/bin/python" host-tools/tests/dbc_cantools.py ...
# The venv lives in ${CARGO_TARGET_DIR:-target}/venv, beside the build products. Progress goes
# to stderr; stdout carries only the path. Fails (non-zero) if python3, venv or pip fail.
set -euo pipefail
cd "$(dirname "$0")/.."

target="${CARGO_TARGET_DIR:-target}"
venv="$target/venv"
requirements="requirements-dev.txt"
stamp="$venv/.requirements-dev.txt"

if [ ! -x "$venv/bin/python" ]; then
    echo "creating $venv" >&2
    mkdir -p "$target"
    python3 -m venv "$venv" >&2
fi
# Install only when the requirements changed since the last successful install.
if ! cmp -s "$requirements" "$stamp"; then
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
        -r "$requirements" >&2
    cp "$requirements" "$stamp"
fi
# An absolute path, whatever the caller's directory.
(cd "$venv" && pwd)
