"""The keyframe pose graph: odometry edges within segments, loop edges with a robust kernel.

Nodes are keyframe poses ``T_world_rect``. Consecutive keyframes of one segment are joined by
the relative pose the smoother estimated; a loop adds the verified relative pose with a Cauchy
kernel, so one wrong loop cannot drag the map. A loop that comes with the covariance of its own
fit (a PnP loop: :attr:`~sea3d.odometry.loop.LoopCandidate.covariance`) is weighted by it, plus
the fixed loop deviations as a floor for what the fit does not see; one without is weighted by
the fixed deviations alone. The first segment's first keyframe is held
(the world's gauge); every later segment's first keyframe has only a loose prior, so segments
started after a tracking loss float until a loop joins them. Solved by gtsam's
Levenberg-Marquardt whenever a loop is added.

A loop is a guarded edit (:meth:`PoseGraph.loop_chi2`): before it moves anything, its measured
relative pose is compared with the one the graph predicts, by the Mahalanobis distance under
the sum of the loop's covariance and the graph's marginal covariance of the relative pose
(gtsam's ``Marginals``); after the solve, the loop must agree with the optimised poses within
its own covariance. Either test failing leaves the graph as it was.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d._typing import F64

__all__ = ["PoseGraph"]

log = logging.getLogger(__name__)


@dataclass
class _Loop:
    a: int
    b: int
    T_a_b: F64
    covariance: F64 | None = None


@dataclass
class PoseGraph:
    """Keyframe pose graph.

    Attributes:
        rotation_sigma_rad, translation_sigma_m: odometry edge standard deviations at rest.
        drift_per_m: growth of the odometry edge deviations per metre (and radian) moved.
        loop_rotation_sigma_rad, loop_translation_sigma_m: loop edge standard deviations (added
            to a loop's own covariance when it has one).
        loop_kernel: Cauchy threshold of the loop edges, in standard deviations.
    """

    rotation_sigma_rad: float = 0.001
    translation_sigma_m: float = 0.002
    drift_per_m: float = 0.02
    loop_rotation_sigma_rad: float = 0.005
    loop_translation_sigma_m: float = 0.01
    loop_kernel: float = 3.0
    loops: list[_Loop] = field(default_factory=list)

    def _edge_noise(self, rel: F64) -> Any:
        """Odometry edge noise that grows with the edge's motion: ``sigma_t = a + d * dist``,
        ``sigma_r = a_r + d * (angle + dist / 1 m)`` (drift per metre ``d``)."""
        import gtsam

        dist = float(np.linalg.norm(rel[:3, 3]))
        c = (float(np.trace(rel[:3, :3])) - 1.0) / 2.0
        angle = float(np.arccos(np.clip(c, -1.0, 1.0)))
        st = self.translation_sigma_m + self.drift_per_m * dist
        sr = self.rotation_sigma_rad + self.drift_per_m * (angle + dist)
        return gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sr] * 3, [st] * 3])

    def add_loop(self, a: int, b: int, T_a_b: F64, covariance: F64 | None = None) -> None:
        """A loop edge: keyframe ``b``'s pose in keyframe ``a``'s frame, optionally with the
        (6, 6) covariance of its measurement as ``T_a_b @ Exp(xi)``, ``xi = (rotation rad,
        translation m)`` in ``b`` (gtsam's Pose3 tangent)."""
        cov = None if covariance is None else np.asarray(covariance, dtype=np.float64)
        self.loops.append(_Loop(a, b, np.asarray(T_a_b, dtype=np.float64), cov))

    def _loop_noise(self, lp: _Loop) -> Any:
        """Cauchy-robust loop edge noise: the fixed deviations, plus the loop's covariance."""
        import gtsam

        base: Any = gtsam.noiseModel.Gaussian.Covariance(self.loop_covariance(lp))
        return gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(self.loop_kernel), base
        )

    def loop_covariance(self, lp: _Loop) -> F64:
        """(6, 6) Gaussian covariance of a loop edge (its own covariance plus the floor)."""
        floor = np.r_[[self.loop_rotation_sigma_rad] * 3, [self.loop_translation_sigma_m] * 3]
        if lp.covariance is None:
            return np.diag(floor**2)
        return 0.5 * (lp.covariance + lp.covariance.T) + np.diag(floor**2)

    def loops_agree(self, T_c_q: F64, cov_q: F64 | None, T_q_p: F64, T_c_p: F64,
                    cov_p: F64 | None) -> float:
        """Squared Mahalanobis distance between two loops to one candidate ``c``: from query
        ``q`` (``T_c_q``) and from a keyframe ``p`` just before it (``T_c_p``), with ``T_q_p``
        the odometry between the two queries (taken as exact: over a keyframe or two it is far
        better known than either loop). ``e = Log((T_c_q T_q_p)^-1 T_c_p)`` in ``p``'s tangent,
        ``S = Ad(T_q_p^-1) S_q Ad(T_q_p^-1)^T + S_p`` with each loop's
        :meth:`loop_covariance`; chi-square with 6 degrees of freedom when both are right.

        Args:
            T_c_q: 4x4 the first loop (maps ``q`` into ``c``).
            cov_q: (6, 6) its covariance, or None.
            T_q_p: 4x4 maps ``p`` into ``q`` (odometry).
            T_c_p: 4x4 the second loop (maps ``p`` into ``c``).
            cov_p: (6, 6) its covariance, or None.

        Returns:
            The squared distance (inf when the covariance is singular).
        """
        import gtsam

        pred = T_c_q @ T_q_p
        e = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(pred) @ T_c_p)))
        Ad = np.asarray(gtsam.Pose3(T_q_p).inverse().AdjointMap())
        S_q = self.loop_covariance(_Loop(0, 1, T_c_q, cov_q))
        S = Ad @ S_q @ Ad.T + self.loop_covariance(_Loop(0, 1, T_c_p, cov_p))
        try:
            return float(e @ np.linalg.solve(S, e))
        except np.linalg.LinAlgError:
            return float("inf")

    def loop_chi2(
        self,
        a: int,
        b: int,
        T_a_b: F64,
        covariance: F64 | None,
        odometry: dict[int, F64],
        segments: dict[int, int],
        poses: dict[int, F64],
        *,
        marginal: bool = True,
    ) -> float | None:
        """Squared Mahalanobis distance of a loop measurement from the graph's poses.

        With ``e = Log(T_pred^-1 T_a_b)`` (gtsam's Pose3 tangent in ``b``), ``T_pred =
        poses[a]^-1 poses[b]`` and ``S`` the loop's covariance (:meth:`loop_covariance`) plus,
        when ``marginal``, the covariance of ``T_pred`` from the graph's joint marginal of ``a``
        and ``b`` (transported into ``b``: ``J = [-Ad(T_pred^-1), I]``), the distance is
        ``e^T S^-1 e``: chi-square with 6 degrees of freedom when the loop and the graph agree.
        Keyframes of segments that no loop has joined yet are tied only by their loose priors,
        so such a loop is never judged against them.

        Args:
            a, b: keyframe ids of the loop (``T_a_b`` maps ``b`` into ``a``).
            T_a_b: 4x4 measured relative pose.
            covariance: (6, 6) its covariance, or None.
            odometry, segments: as for :meth:`optimise`.
            poses: per keyframe its ``T_world_rect`` (the current solution, or the optimised).
            marginal: add the graph's uncertainty of the predicted relative pose (before the
                solve); False judges the loop by its own covariance alone (after the solve).

        Returns:
            The squared distance (inf when the covariance is singular), or None when the graph
            cannot predict the relative pose (its marginal is indeterminate: a segment tied to
            the rest by nothing but its loose prior).
        """
        import gtsam

        T_pred = np.linalg.inv(poses[a]) @ poses[b]
        e = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(T_pred) @ T_a_b)))
        S = self.loop_covariance(_Loop(a, b, T_a_b, covariance))
        if marginal:
            graph, values = self._build(odometry, segments, poses)
            try:
                marg = gtsam.Marginals(graph, values)
                jm = marg.jointMarginalCovariance(gtsam.KeyVector([a, b]))
            except RuntimeError:  # gtsam's IndeterminateLinearSystemException
                return None
            cov = np.block([[jm.at(a, a), jm.at(a, b)], [jm.at(b, a), jm.at(b, b)]])
            J = np.hstack([-np.asarray(gtsam.Pose3(T_pred).inverse().AdjointMap()), np.eye(6)])
            S = S + J @ cov @ J.T
        try:
            return float(e @ np.linalg.solve(S, e))
        except np.linalg.LinAlgError:
            return float("inf")

    def _build(
        self,
        odometry: dict[int, F64],
        segments: dict[int, int],
        initial: dict[int, F64],
    ) -> tuple[Any, Any]:
        """The factor graph and its starting values (see :meth:`optimise`)."""
        import gtsam

        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
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
                graph.add(gtsam.BetweenFactorPose3(p, k, gtsam.Pose3(rel), self._edge_noise(rel)))
            prev_of[s] = k
        for lp in self.loops:
            if lp.a in odometry and lp.b in odometry:
                noise = self._loop_noise(lp)
                graph.add(gtsam.BetweenFactorPose3(lp.a, lp.b, gtsam.Pose3(lp.T_a_b), noise))
        return graph, values

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

        graph, values = self._build(odometry, segments, initial)
        ids = sorted(odometry)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(50)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        return {k: np.asarray(result.atPose3(k).matrix(), dtype=np.float64) for k in ids}
