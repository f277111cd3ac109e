#!/usr/bin/env bash
# Creates the virtual environment of `make python` at $1 (once) and installs the pinned requirements.
# On a Debian whose python3 lacks the venv module, installs python3-venv first.
set -euo pipefail
venv="$1"
req="$(dirname "$0")/requirements-dev.txt"
if [ ! -x "$venv/bin/python" ]; then
  if ! python3 -c 'import venv, ensurepip' 2>/dev/null; then
    sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    echo "installing python3-venv (python3 has no venv module)" >&2
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends python3-venv >/dev/null
  fi
  python3 -m venv "$venv"
fi
if ! cmp -s "$req" "$venv/.requirements"; then
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$req"
  cp "$req" "$venv/.requirements"
fi
