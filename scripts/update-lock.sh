#!/usr/bin/env bash
# Regenerate the lock files from pyproject.toml (run it after changing a dependency there; commit the locks with it):
#   requirements.lock        the app, the `test` and the `ray` extras: what scripts/setup.sh and CI install
#   requirements-app.lock    the app alone: what the Docker image installs (docker/Dockerfile)
#   requirements-bench.lock  requirements.lock plus the `bench` extra (Open3D)
# The last two are constrained by the first, so a package has the same version in all three.
# Exact versions with the sha256 of every file of that release (pip install --require-hashes), resolved for
# Python >= 3.11 on every platform (--universal). uv is a tool here, not a dependency: it is installed into .venv
# when missing. Pass --upgrade to move every package to its newest release (otherwise the pins are kept where they
# still satisfy pyproject.toml).
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/python ] || "${PYTHON:-python3}" -m venv .venv
.venv/bin/python -m uv --version >/dev/null 2>&1 || .venv/bin/python -m pip install --quiet uv
compile() {
  .venv/bin/python -m uv pip compile pyproject.toml --quiet --universal --python-version 3.11 --generate-hashes \
    --no-emit-index-url --no-emit-find-links --custom-compile-command "bash scripts/update-lock.sh" "$@"
}
compile --extra test --extra ray -o requirements.lock "${@}"
compile -c requirements.lock -o requirements-app.lock "${@}"
compile --extra test --extra ray --extra bench -c requirements.lock -o requirements-bench.lock "${@}"
echo "wrote requirements.lock, requirements-app.lock and requirements-bench.lock"
