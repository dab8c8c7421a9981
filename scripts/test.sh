#!/usr/bin/env bash
# Runs the test suite: installs coplanar with its test tools and Debian's Chromium (for the
# browser tests) where missing, then ruff (lint and format), mypy and pytest.
# Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh" --test
bash "$root/scripts/setup.sh" --chromium || echo "warning: Chromium could not be installed: the browser tests will skip" >&2
cd "$root"
# The habits first: lint, format and types (pyproject.toml), each a one-line summary when clean.
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/mypy
exec .venv/bin/python -m pytest tests "$@"
