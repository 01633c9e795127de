"""Calibration: boards and their detection, stereo calibration (in air, or in water with
refraction absorbed), refractive dome/flat-port calibration, reports and guidance.

See ``docs/calibration.md``.
"""

from sea3d.calib.port import (
    PortCalibConfig,
    PortCalibration,
    PortRigCalibration,
    calibrate_port,
    calibrate_port_rig,
)
from sea3d.calib.stereo import (
    CalibrationStatus,
    StereoCalibConfig,
    StereoCalibration,
    calibrate_stereo,
)
from sea3d.calib.targets import (
    BoardSpec,
    Detection,
    DetectionStatus,
    detect_board,
    load_board,
    parse_board,
    render_board,
)

__all__ = [
    "BoardSpec",
    "CalibrationStatus",
    "Detection",
    "DetectionStatus",
    "PortCalibConfig",
    "PortCalibration",
    "PortRigCalibration",
    "StereoCalibConfig",
    "StereoCalibration",
    "calibrate_port",
    "calibrate_port_rig",
    "calibrate_stereo",
    "detect_board",
    "load_board",
    "parse_board",
    "render_board",
]
