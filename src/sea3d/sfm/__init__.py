"""Structure from motion (pycolmap) with sea3d's cameras and rigs: self-calibrated monocular,
calibrated monocular, and metric stereo-rig models; virtual pinholes and refractive bundle
adjustment for port cameras; pose priors; metric scale of monocular trajectories from the IMU.

See ``docs/sfm.md``.
"""

from typing import Any

from sea3d.sfm.types import PosePriors, RefractiveBaReport, SfmConfig, SfmFrame, SfmResult

__all__ = ["PosePriors", "RefractiveBaReport", "SfmConfig", "SfmFrame", "SfmResult", "run_sfm"]


def __getattr__(name: str) -> Any:
    # run_sfm imports pycolmap (over a second): only when it is used, so that the CLI can read
    # SfmConfig's defaults for its options without paying for it on every command.
    if name == "run_sfm":
        from sea3d.sfm.colmap import run_sfm

        return run_sfm
    raise AttributeError(f"module 'sea3d.sfm' has no attribute {name!r}")
