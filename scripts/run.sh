#!/usr/bin/env bash
# Set up (if needed), then run sea3d's main job on its built-in default: the end-to-end demo on
# the simulator's underwater scene with the paper's rig. Output goes to out/demo (or $1);
# further arguments go to `sea3d demo` (e.g. --frames 30 for a quicker run; --size 960x540
# renders 2.25 times the default 640x360's pixels and is slower, not quicker).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=${1:-out/demo}
mkdir -p "$out"
.venv/bin/sea3d demo -o "$out" "${@:2}"
