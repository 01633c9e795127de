"""Synthetic underwater scenes, stereo sessions and calibration sets with ground truth.

See ``docs/simulator.md``. Rays come from the rig's own camera models, so refraction at dome and
flat ports is exact; water follows Akkaynak and Treibitz (CVPR 2018).

The settings (:mod:`sea3d.sim.config`) load at once; the renderer and everything that needs
numba or Open3D load when first named, so that ``sea3d --help`` can read the settings'
defaults without them.
"""

import importlib
from typing import TYPE_CHECKING, Any

from sea3d.sim.config import CalibrationSetConfig, SurveyConfig

if TYPE_CHECKING:  # the names __getattr__ loads, for type checkers
    from sea3d.sim.motion import HandHeld, ImuNoise, Lawnmower, Mount, Orbit, imu_samples
    from sea3d.sim.optics import WATER_PRESETS, Imaging, Water
    from sea3d.sim.render import RenderedView, Renderer, ViewTruth
    from sea3d.sim.scene import Scene, SceneObject, builtin_scene, load_scene
    from sea3d.sim.survey import (
        CalibrationSet,
        SurveyResult,
        render_calibration_set,
        simulate_pair,
        simulate_survey,
    )

__all__ = [
    "WATER_PRESETS",
    "CalibrationSet",
    "CalibrationSetConfig",
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

_LAZY = {
    **dict.fromkeys(("HandHeld", "ImuNoise", "Lawnmower", "Mount", "Orbit", "imu_samples"),
                    "motion"),
    **dict.fromkeys(("WATER_PRESETS", "Imaging", "Water"), "optics"),
    **dict.fromkeys(("RenderedView", "Renderer", "ViewTruth"), "render"),
    **dict.fromkeys(("Scene", "SceneObject", "builtin_scene", "load_scene"), "scene"),
    **dict.fromkeys(("CalibrationSet", "SurveyResult", "render_calibration_set",
                     "simulate_pair", "simulate_survey"), "survey"),
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'sea3d.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(f"sea3d.sim.{module}"), name)
