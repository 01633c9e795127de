"""Configuration of the odometry: one frozen dataclass for the library call and the CLI."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from sea3d.errors import ConfigError

__all__ = ["OdometryConfig"]


@dataclass(frozen=True, kw_only=True)
class OdometryConfig:
    """Every tunable of :mod:`sea3d.odometry`, with units in the names.

    The defaults suit 640x360 to 1920x1080 rectified images at 10-30 Hz; feature counts and
    pixel thresholds are given for 640 px wide images and scale with the image width.
    """

    # ---- front end
    max_features: int = 250
    """Features kept in tracking (new ones are detected at keyframes to top up to this)."""
    min_feature_distance_px: float = 14.0
    """Smallest distance between two features (at 640 px width)."""
    feature_quality: float = 0.005
    """Shi-Tomasi quality level relative to the image's strongest corner."""
    klt_window_px: int = 21
    """Lucas-Kanade window size (odd) for frame-to-frame tracking."""
    klt_levels: int = 3
    """Pyramid levels of frame-to-frame tracking."""
    forward_backward_px: float = 0.7
    """Largest forward-backward tracking error kept, pixels."""
    stereo_window_px: int = 15
    """Lucas-Kanade window size (odd) for left-right matching."""
    stereo_row_px: float = 1.0
    """Largest row difference of a left-right match in the rectified pair, pixels."""
    stereo_depth_agreement_px: float = 1.5
    """Largest disagreement between the matched disparity and the depth map's, pixels."""
    stereo_on_row: bool = True
    """Refine each left-right match on its own row (the disparity alone) after the 2D
    Lucas-Kanade match, in a rectified pinhole pair (:mod:`sea3d.odometry.stereo_match`: a 2D
    match slides along oblique edges and biases the disparity); matches that do not converge,
    or that move a pixel or more, are dropped. Refractive rigs keep the 2D match (their true
    matches sit off the row)."""
    min_depth_m: float | None = None
    """Nearest point used, metres; None: every point the depth map holds (its range comes
    from the rig: :class:`~sea3d.stereo.recipe.StereoDepth`)."""
    max_depth_m: float | None = None
    """Farthest point used, metres; None: every point the depth map holds (the rig's range:
    ``f B / 4 px``, where the relative depth error reaches about 1/16)."""
    min_disparity_px: float = 2.0
    """Smallest disparity of a point used, pixels."""
    pnp_threshold_px: float = 2.0
    """RANSAC reprojection threshold of the per-frame pose, pixels."""
    min_inliers: int = 20
    """Fewest inlier features for a frame to count as tracked."""
    rescue_search: bool = True
    """Before a frame is given up (IMU-only or lost), search every landmark of the last
    keyframe from its image, seeded by the predicted pose (IMU or constant velocity), with a
    window and pyramid twice tracking's, and solve PnP RANSAC on them (large motion)."""
    warped_tracking: bool = True
    """Search the features that KLT lost once more, each patch warped by the local affine map
    that the predicted pose and its landmark's depth give, aligned by Gauss-Newton and kept
    at a zero-normalised cross-correlation of 0.85 (:func:`~sea3d.odometry.frontend.
    track_warped`): large steps towards near points, and rolls, that defeat a translational
    window."""
    # ---- keyframes
    keyframe_track_ratio: float = 0.75
    """A keyframe is made when fewer than this fraction of the last keyframe's features track
    (track overlap)."""
    keyframe_parallax_rad: float = 0.1
    """A keyframe is made when the median rotation-compensated motion of the features tracked
    since the last keyframe (the parallax) passes their median stereo disparity (the motion
    has become a longer baseline than the rig's: ``t / z > B / z``) and this angle, radians,
    times the focal length (50 px at 500 px: a move of a tenth of the scene's depth, the order
    of LSD-SLAM's keyframe distance). A still or only turning camera makes no keyframe by
    parallax."""
    keyframe_max_interval_s: float = 0.5
    """Longest time between keyframes with an IMU while the camera moves, seconds (bounds the
    preintegration); a still camera (parallax under a quarter of the threshold) waits up to
    half the smoother's window (``smoother_lag_s / 2``)."""
    keyframe_max_frames: int = 30
    """Most frames between keyframes (a bound for slow drifts of the view that neither
    parallax nor overlap catch; 3 s at 10 Hz)."""
    keyframe_min_features: int = 120
    """A keyframe is made when fewer features than this are tracked, where the last keyframe
    had at least as many (an image with less texture makes keyframes by overlap and
    parallax only)."""
    # ---- back end
    smoother_lag_s: float = 3.0
    """Fixed-lag smoother window, seconds: cost per keyframe stays bounded over hours."""
    pixel_sigma_px: float = 0.5
    """Standard deviation of a stereo measurement (left u, right u, v), pixels."""
    huber_k: float = 1.345
    """Huber threshold of the stereo factors, in standard deviations."""
    imu_noise_scale: float = 2.0
    """Factor on the rig's IMU noise densities and random walks (unmodelled effects)."""
    prior_rotation_sigma_rad: float = 0.05
    """First keyframe: attitude prior (from the accelerometer) with IMU."""
    prior_velocity_sigma_mps: float = 0.5
    """First keyframe: velocity prior (zero mean) with IMU."""
    prior_accel_bias_sigma_mps2: float = 0.1
    """First keyframe: accelerometer bias prior (zero mean)."""
    prior_gyro_bias_sigma_radps: float = 0.01
    """First keyframe: gyroscope bias prior (zero mean)."""
    imu_bridge_s: float = 3.0
    """Longest vision outage bridged by the IMU before the frame is declared LOST, seconds."""
    imu_max_gap_s: float = 0.1
    """Longest gap between IMU samples that is integrated; longer gaps cut the IMU link."""
    imu_max_clock_offset_s: float = 1.0
    """IMU samples this far outside the camera frames' time disable the IMU (clock mismatch)."""
    # ---- loop closure
    loop_closure: bool = True
    """Detect loops and re-optimise the keyframe pose graph."""
    orb_features: int = 600
    """ORB features per keyframe for place recognition and verification."""
    vocabulary_branching: int = 10
    """Branching of the vocabulary tree trained on the dive's own keyframes."""
    vocabulary_depth: int = 3
    """Depth of the vocabulary tree (branching ** depth words)."""
    vocabulary_train_keyframes: int = 30
    """Keyframes whose descriptors train the vocabulary (loop detection starts after them)."""
    loop_min_gap_s: float = 20.0
    """Keyframes closer in time than this (same segment) are not loop candidates, seconds."""
    loop_min_score: float = 0.05
    """Smallest bag-of-words similarity of a loop candidate (0..1)."""
    loop_candidates: int = 10
    """Candidates geometrically verified per keyframe."""
    loop_min_inliers: int = 25
    """PnP RANSAC inliers needed to accept a loop."""
    loop_local_keyframes: int = 2
    """Keyframes on each side of a loop candidate (its segment, placed by the odometry) whose
    features join the candidate's in the geometric check (a local map, as ORB-SLAM checks a
    loop against the candidate's covisible keyframes): 0, the candidate alone."""
    loop_min_spread: float = 0.15
    """A loop's PnP inliers must span at least this fraction of the view's width and height (a
    pose fitted to a small patch of the view is not determined)."""
    loop_max_chi2: float = 22.46
    """A verified loop moves the pose graph only when its squared Mahalanobis distance from the
    graph's prediction (loop covariance plus the graph's marginal covariance of the relative
    pose) is at most this, and, after the solve, its distance from the optimised poses under
    its own covariance too (22.46: chi-square, 6 degrees of freedom, p = 0.999)."""
    loop_confirm_keyframes: int = 2
    """A loop within one joined map moves the graph only when one of the query's this many
    previous keyframes verifies the same candidate with a relative pose that agrees with the
    loop's (chi-square with both loops' covariances, :attr:`loop_max_chi2`): a pose fitted to
    one view can be wrong by degrees with its inliers still consistent, and a second view
    rarely is wrong the same way (ORB-SLAM confirms a loop by covisible keyframes). 0: a loop
    needs no confirmation."""
    loop_cooldown_keyframes: int = 3
    """Keyframes after an accepted loop before the next search."""
    pose_graph_rotation_sigma_rad: float = 0.001
    """Odometry edge of the pose graph: rotation standard deviation at rest."""
    pose_graph_translation_sigma_m: float = 0.002
    """Odometry edge of the pose graph: translation standard deviation at rest."""
    pose_graph_drift_per_m: float = 0.005
    """Odometry edge deviations grow by this per metre (and radian) moved. 0.5 %: about the
    drift the odometry shows per metre (0.56 % RPE over 60 m with the IMU on the simulated
    survey); a looser 2 % let loops less exact than the odometry pull the graph to them (the
    600-frame orbit: ATE 4.3 mm without loops, 4.9 mm with them at 2 %, 3.6 mm at 0.5 %)."""
    loop_rotation_sigma_rad: float = 0.005
    """Loop edge: rotation standard deviation."""
    loop_translation_sigma_m: float = 0.01
    """Loop edge: translation standard deviation."""
    # ---- RGB-D
    rgbd_depth_noise_m_at_1m: float = 0.003
    """RGB-D mode: depth noise at 1 m (grows with depth squared, Kinect-like), metres."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or (value is None and f.name.endswith("depth_m")):
                continue
            if not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ConfigError(
                    f"odometry config {f.name} must be a finite number >= 0, got {value!r}"
                )
        positive = (
            "max_features",
            "klt_window_px",
            "stereo_window_px",
            "pixel_sigma_px",
            "huber_k",
            "min_inliers",
            "smoother_lag_s",
            "keyframe_max_interval_s",
            "imu_noise_scale",
            "orb_features",
            "vocabulary_branching",
            "vocabulary_depth",
            "loop_min_inliers",
            "keyframe_max_frames",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"odometry config {name} must be > 0, got {getattr(self, name)}")
        if (self.min_depth_m is not None and self.max_depth_m is not None
                and self.min_depth_m >= self.max_depth_m):
            raise ConfigError(
                f"min_depth_m ({self.min_depth_m}) must be below max_depth_m ({self.max_depth_m})"
            )
        if self.klt_window_px % 2 == 0 or self.stereo_window_px % 2 == 0:
            raise ConfigError("klt_window_px and stereo_window_px must be odd")
        if not 0 < self.keyframe_track_ratio <= 1:
            raise ConfigError(
                f"keyframe_track_ratio must be in (0, 1], got {self.keyframe_track_ratio}"
            )
