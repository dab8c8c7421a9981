#!/usr/bin/env bash
# Runs the test suite: installs coplanar with its test tools where missing, then pytest.
# Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh" --test
cd "$root"
exec .venv/bin/python -m pytest tests "$@"
