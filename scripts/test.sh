#!/usr/bin/env bash
# Set up (if needed), then lint, type-check and run the whole test suite the machine can run.
# Extra arguments go to pytest, e.g. scripts/test.sh -k dome -x
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "== ruff"
.venv/bin/ruff check src tests benchmarks
echo "== mypy"
.venv/bin/mypy src/sea3d
echo "== docs"
site_dir=$(mktemp -d)
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict --quiet --site-dir "$site_dir"
rm -rf "$site_dir"
echo "== pytest"
exec .venv/bin/python -m pytest -q "$@"
