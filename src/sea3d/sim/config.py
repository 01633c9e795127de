"""Settings of the simulator's runs, in a module that imports nothing heavy (no numba, no
Open3D): ``sea3d sim`` reads their defaults for its options when it builds its parser.

- :class:`SurveyConfig`: a simulated session (:func:`sea3d.sim.survey.simulate_survey`).
- :class:`CalibrationSetConfig`: a rendered calibration set
  (:func:`sea3d.sim.survey.render_calibration_set`).
"""

from __future__ import annotations

from dataclasses import dataclass

from sea3d.errors import SimulationError

__all__ = ["DEFAULT_SCENE", "CalibrationSetConfig", "SurveyConfig"]

DEFAULT_SCENE = "lake"
"""The built-in scene a survey renders unless told otherwise."""


@dataclass(frozen=True, kw_only=True)
class SurveyConfig:
    """A simulated session.

    Attributes:
        frames: number of stereo frames.
        fps: camera rate, frames per second.
        imu_rate_hz: IMU rate.
        sonar_rate_hz: echosounder rate.
        trajectory: ``lawnmower``, ``orbit`` or ``handheld``.
        water: ``none``, ``clear``, ``coastal`` or ``turbid``.
        seed: noise and hand-held wobble seed.
        supersample: rays per pixel along each axis.
        camera_tilt_deg: the cameras' downward tilt on the body; None = 60 degrees for the
            lawnmower survey (looking at the floor), 30 for the others.
        imu_noise: add MTi-300-like IMU noise.
        sonar_noise_fraction: echosounder range noise, fraction of range (standard deviation).
        clean_reference: also write each view without water (same seed) to ``gt/clean/``.
    """

    frames: int = 300
    fps: float = 10.0
    imu_rate_hz: float = 200.0
    sonar_rate_hz: float = 10.0
    trajectory: str = "lawnmower"
    water: str = "coastal"
    seed: int = 0
    supersample: int = 2
    camera_tilt_deg: float | None = None
    imu_noise: bool = True
    sonar_noise_fraction: float = 0.005
    clean_reference: bool = False

    def tilt_deg(self) -> float:
        """The camera tilt in effect (see ``camera_tilt_deg``)."""
        if self.camera_tilt_deg is not None:
            return float(self.camera_tilt_deg)
        return 60.0 if self.trajectory == "lawnmower" else 30.0

    def __post_init__(self) -> None:
        if self.frames < 1 or self.fps <= 0 or self.imu_rate_hz <= 0 or self.sonar_rate_hz <= 0:
            raise SimulationError(
                f"survey needs frames >= 1 and positive rates; got frames={self.frames}, "
                f"fps={self.fps}, "
                f"imu_rate_hz={self.imu_rate_hz}, sonar_rate_hz={self.sonar_rate_hz}"
            )


@dataclass(frozen=True, kw_only=True)
class CalibrationSetConfig:
    """A rendered calibration set: the defaults of
    :func:`~sea3d.sim.survey.render_calibration_set` (``views`` and ``board`` of
    ``sea3d sim calibration``).

    Attributes:
        board: the board, as for calibration: ``checkerboard:COLSxROWS:SQUARE`` (inner corners)
            or ``charuco:COLSxROWS:SQUARE:MARKER[:DICT][:legacy]`` (squares), or a board file.
        views: number of views.
        medium: ``water`` (through the ports) or ``air`` (the bare pinholes).
        seed: pose seed.
        distance_range_m: board distance range, metres.
        water: water effects on the images: ``none``, ``clear``, ``coastal`` or ``turbid``.
    """

    board: str = "checkerboard:9x6:40mm"
    views: int = 20
    medium: str = "water"
    seed: int = 0
    distance_range_m: tuple[float, float] = (0.5, 2.5)
    water: str = "none"
