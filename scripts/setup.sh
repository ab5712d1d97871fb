#!/usr/bin/env bash
# Create .venv (if missing) and install the package with its test and ray extras. Idempotent and quick when nothing
# changed: the install is skipped while pyproject.toml matches the stamp of the last successful install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
STAMP=.venv/.assembly-agent-installed
WANT=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$WANT" ] && .venv/bin/python -c "import app, tracker" 2>/dev/null; then
  exit 0
fi
echo "setting up .venv (first run or pyproject.toml changed)..." >&2
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e ".[test,ray]"
# opencv-contrib-python-headless (AKAZE for the odometry's FastSLAM option) replaces opencv-python-headless; both
# install the cv2 package, so a venv that still has the plain one loses it and gets contrib reinstalled over it.
if .venv/bin/python -m pip show opencv-python-headless >/dev/null 2>&1; then
  .venv/bin/python -m pip uninstall --quiet -y opencv-python-headless
  .venv/bin/python -m pip install --quiet --force-reinstall --no-deps opencv-contrib-python-headless
fi
echo "$WANT" > "$STAMP"
