#!/usr/bin/env bash
# Creates .venv and installs nbvs_drake with its test extras. Installs the Debian packages the
# stack needs (open3d: libusb-1.0-0; VTK's headless rendering: EGL/Mesa; diagram pictures:
# graphviz) when they are missing and we are root; otherwise says which ones to install.
# Optional: chromium (headless screenshots of replay.html in tests/test_replay.py and
# scripts/screenshot_replay.py; the test is skipped without it): installed the same way, but
# a failure there does not stop the set-up.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
DEB_PKGS="libusb-1.0-0 libegl1 libegl-mesa0 libgl1-mesa-dri graphviz"
DEB_PKGS_OPTIONAL="chromium"

# not_installed PKG...: prints those of the Debian packages that are not installed
not_installed() {
  command -v dpkg-query >/dev/null 2>&1 || return 0
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || printf ' %s' "$p"
  done
}

missing="$(not_installed $DEB_PKGS)"
if [ -n "$missing" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing Debian packages:$missing"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $missing >/dev/null
  else
    echo "setup: please install these Debian packages (as root):$missing" >&2
  fi
fi
optional="$(not_installed $DEB_PKGS_OPTIONAL)"
if [ -n "$optional" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing optional Debian packages:$optional"
    export DEBIAN_FRONTEND=noninteractive
    { [ -n "$missing" ] || apt-get update -qq; } && apt-get install -y -qq --no-install-recommends $optional >/dev/null \
      || echo "setup: could not install$optional (optional: replay.html screenshots)" >&2
  else
    echo "setup: optional Debian packages (replay.html screenshots):$optional" >&2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
.venv/bin/python -c "import pydrake, open3d, numba; print('setup: ok (drake, open3d', open3d.__version__ + ', numba', numba.__version__ + ')')"
# compile the motion planner's numba kernels into numba's cache now, not in the first plan
.venv/bin/python -m nbvs_drake.app.warmup
