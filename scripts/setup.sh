#!/usr/bin/env bash
# Create (or reuse) .venv at the repository root and install libero-elegant with its test extra (which
# includes the openpi and ray extras' packages).
# Installs Debian's OSMesa (headless rendering), strace (the kill-injection test) and chromium (the test that
# opens a report's HTML page in a real browser) when they are missing and apt is usable.
set -euo pipefail
cd "$(dirname "$0")/.."
missing=()
ldconfig -p 2>/dev/null | grep -q libOSMesa || missing+=(libosmesa6)
command -v strace >/dev/null || missing+=(strace)
command -v chromium >/dev/null || missing+=(chromium)
if [ ${#missing[@]} -gt 0 ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null) \
    || echo "warning: could not install ${missing[*]}; rgb rendering, the kill test or the browser test may be skipped" >&2
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check "torch==2.13.0"
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".[test]"
# openpi-client without its numpy<2 pin (README: "Policies that are not ours")
.venv/bin/python -m pip install -q --disable-pip-version-check --no-deps "openpi-client==0.1.2"
.venv/bin/python -c "import torch, torchrl, libero.libero, base_suites" >/dev/null
