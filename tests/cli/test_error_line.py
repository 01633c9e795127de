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
