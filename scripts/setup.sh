#!/usr/bin/env bash
# Creates .venv with Python 3.11 and installs coplanar with its pinned dependencies
# (and the test tools when called with --test). Re-running is cheap: it reinstalls only
# when pyproject.toml changed. Sourced by start.sh and test.sh.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

# --chromium: only make sure Debian's Chromium is there (the browser tests drive it).
if [ "${1:-}" = "--chromium" ]; then
  if [ -x /usr/bin/chromium ]; then exit 0; fi
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
    echo "installing chromium (Debian) for the browser tests" >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    exit 0
  fi
  echo "cannot install chromium: needs apt-get and root" >&2
  exit 1
fi

extras=""
if [ "${1:-}" = "--test" ]; then extras="[test]"; fi

python_bin=""
for cand in python3.11 python3; do
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)'; then
    python_bin="$(command -v "$cand")"; break
  fi
done
if [ -z "$python_bin" ]; then
  echo "error: coplanar needs Python 3.11 (python3.11 or python3 on PATH)" >&2
  exit 2
fi

# Python's venv module is a separate Debian package on some systems.
if ! "$python_bin" -c 'import venv, ensurepip' >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
    echo "installing python3-venv (Debian)" >&2
    apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
  else
    echo "error: Python's venv module is missing: install python3-venv" >&2
    exit 2
  fi
fi

if [ ! -x .venv/bin/python ]; then
  "$python_bin" -m venv .venv
fi

# open3d (the typed map exports and the dense check) needs libusb-1.0 to import.
has_libusb() {
  local f
  for f in /usr/lib/*/libusb-1.0.so.0 /lib/*/libusb-1.0.so.0 /usr/lib/libusb-1.0.so.0 /usr/lib64/libusb-1.0.so.0; do
    [ -e "$f" ] && return 0
  done
  { /sbin/ldconfig -p 2>/dev/null || ldconfig -p 2>/dev/null; } | grep -q 'libusb-1\.0\.so\.0'
}
if ! has_libusb; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = "0" ]; then
    echo "installing libusb-1.0-0 (Debian), which open3d needs" >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "warning: libusb-1.0 is missing and cannot be installed (needs apt-get and root): the map-file exports and --dense will say so" >&2
  fi
fi

stamp=".venv/.coplanar-installed${extras}"
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "installing coplanar${extras} and its pinned dependencies into .venv" >&2
  .venv/bin/python -m pip install --quiet --upgrade "pip==25.3"
  .venv/bin/python -m pip install --quiet -e ".${extras}"
  echo "$want" > "$stamp"
fi
