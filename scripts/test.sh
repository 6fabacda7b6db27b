#!/usr/bin/env bash
# Set-up plus the whole test suite (slow and integration tests included). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/python -m pytest -n 2 --dist loadgroup "$@"
