#!/usr/bin/env bash
# Set up taichi_anim on a fresh Debian machine (as root) or any machine with Python 3.10-3.12.
# Usage: scripts/setup.sh [dev]   — creates .venv and installs the package (with test extras for "dev").
set -euo pipefail
cd "$(dirname "$0")/.."
# Open3D loads libusb-1.0 at import time; a fresh Debian image does not have it.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        apt-get update -qq && apt-get install -y -qq --no-install-recommends libusb-1.0-0 >/dev/null
    else
        echo "setup: libusb-1.0 is missing; install it (Debian: apt-get install libusb-1.0-0)" >&2
        exit 1
    fi
fi
PY=${PYTHON:-python3}
# Debian's system Python ships venv (with ensurepip) in a separate package.
if ! "$PY" -c 'import ensurepip, venv' >/dev/null 2>&1; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        apt-get update -qq && apt-get install -y -qq --no-install-recommends python3-venv >/dev/null
    else
        echo "setup: $PY has no venv module; install python3-venv" >&2
        exit 1
    fi
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
if [ "${1:-}" = dev ]; then
    .venv/bin/python -m pip install -q -e ".[dev]"
else
    .venv/bin/python -m pip install -q -e .
fi
