#!/usr/bin/env bash
# Set up sea3d on a fresh Debian (12+) machine: Debian packages, a virtual environment in .venv,
# the pinned Python packages of requirements.lock, and sea3d itself (editable). Safe to re-run:
# it skips what is already done.
set -euo pipefail
cd "$(dirname "$0")/.."

log() { printf 'setup: %s\n' "$*" >&2; }

# Debian packages: libusb and libgomp for Open3D, venv support for Python, chromium for the
# browser tests of the live monitor (optional: those tests skip without it).
apt_pkgs=(libusb-1.0-0 libgomp1 python3-venv)
if [ "${SEA3D_BROWSER_TESTS:-1}" = "1" ]; then apt_pkgs+=(chromium); fi
missing=()
for p in "${apt_pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# python3-venv is only needed when the system python lacks ensurepip.
if python3 -c 'import ensurepip' 2>/dev/null; then
  missing=("${missing[@]/python3-venv}")
fi
read -r -a missing <<<"${missing[*]}"
if [ ${#missing[@]} -gt 0 ]; then
  log "installing Debian packages: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  log "sea3d needs Python 3.11 or newer; $PY is $("$PY" --version 2>&1). Set PYTHON=/path/to/python3.11"
  exit 1
fi

if [ ! -x .venv/bin/python ]; then
  log "creating .venv with $("$PY" --version 2>&1)"
  "$PY" -m venv .venv
fi

# Reinstall only when the pins or the package metadata change.
stamp=.venv/.sea3d-installed
want=$(cat requirements.lock pyproject.toml | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  log "installing pinned Python packages (first run takes a few minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -r requirements.lock
  .venv/bin/python -m pip install -q --no-deps -e .
  echo "$want" >"$stamp"
fi
log "ready: $(.venv/bin/sea3d --version)"
