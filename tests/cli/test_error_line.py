"""Library errors name config fields; the CLI's one-line error names its options instead."""

from __future__ import annotations

from pathlib import Path

import pytest

from sea3d.cli import error_line, main
from sea3d.errors import ConfigError
from sea3d.pipeline.process import ExecutorConfig, MapConfig, ProcessConfig

OUT = Path("unused-out")


@pytest.mark.parametrize(("message", "line"), [
    ("voxel_m must be > 0, got 0.0", "--voxel-m must be > 0, got 0.0"),
    ("give either workers or scheduler, not both",
     "give either --workers or --scheduler, not both"),
    ("x.mcap: bad chunk; refusing to convert a damaged session (strict)",
     "x.mcap: bad chunk; refusing to convert a damaged session (--strict)"),
    ("s stores no rig; give a rig file", "s stores no rig; pass --rig rig.yaml"),
    ("size_px must be at least 32x24, got (8, 8)", "--size must be at least 32x24, got (8, 8)"),
    ("depth_rate must be >= 1 frame, got 0", "--depth-rate must be >= 1 frame, got 0"),
    ("color matches 8 files but depth 7; they must pair up",
     "--color matches 8 files but --depth 7; they must pair up"),
    ("depth 'd/*.png' matches no files", "--depth 'd/*.png' matches no files"),
    ("the left source needs image records, but 'imu.csv' gives imu records",
     "--left needs image records, but 'imu.csv' gives imu records"),
    ("f.png: no right image; camera stereo needs a right camera",
     "f.png: no right image; --camera stereo needs a right camera"),
    ("the range may exclude the scene (set min_depth_m/max_depth_m)",
     "the range may exclude the scene (set --min-depth/--max-depth)"),
    ("depth d.npy lives on the rectified-left grid, not on the image's own pixels: give the rig "
     "to resample it; write raw-view depth (the raw grid) with sea3d depth",
     "depth d.npy lives on the rectified-left grid, not on the image's own pixels: pass --rig "
     "to resample it; write raw-view depth with sea3d depth --grid raw"),
    ("write depth on the grid the colour images live on (the grid option of sea3d depth)",
     "write depth on the grid the colour images live on (sea3d depth --grid)"),
])
def test_error_line_names_the_option_of_the_field(message: str, line: str) -> None:
    assert error_line(message) == line


def test_error_line_leaves_words_that_are_not_field_references() -> None:
    for text in ("the workers died", "median size_px must be odd", "a strict reading",
                 "tsdf.voxel_m must be > 0"):
        assert error_line(text) == text


def test_library_error_names_the_field_and_value() -> None:
    with pytest.raises(ConfigError, match=r"^voxel_m must be > 0, got 0\.0$"):
        ProcessConfig(out_dir=OUT, map=MapConfig(voxel_m=0.0))
    with pytest.raises(ConfigError, match=r"^workers must be >= 0, got -1$"):
        ProcessConfig(out_dir=OUT, executor=ExecutorConfig(workers=-1))
    with pytest.raises(ConfigError, match=r"^max_frames must be >= 1, got 0$"):
        ProcessConfig(out_dir=OUT, max_frames=0)


def test_cli_error_names_the_flag_and_value(tmp_path, capsys) -> None:
    assert main(["process", str(tmp_path / "none.mcap"), "-o", str(tmp_path / "o"),
                 "--voxel-m", "0"]) == 2
    err = capsys.readouterr().err
    assert "--voxel-m must be > 0, got 0.0" in err and "Traceback" not in err


def test_cli_log_filter_names_the_option() -> None:
    import logging

    from sea3d.cli import FlagNames

    record = logging.LogRecord("sea3d.io.rig_file", logging.WARNING, __file__, 1,
                               "%s holds no image size; assuming %dx%d (pass image_size to set it)",
                               ("rig.yml", 64, 48), None)
    assert FlagNames().filter(record)
    assert record.getMessage() == ("rig.yml holds no image size; assuming 64x48 (pass --size to "
                                   "set it)")
    # a field the running command's own option sets is named by that option
    record = logging.LogRecord("sea3d.recon", logging.WARNING, __file__, 1,
                               "min_observations must be >= 1, got 0", None, None)
    assert FlagNames({"min_observations": "--min-observations"}).filter(record)
    assert record.getMessage() == "--min-observations must be >= 1, got 0"


# ------------------------------------------------- the phrases still occur in the library
# error_line matches library text exactly, so a reworded library message would silently lose
# its flag spelling: every phrase must still occur in a string of the library, and every
# pattern must rewrite a sample message that a library string still produces.
_SRC = Path(__file__).resolve().parents[2] / "src" / "sea3d"
_FIELD = "\x00"  # stands for an f-string field

# A message each pattern of sea3d.cli._PATTERNS rewrites, as the library writes it.
_PATTERN_SAMPLES = {
    r"no right image; camera (\S+) needs": "f.png: no right image; camera stereo needs a right "
    "camera in every frame (2 of 3 frames have none)",
    r"(no right camera images|an image glob has one camera); camera (\S+) needs":
        "s.mcap: the session has no right camera images; camera right needs a right camera",
    r"^(color|depth) ('.*' matches no files)$": "depth 'd/*.png' matches no files",
    r"^color matches (\d+) files but depth (\d+);": "color matches 8 files but depth 7; they "
    "must pair up one to one in sorted order",
    r"^intrinsics: ": "intrinsics: focal lengths must be > 0, got (0.0, 1.0, 2.0, 3.0)",
    r"^the (left|right|imu|sonar) source needs ": "the left source needs image records, but "
    "'imu.csv' gives imu records",
    r"^align (se3|sim3) needs trajectories EST GT$": "align se3 needs trajectories EST GT",
}


def _library_strings() -> list[str]:
    """Every string literal outside sea3d.cli, an f-string's fields as ``_FIELD``."""
    import ast

    out = []
    for path in _SRC.rglob("*.py"):
        if path.relative_to(_SRC).parts[0] == "cli":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.JoinedStr):
                out.append("".join(v.value if isinstance(v, ast.Constant) else _FIELD
                                   for v in node.values))
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                out.append(node.value)
    return out


def _produces(template: str, message: str) -> bool:
    """Whether a library string (fields as ``_FIELD``) can produce ``message``, its own text
    making at least half of it (so that ``f"{where}: {why}"`` does not produce everything)."""
    import re

    parts = template.split(_FIELD)
    if 2 * sum(map(len, parts)) < len(message):
        return False
    return re.fullmatch(".+?".join(map(re.escape, parts)), message, re.S) is not None


def test_every_phrase_and_pattern_still_matches_a_library_message() -> None:
    from sea3d.cli import _PATTERNS, _PHRASES

    strings = _library_strings()
    lost = [p for p in _PHRASES if not any(p in s for s in strings)]
    assert not lost, f"phrases of sea3d.cli._PHRASES no library string holds: {lost}"
    assert {p.pattern for p, _ in _PATTERNS} == set(_PATTERN_SAMPLES), "a sample per pattern"
    for pattern, _ in _PATTERNS:
        sample = _PATTERN_SAMPLES[pattern.pattern]
        assert pattern.search(sample), (pattern.pattern, sample)
        assert any(_produces(s, sample) for s in strings), (
            f"no library string produces {sample!r} (rewritten by {pattern.pattern!r})")


def test_a_reworded_library_message_is_caught() -> None:
    sample = "f.png: no right image; camera stereo needs a right camera"
    assert _produces(f"{_FIELD}: no right image; camera {_FIELD} needs a right camera", sample)
    assert not _produces(f"{_FIELD}: no right image; the {_FIELD} camera needs a right camera",
                         sample)
    assert not _produces(f"{_FIELD}: {_FIELD}", sample)


def _options() -> tuple[set[str], set[str]]:
    """Every option of every command, and the ones that are an option's own spelling (its
    first long name; the others are deprecated aliases)."""
    import argparse

    from sea3d.cli import build_parser

    def actions(parser: argparse.ArgumentParser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from actions(sub)
            else:
                yield action

    every, own = set(), set()
    for action in actions(build_parser()):
        every.update(action.option_strings)
        own.update([o for o in action.option_strings if o.startswith("--")][:1])
    return every, own


def test_every_option_the_rewrite_names_is_spelt_as_the_commands_spell_it() -> None:
    import re

    from sea3d.cli import _FLAG_OF_FIELD, _PATTERNS, _PHRASES

    every, own = _options()
    written = [*_FLAG_OF_FIELD.values(), *_PHRASES.values(), *(r for _, r in _PATTERNS)]
    named = {f for text in written for f in re.findall(r"--[a-z][a-z0-9-]*", text)}
    assert named - every == set(), "options no command has"
    assert named - own == set(), "deprecated aliases instead of the options' own spelling"
    assert "--restore-colours" in every - own  # the check sees an alias


@pytest.mark.parametrize(("flag", "value", "named"), [
    ("--min-observations", "0", "--min-observations must be >= 1, got 0"),
    ("--hole-margin-px", "40", "--hole-margin-px must be 0..16, got 40"),
    ("--fusion-min-confidence", "1.5", "--fusion-min-confidence must be in [0, 1), got 1.5"),
])
def test_cli_error_names_the_commands_own_option_of_the_field(tmp_path, capsys, flag, value,
                                                              named) -> None:
    argv = ["process", str(tmp_path / "none.mcap"), "-o", str(tmp_path / "out"), flag, value]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == f"sea3d: error: {named}"


def test_command_flags_are_the_commands_own_options_in_their_own_spelling() -> None:
    from sea3d.cli import build_parser, command_flags

    parser = build_parser()
    process = command_flags(parser, ["-q", "process", "s.mcap", "-o", "o"])
    assert process["min_observations"] == "--min-observations"
    assert process["restore_colours"] == "--restore-colors"  # not the deprecated alias
    assert process["min_confidence"] == "--fusion-min-confidence"  # renamed by the CLI
    assert "stall_warn_s" not in process  # another command's option
    assert command_flags(parser, []) == {}
    # a field the command does not set is left to the table
    assert error_line("stall_warn_s must be > 0", process) == "--stall-warn must be > 0"
    assert error_line("min_observations must be >= 1", {}) == "min_observations must be >= 1"
