#!/usr/bin/env bash
# Set up and run the whole test suite (unit, integration, browser) and the linter.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/system-deps.sh
bash scripts/setup.sh
export CHROMIUM_PATH=${CHROMIUM_PATH:-$(command -v chromium || echo /usr/bin/chromium)}
.venv/bin/ruff check .
.venv/bin/python -m pytest -q "$@"
