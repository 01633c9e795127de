"""One spelling per option, old ones kept as aliases; -q/-v anywhere on the line."""

import logging

import pytest

from sea3d.cli import build_parser, main


@pytest.mark.parametrize("argv, dest, value", [
    (["sim", "-o", "x.mcap"], "out", "x.mcap"),
    (["sim", "--output", "x.mcap"], "out", "x.mcap"),
    (["sim", "--out", "x.mcap"], "out", "x.mcap"),
    (["sim", "calibration", "--rig", "r.yaml", "--board", "checkerboard:9x6:40mm", "-o", "c/"],
     "cal_out", "c"),
    (["sim", "calibration", "--rig", "r.yaml", "--board", "checkerboard:9x6:40mm", "--out",
      "c/"], "cal_out", "c"),
    (["record", "--left", "a", "--right", "b", "-o", "d.mcap"], "out", "d.mcap"),
    (["record", "--left", "a", "--right", "b", "--out", "d.mcap"], "out", "d.mcap"),
    (["demo", "-o", "o/"], "out", "o"),
    (["demo", "--out", "o/"], "out", "o"),
    (["process", "s.mcap", "-o", "o", "--enhance-method", "clahe"], "enhance", "clahe"),
    (["process", "s.mcap", "-o", "o", "--enhance", "clahe"], "enhance", "clahe"),
    (["process", "s.mcap", "-o", "o", "--restore-colors", "seathru"], "restore_colours",
     "seathru"),
    (["process", "s.mcap", "-o", "o", "--restore-colours", "seathru"], "restore_colours",
     "seathru"),
])
def test_new_spelling_and_deprecated_alias_parse_alike(argv, dest, value):
    args = build_parser().parse_args(argv)
    assert str(getattr(args, dest)) == value


def test_demo_output_default_is_kept():
    assert str(build_parser().parse_args(["demo"]).out) == "out/demo"


@pytest.mark.parametrize("argv, verbose, quiet", [
    (["-q", "rig", "show", "r.yaml"], 0, True),
    (["rig", "show", "r.yaml", "-q"], 0, True),
    (["rig", "show", "-vv", "r.yaml"], 2, False),
    (["eval", "surface", "a.ply", "b.ply", "--quiet"], 0, True),
    (["-v", "rig", "show", "r.yaml"], 1, False),
])
def test_quiet_and_verbose_after_the_subcommand(argv, verbose, quiet):
    args = build_parser().parse_args(argv)
    assert (args.verbose, args.quiet) == (verbose, quiet)


def test_quiet_after_the_subcommand_silences_info(tmp_path, capsys, monkeypatch):
    root = logging.getLogger()
    # basicConfig configures only a bare root; the handler it adds (on this test's captured
    # stderr) must not outlive the test, nor the level it sets
    monkeypatch.setattr(root, "handlers", [])
    level = root.level
    try:
        assert main(["rig", "create", "--preset", "sea3d-paper", "-o",
                     str(tmp_path / "r.yaml"), "-q"]) == 0
        assert root.level == logging.WARNING
    finally:
        root.setLevel(level)


def test_a_session_loop_logs_each_message_once_and_counts_the_rest(caplog):
    from sea3d.cli._progress import once_per_message

    log = logging.getLogger("sea3d.enhance.seathru")
    other = logging.getLogger("sea3d.io")
    caplog.set_level(logging.INFO)
    with once_per_message("sea3d.enhance", "pair"):
        for _ in range(40):
            log.info("two-term fit not better than a constant")
            other.info("not mine")
    lines = [r.getMessage() for r in caplog.records]
    assert lines.count("two-term fit not better than a constant") == 1
    assert lines.count("not mine") == 40
    assert any("came 40 times in all, once per pair" in m for m in lines)


def test_json_turns_bars_off_and_quiet_does_too(capsys):
    from sea3d.cli._progress import bar

    assert bar(10, "x", enabled=False).disable is True
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.WARNING)
    try:
        assert bar(10, "x").disable is True
    finally:
        root.setLevel(level)
