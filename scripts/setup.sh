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
# the review page's browser tests and benchmark drive Debian's Chromium, and Firefox ESR on an Xvfb display
# (tests/ui/browser.py); each skips without its browser
missing_browsers=""
[ -x /usr/bin/chromium ] || missing_browsers="chromium"
[ -x /usr/bin/firefox-esr ] && command -v Xvfb >/dev/null || missing_browsers="$missing_browsers firefox-esr xvfb"
if [ -n "$missing_browsers" ]; then
  if [ "$(id -u)" = 0 ]; then as_root=""; elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then as_root="sudo -n"
  else as_root="none"; fi
  if [ "$as_root" != none ] && command -v apt-get >/dev/null; then
    # shellcheck disable=SC2086
    $as_root apt-get update -qq >/dev/null \
      && DEBIAN_FRONTEND=noninteractive $as_root apt-get install -y -qq $missing_browsers >/dev/null \
      || echo "setup: installing$missing_browsers failed; those browser tests of the review page will skip" >&2
  else
    echo "setup: missing$missing_browsers, which cannot be installed here (needs root or sudo, and apt-get):" \
      "those browser tests of the review page will skip (apt-get install$missing_browsers)" >&2
  fi
fi
# the review page's front-end dependencies, exactly as ui/package-lock.json pins them (the build is checked in under
# services/api/ui/; tests/ui/test_build.py rebuilds it with these and compares)
if command -v npm >/dev/null; then
  lstamp=$(sha256sum ui/package-lock.json | cut -d' ' -f1)
  if [ "$(cat ui/node_modules/.setup-stamp 2>/dev/null)" != "$lstamp" ]; then
    (cd ui && npm ci --no-audit --no-fund --loglevel=error >/dev/null) && echo "$lstamp" > ui/node_modules/.setup-stamp \
      || echo "setup: npm ci in ui/ failed; the review page's rebuild test will skip" >&2
  fi
else
  echo "setup: npm not found; the review page's rebuild test will skip (the checked-in build is still served)" >&2
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
