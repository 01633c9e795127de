"""The README's tour, as written: its commands parse, and run one after the other.

The tour is the ```bash block under "## A tour" in README.md. Each command works on the files
the ones before it wrote (the simulator stands in for cameras and boards), so the slow test
runs the block as a bash script in an empty folder and checks what the last steps wrote.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from sea3d.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
MAX_COMMANDS = 12  # issue: "at most about 12 commands"


def _tour_block() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    match = re.search(r"^## A tour\n.*?^```bash\n(.*?)^```", text, flags=re.S | re.M)
    assert match, "README.md has no ```bash block under '## A tour'"
    return match.group(1)


def _commands(block: str) -> list[str]:
    """The block's lines with continuations joined, comments and blank lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", block)
    lines = (line.split(" #", 1)[0].strip() for line in joined.splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def _sea3d_commands() -> list[str]:
    return [c for c in _commands(_tour_block()) if c.startswith("sea3d ")]


def test_tour_has_at_most_twelve_sea3d_commands() -> None:
    commands = _sea3d_commands()
    assert 0 < len(commands) <= MAX_COMMANDS, commands


def test_every_tour_command_parses_with_the_cli() -> None:
    parser = build_parser()
    for command in _sea3d_commands():
        try:
            args = parser.parse_args(shlex.split(command)[1:])
        except SystemExit as err:  # argparse exits on an unknown flag or a bad value
            pytest.fail(f"README tour command does not parse (exit {err.code}): {command}")
        assert getattr(args, "handler", None) is not None, command


@pytest.mark.slow
def test_tour_runs_as_written(tmp_path: Path) -> None:
    body = "\n".join(line for line in _tour_block().splitlines() if not line.startswith(". .venv/"))
    script = (
        f'set -euo pipefail\nsea3d() {{ {shlex.quote(sys.executable)} -m sea3d "$@"; }}\n' + body
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    done = subprocess.run(
        ["bash", "-c", script],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=1200,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    tour = tmp_path / "tour"
    for made in (
        "rig.yaml",
        "dive.mcap",
        "out/dive/mesh.ply",
        "out/dive/trajectory.tum",
        "out/live/summary.json",
    ):
        assert (tour / made).is_file(), made
    assert list((tour / "depth").rglob("*.png")), "sea3d depth --session wrote no depth"
    assert "ATE: rmse" in done.stdout
    assert "accuracy (estimate to reference)" in done.stdout
