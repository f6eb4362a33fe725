#!/usr/bin/env bash
# Create (or reuse) .venv at the repository root and install libero-elegant with its test extra.
# Installs Debian's OSMesa for headless rendering when it is missing and apt is usable.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ldconfig -p 2>/dev/null | grep -q libOSMesa; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null) \
      || echo "warning: could not install libosmesa6; rgb observations will not render" >&2
  fi
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check "torch==2.13.0"
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test]"
.venv/bin/python -c "import torch, torchrl, libero.libero, base_suites" >/dev/null
