"""Fixtures of the odometry tests, each made once per test session: the simulated survey (see
``odometry_sim``) and the real 7-Scenes chess clip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from odometry._chess import load_chess
from odometry._survey import SimSurvey, make_sim_survey

CHESS_FRAMES = 60
"""The whole 60-frame clip, as in benchmarks/bench_odometry.py --only chess (on shorter
prefixes ours and Open3D frame-to-frame are within the ground truth's noise: ours wins on 20
and 50 frames, loses on 30 and 40; see docs/odometry.md)."""


@pytest.fixture(scope="session")
def sim_survey(tmp_path_factory: pytest.TempPathFactory) -> SimSurvey:
    return make_sim_survey(tmp_path_factory.mktemp("odometry_sim"))


@pytest.fixture(scope="session")
def chess(data_dir: Path) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """The chess clip's ``CHESS_FRAMES`` frames (RGB, depth in metres) and ground-truth poses,
    shared by the dense and frame-to-model RGB-D tests (read-only: do not modify in place)."""
    return load_chess(data_dir, CHESS_FRAMES)
