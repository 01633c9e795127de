"""Shared fixtures: the real-data folder and seeded random generators.

Tolerances are kept in ``tests/tolerances.py`` with their units in their names.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

_DEFAULT_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def _data_root() -> Path:
    return Path(os.environ.get("SEA3D_TEST_DATA", str(_DEFAULT_DATA))).resolve()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The real test data folder (``SEA3D_TEST_DATA``, default ``../shared/data``).

    Tests using it are marked ``data``; they skip with a clear message when it is missing.
    """
    root = _data_root()
    if not root.is_dir():
        pytest.skip(f"real test data not found at {root} (set SEA3D_TEST_DATA)")
    return root


@pytest.fixture
def rng() -> np.random.Generator:
    """One seeded generator per test; never the global RNG."""
    return np.random.default_rng(0)


def _register_hypothesis_profiles() -> None:
    """Property-based drills: a fast default for CI, the thorough run with SEA3D_DRILLS=full."""
    try:
        from hypothesis import HealthCheck, settings
    except ImportError:  # pragma: no cover - hypothesis is a dev dependency
        return
    settings.register_profile(
        "ci", max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow]
    )
    settings.register_profile(
        "full", max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow]
    )
    settings.load_profile("full" if os.environ.get("SEA3D_DRILLS") == "full" else "ci")


_register_hypothesis_profiles()


pytest_plugins = ["crash_handlers"]
