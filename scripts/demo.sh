#!/usr/bin/env bash
# Set-up plus the main job on the embedded default: grasps for a shipped example part, written to out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# the example parts are steel: criterion (e) gets their mass from the density (docs/HOLD.md)
exec .venv/bin/graspgen demo --density 7850 "$@"
