"""The keyframe pose graph: odometry edges within segments, loop edges with a robust kernel.

Nodes are keyframe poses ``T_world_rect``. Consecutive keyframes of one segment are joined by
the relative pose the smoother estimated; a loop adds the verified relative pose with a Cauchy
kernel, so one wrong loop cannot drag the map. The first segment's first keyframe is held
(the world's gauge); every later segment's first keyframe has only a loose prior, so segments
started after a tracking loss float until a loop joins them. Solved by gtsam's
Levenberg-Marquardt whenever a loop is added.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["PoseGraph"]

log = logging.getLogger(__name__)
F64 = NDArray[np.float64]


@dataclass
class _Loop:
    a: int
    b: int
    T_a_b: F64


@dataclass
class PoseGraph:
    """Keyframe pose graph.

    Attributes:
        rotation_sigma_rad, translation_sigma_m: odometry edge standard deviations.
        loop_rotation_sigma_rad, loop_translation_sigma_m: loop edge standard deviations.
    """

    rotation_sigma_rad: float = 0.002
    translation_sigma_m: float = 0.005
    loop_rotation_sigma_rad: float = 0.01
    loop_translation_sigma_m: float = 0.02
    loops: list[_Loop] = field(default_factory=list)

    def add_loop(self, a: int, b: int, T_a_b: F64) -> None:
        """A loop edge: keyframe ``b``'s pose in keyframe ``a``'s frame."""
        self.loops.append(_Loop(a, b, np.asarray(T_a_b, dtype=np.float64)))

    def optimise(
        self,
        odometry: dict[int, F64],
        segments: dict[int, int],
        initial: dict[int, F64],
    ) -> dict[int, F64]:
        """Solve the graph.

        Args:
            odometry: per keyframe its pose in its segment's odometry frame (4x4).
            segments: per keyframe its segment.
            initial: per keyframe the current corrected pose (the starting point).

        Returns:
            Per keyframe the optimised ``T_world_rect``.
        """
        import gtsam

        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        odo = gtsam.noiseModel.Diagonal.Sigmas(
            np.r_[[self.rotation_sigma_rad] * 3, [self.translation_sigma_m] * 3]
        )
        loop_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
            gtsam.noiseModel.Diagonal.Sigmas(
                np.r_[[self.loop_rotation_sigma_rad] * 3, [self.loop_translation_sigma_m] * 3]
            ),
        )
        held = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[1e-6] * 3, [1e-6] * 3])
        loose = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[3.0] * 3, [100.0] * 3])
        ids = sorted(odometry)
        first_of: dict[int, int] = {}
        prev_of: dict[int, int] = {}
        for k in ids:
            values.insert(k, gtsam.Pose3(initial[k]))
            s = segments[k]
            if s not in first_of:
                first_of[s] = k
                noise = held if s == min(segments.values()) else loose
                graph.add(gtsam.PriorFactorPose3(k, gtsam.Pose3(initial[k]), noise))
            else:
                p = prev_of[s]
                rel = np.linalg.inv(odometry[p]) @ odometry[k]
                graph.add(gtsam.BetweenFactorPose3(p, k, gtsam.Pose3(rel), odo))
            prev_of[s] = k
        for lp in self.loops:
            if lp.a in odometry and lp.b in odometry:
                graph.add(gtsam.BetweenFactorPose3(lp.a, lp.b, gtsam.Pose3(lp.T_a_b), loop_noise))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(50)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        return {k: np.asarray(result.atPose3(k).matrix(), dtype=np.float64) for k in ids}
