"""Every command with a stereo depth range spells it --min-depth/--max-depth (metres), default
from the rig (None), with the old --min-depth-m/--max-depth-m as hidden aliases."""

from __future__ import annotations

import pytest

from sea3d.cli import build_parser
from sea3d.cli._args import depth_config

COMMANDS = [
    ["depth", "--rig", "r.yaml", "--left", "l.png", "--right", "r.png", "-o", "d.png"],
    ["process", "s.mcap", "-o", "out"],
    ["odometry", "s.mcap", "-o", "t.tum"],
    ["enhance", "in.png", "-o", "out.png", "--method", "seathru"],
    ["mono-depth", "in.png", "--model", "m.onnx", "-o", "d.png"],
    ["eval", "sonar", "s.mcap"],
]


@pytest.mark.parametrize("argv", COMMANDS, ids=[" ".join(c[:2]) for c in COMMANDS])
def test_depth_range_defaults_to_the_rig_and_old_spellings_still_parse(argv: list[str]) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    assert args.min_depth is None and args.max_depth is None
    cfg = depth_config(args)
    assert cfg.min_depth_m is None and cfg.max_depth_m is None
    new = parser.parse_args([*argv, "--min-depth", "0.7", "--max-depth", "9"])
    old = parser.parse_args([*argv, "--min-depth-m", "0.7", "--max-depth-m", "9"])
    assert (new.min_depth, new.max_depth) == (old.min_depth, old.max_depth) == (0.7, 9.0)


def test_old_spellings_are_not_listed_in_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["odometry", "--help"])
    out = capsys.readouterr().out
    assert "--min-depth " in out and "--min-depth-m" not in out
