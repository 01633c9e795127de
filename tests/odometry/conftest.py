"""Fixtures of the odometry tests: the simulated survey (see ``odometry_sim``), rendered once."""

from __future__ import annotations

import pytest

from odometry._survey import SimSurvey, make_sim_survey


@pytest.fixture(scope="session")
def sim_survey(tmp_path_factory: pytest.TempPathFactory) -> SimSurvey:
    return make_sim_survey(tmp_path_factory.mktemp("odometry_sim"))
