#!/usr/bin/env bash
# Creates .venv and installs graspgen with pinned dependencies (constraints.txt). Idempotent and quick when
# nothing changed: it reinstalls only when pyproject.toml or constraints.txt differ from the last install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1)
if [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp" ]; then
  .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e '.[dev,service,validate,client]'
  echo "$stamp" > .venv/.setup-stamp
fi
# numba's kernels compiled into its on-disk cache (graspgen/__pycache__, or NUMBA_CACHE_DIR) whenever graspgen's
# sources or the dependencies changed, so the first job after set-up does not compile them (1-2 min cold)
wstamp=$(find graspgen -name "*.py" | sort | xargs cat .venv/.setup-stamp | sha256sum | cut -d' ' -f1)
if [ "$(cat .venv/.warmup-stamp 2>/dev/null)" != "$wstamp" ]; then
  if .venv/bin/graspgen warmup --quiet; then
    echo "$wstamp" > .venv/.warmup-stamp
  else
    echo "setup: graspgen warmup failed; kernels will compile on first use" >&2
  fi
fi
