"""A short simulated survey shared by the pipeline tests (rendered once per test session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sea3d.cli import main

SESSION_FRAMES = 30
SESSION_SIZE = "320x180"


@pytest.fixture(scope="session")
def sim_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """30 frames of the lake in coastal water through the paper's dome rig, 320x180, 10 fps,
    as an MCAP file with its ground truth beside it in ``lake_gt/``."""
    out = tmp_path_factory.mktemp("sim") / "lake.mcap"
    code = main(["-q", "sim", "--scene", "lake", "--frames", str(SESSION_FRAMES), "--size",
                 SESSION_SIZE, "--water", "coastal", "--out", str(out)])
    assert code == 0
    return out
