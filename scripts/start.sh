#!/usr/bin/env bash
# The main command: installs what is missing, then starts the debugger at
# http://127.0.0.1:8080 with the stereo pipeline on the rendered `room` scene (60 s of
# motion, frames rendered on demand).
# Extra arguments go to `coplanar serve`, e.g. `--scene corridor`, `--dataset DIR`, or the
# paper's Monte-Carlo worlds `--scene mc-a --play`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/coplanar serve "$@"
