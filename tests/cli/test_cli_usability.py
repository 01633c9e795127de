"""What a new user meets first: help texts, the files the CLI writes, plain-English counts."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest

from sea3d.cli import build_parser, main
from sea3d.cli._args import plural


def _subparser(*names: str) -> argparse.ArgumentParser:
    parser = build_parser()
    for name in names:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


@pytest.mark.parametrize("command", [("demo",), ("sim",), ("sim", "calibration"),
                                     ("calibrate", "stereo"), ("calibrate", "port"),
                                     ("rig", "convert")])
def test_every_option_says_what_it_does(command: tuple[str, ...]) -> None:
    parser = _subparser(*command)
    for action in parser._actions:
        if action.option_strings and action.help is not argparse.SUPPRESS:
            assert action.help, f"{' '.join(command)} {action.option_strings[0]} has no help"
    text = parser.format_help()
    # No internal destination names (CAL_RIG, CAL_OUT) as metavars.
    assert "CAL_" not in text


def test_sim_help_shows_the_subcommand_as_optional(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["sim", "--help"])
    text = capsys.readouterr().out
    assert "SUBCOMMAND" not in text
    assert "sea3d sim [options]" in text and "sea3d sim calibration [options]" in text
    with pytest.raises(SystemExit):
        main(["sim", "calibration", "--help"])
    # -v and -q are accepted after the subcommand too
    assert capsys.readouterr().out.startswith(
        "usage: sea3d sim calibration [-h] [-v] [-q] [--rig RIG]")


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_rig_files_get_the_usual_permissions(tmp_path: Path, umask: int) -> None:
    old = os.umask(umask)
    try:
        assert main(["rig", "create", "--preset", "sea3d-paper", "-o",
                     str(tmp_path / "rig.yaml")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "rig.yaml").stat().st_mode & 0o777 == 0o666 & ~umask
    assert [p.name for p in tmp_path.iterdir()] == ["rig.yaml"]  # no temporary file left


def test_rig_convert_refuses_an_extension_that_names_no_format(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = tmp_path / "rig.yaml"
    assert main(["rig", "create", "--preset", "sea3d-paper", "-o", str(rig)]) == 0
    capsys.readouterr()
    assert main(["rig", "convert", str(rig), str(tmp_path / "rig.xyz")]) == 2
    err = capsys.readouterr().err
    assert "rig.xyz" in err and "'.xyz'" in err and "--format" in err and "\n" == err[-1]
    assert not (tmp_path / "rig.xyz").exists()
    assert main(["rig", "convert", str(rig), str(tmp_path / "rig.xyz"), "--format",
                 "sea3d"]) == 0
    assert (tmp_path / "rig.xyz").read_text().startswith(rig.read_text()[:20])


def test_counts_read_as_english() -> None:
    assert [plural(n, "pair") for n in (0, 1, 2)] == ["0 pairs", "1 pair", "2 pairs"]
    assert plural(1, "problem") == "1 problem" and plural(3, "problem") == "3 problems"
