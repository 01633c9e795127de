#!/usr/bin/env bash
# Set up (if needed), then run sea3d's main job on its built-in default: the end-to-end demo on
# the simulator's underwater scene with the paper's rig. Output goes to out/demo (or $1);
# further arguments go to `sea3d demo` (e.g. --size 960x540 for a quicker run).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=${1:-out/demo}
mkdir -p "$out"
.venv/bin/sea3d demo -o "$out" "${@:2}"
