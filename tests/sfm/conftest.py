"""A small simulated stereo session shared by the structure-from-motion tests.

Ten 320x180 frames of the simulator's lake scene in clear water, orbiting the ArUco cube,
through the paper's dome-port rig (``paper_rig("dome")``), as a folder session with its rig and
ground truth (``gt/poses_left.tum``). Rendered once per test session (about 8 s of CPU).
"""

from __future__ import annotations

from pathlib import Path

import pytest

N_FRAMES = 10
SIZE_PX = (320, 180)


@pytest.fixture(scope="session")
def sim_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import SurveyConfig, builtin_scene, simulate_survey

    root = tmp_path_factory.mktemp("sfm_sim") / "session"
    rig = paper_rig("dome", size_px=SIZE_PX)
    with SessionWriter(root, format="folder", rig_yaml=rig_to_yaml(rig)) as writer:
        simulate_survey(builtin_scene("lake"), rig,
                        SurveyConfig(frames=N_FRAMES, trajectory="orbit", water="clear"),
                        writer, root / "gt")
    return root
