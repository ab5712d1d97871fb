#!/usr/bin/env bash
# Set up (first run only installs) and start the server on the simulated table: http://127.0.0.1:8000
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/assembly-agent serve "$@"
