#!/usr/bin/env bash
# Set up (if needed), then run sea3d's main job on its built-in default: the end-to-end demo on
# the simulator's underwater scene with the paper's rig. Output goes to out/demo (or $1);
# further arguments go to `sea3d demo` (e.g. --frames 30 for a quicker run; --size 960x540
# renders 2.25 times the default 640x360's pixels and is slower, not quicker: 10 frames took
# 41 s wall / 33 s CPU at 960x540 against 34 s / 23 s at 640x360, one run each, loaded machine).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=${1:-out/demo}
mkdir -p "$out"
.venv/bin/sea3d demo -o "$out" "${@:2}"
