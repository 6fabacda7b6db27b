#!/usr/bin/env bash
# Set-up, the static checks, then the whole test suite (slow and integration tests included). Extra arguments go to
# pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh

# lint, format and types before any test: the first that fails stops the run with its findings. The configuration of
# each is in pyproject.toml; mypy keeps its cache in .mypy_cache, so a re-run takes seconds
check() {
  local what=$1
  shift
  if ! "$@"; then
    echo "test.sh: $what failed (above); no test was run" >&2
    exit 1
  fi
}
check "ruff check (lint; ruff check --fix repairs some)" .venv/bin/ruff check .
check "ruff format --check (ruff format . rewrites the files)" .venv/bin/ruff format --check .
check "mypy (strict on graspgen/, default checks on services/)" .venv/bin/python -m mypy

exec .venv/bin/python -m pytest -n 2 --dist loadgroup "$@"
