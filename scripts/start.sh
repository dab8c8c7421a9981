#!/usr/bin/env bash
# The main command: installs what is missing, then runs the paper's Monte-Carlo study on
# sequence b (30 runs), prints its table and writes out/sim.json, out/sim.png and the
# Hessian images in out/hessian/. (The web debugger takes this place in a later release.)
# Extra arguments go to `coplanar sim` and override these, e.g. `--sequence a --runs 5`.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
cd "$root"
mkdir -p out
exec .venv/bin/coplanar sim --sequence b --runs 30 --json out/sim.json --hessian-dir out/hessian "$@"
