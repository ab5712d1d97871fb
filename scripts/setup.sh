#!/usr/bin/env bash
# Create .venv (if missing) and install the locked dependencies (requirements.lock: the app with its test and ray
# extras, exact versions checked against their sha256 hashes), then the package itself (editable, no dependencies).
# Idempotent and quick when nothing changed: the install is skipped while pyproject.toml and the lock file match
# the stamp of the last successful install. LOCK=requirements-bench.lock adds the benchmarks' Open3D.
# Regenerate the lock with scripts/update-lock.sh after changing a dependency in pyproject.toml.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
LOCK=${LOCK:-requirements.lock}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
STAMP=.venv/.assembly-agent-installed
WANT=$(cat pyproject.toml "$LOCK" | sha256sum | cut -d' ' -f1)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$WANT" ] && .venv/bin/python -c "import app, tracker" 2>/dev/null; then
  exit 0
fi
echo "setting up .venv from $LOCK (first run, or pyproject.toml or the lock changed)..." >&2
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet --require-hashes -r "$LOCK"
.venv/bin/python -m pip install --quiet --no-deps -e .
# opencv-contrib-python-headless (AKAZE for the odometry's FastSLAM option) replaces opencv-python-headless; both
# install the cv2 package, so a venv that still has the plain one loses it and gets contrib reinstalled over it.
if .venv/bin/python -m pip show opencv-python-headless >/dev/null 2>&1; then
  .venv/bin/python -m pip uninstall --quiet -y opencv-python-headless
  # its entry of the lock (the pin and its hash lines, up to the next package)
  awk '/^opencv-contrib-python-headless==/ {p = 1; print; next} p && /^[^ ]/ {p = 0} p' "$LOCK" > .venv/opencv.lock
  .venv/bin/python -m pip install --quiet --force-reinstall --no-deps --require-hashes -r .venv/opencv.lock
fi
if ! problems=$(.venv/bin/python -m pip check 2>&1); then
  echo "$problems" >&2
  echo "scripts/setup.sh: the installed packages do not fit pyproject.toml; if a dependency changed there, run" \
    "'bash scripts/update-lock.sh' and commit the lock files with it" >&2
  exit 1
fi
echo "$WANT" > "$STAMP"
