"""sea3d: underwater stereo 3D reconstruction.

Refractive (dome- and flat-port) camera models, calibration, stereo depth, reconstruction and a
synthetic underwater world with ground truth. Conventions: ``docs/conventions.md``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("sea3d")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
