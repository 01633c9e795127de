"""Structure from motion (pycolmap) with sea3d's cameras and rigs: self-calibrated monocular,
calibrated monocular, and metric stereo-rig models; virtual pinholes and refractive bundle
adjustment for port cameras; pose priors; metric scale of monocular trajectories from the IMU.

See ``docs/sfm.md``.
"""

from sea3d.sfm.colmap import run_sfm
from sea3d.sfm.types import PosePriors, RefractiveBaReport, SfmConfig, SfmFrame, SfmResult

__all__ = ["PosePriors", "RefractiveBaReport", "SfmConfig", "SfmFrame", "SfmResult", "run_sfm"]
