#!/usr/bin/env bash
# The main command: installs what is missing, then starts the debugger on the built-in
# scene (the paper's four-wall Monte-Carlo world) at http://127.0.0.1:8080.
# Extra arguments go to `coplanar serve` and override these, e.g. `--scene mc-b --play`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/coplanar serve "$@"
