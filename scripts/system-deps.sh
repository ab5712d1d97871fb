#!/usr/bin/env bash
# Install the Debian packages the tests need when they are missing: Chromium (browser tests), PostgreSQL (the
# storage tests start a throw-away PostgreSQL server of their own; nothing is configured system-wide) and
# docker-compose (v1, Python: `docker-compose config` validates the compose files without a Docker engine, in
# tests/test_docker_compose.py). Needs root (or password-less sudo); without either it says what to install and
# carries on (those tests then skip and say why).
set -euo pipefail
missing=()
lean=()  # installed without their recommended packages (docker-compose would pull in the Docker engine)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
if ! command -v initdb >/dev/null 2>&1 && ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
  missing+=(postgresql)
fi
command -v docker-compose >/dev/null 2>&1 || lean+=(docker-compose)
if [ ${#missing[@]} -eq 0 ] && [ ${#lean[@]} -eq 0 ]; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    SUDO="sudo -n"
  else
    echo "scripts/system-deps.sh: please install the Debian package(s) ${missing[*]} ${lean[*]} (needs root)" >&2
    exit 0
  fi
fi
export DEBIAN_FRONTEND=noninteractive
echo "installing Debian package(s): ${missing[*]} ${lean[*]}" >&2
$SUDO apt-get update -qq
if [ ${#missing[@]} -gt 0 ]; then
  $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
if [ ${#lean[@]} -gt 0 ]; then
  $SUDO apt-get install -y -qq --no-install-recommends "${lean[@]}" >/dev/null
fi
