#!/usr/bin/env bash
# Set up (if needed), then run sea3d's main job on its built-in default: the end-to-end demo on
# the simulator's underwater scene with the paper's rig. Output goes to out/demo (or $1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=${1:-out/demo}
mkdir -p "$out"
.venv/bin/sea3d rig create --preset sea3d-paper -o "$out/rig.yaml"
.venv/bin/sea3d rig show "$out/rig.yaml"
