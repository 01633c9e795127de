"""Synthetic underwater scenes, stereo sessions and calibration sets with ground truth.

See ``docs/simulator.md``. Rays come from the rig's own camera models, so refraction at dome and
flat ports is exact; water follows Akkaynak and Treibitz (CVPR 2018).
"""

from sea3d.sim.motion import HandHeld, ImuNoise, Lawnmower, Mount, Orbit, imu_samples
from sea3d.sim.optics import WATER_PRESETS, Imaging, Water
from sea3d.sim.render import RenderedView, Renderer, ViewTruth
from sea3d.sim.scene import (
    Scene,
    SceneObject,
    builtin_scene,
    load_scene,
)
from sea3d.sim.survey import (
    CalibrationSet,
    SurveyConfig,
    SurveyResult,
    render_calibration_set,
    simulate_pair,
    simulate_survey,
)

__all__ = [
    "WATER_PRESETS",
    "CalibrationSet",
    "HandHeld",
    "Imaging",
    "ImuNoise",
    "Lawnmower",
    "Mount",
    "Orbit",
    "RenderedView",
    "Renderer",
    "Scene",
    "SceneObject",
    "SurveyConfig",
    "SurveyResult",
    "ViewTruth",
    "Water",
    "builtin_scene",
    "imu_samples",
    "load_scene",
    "render_calibration_set",
    "simulate_pair",
    "simulate_survey",
]
