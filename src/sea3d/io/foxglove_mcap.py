"""Processed results as an MCAP file with Foxglove schemas, to open in Foxglove or Lichtblick.

``sea3d process`` writes ``OUT/results.mcap`` with :func:`write_results_mcap`::

    from sea3d.io.foxglove_mcap import write_results_mcap

    write_results_mcap(
        out / "results.mcap",
        trajectory=(t_ns, T_world_left),            # (N,) int64, (N, 4, 4) float64
        status=[e.status.value for e in estimates], # optional, one string per pose
        cloud=(points_world, colors_rgb),           # (M, 3) float64 m, (M, 3) uint8
        mesh=(vertices, triangles, vertex_colors),  # (V, 3), (T, 3), (V, 3) uint8 or None
        rig=rig,                                    # optional: left -> right in /tf
    )

What goes in (topics and schemas of :mod:`sea3d.io.foxglove_msgs`):

- per pose: ``/tf`` (``world`` -> ``left``, and ``left`` -> ``right`` from the rig) and
  ``/odometry/pose`` (``foxglove.PoseInFrame``); ``/odometry/status`` (JSON) when given;
- the whole path once, at the last stamp: ``/odometry/trajectory`` (``foxglove.PosesInFrame``);
- the cloud and the mesh once, at the last stamp (or ``t_ns`` of :meth:`ResultsMcapWriter.cloud`
  / ``mesh``): ``/cloud`` (``foxglove.PointCloud``), ``/mesh`` (``foxglove.SceneUpdate``).

Meshes larger than ``max_mesh_triangles`` are decimated with Open3D's quadric decimation first
(Foxglove renders a triangle list of a few hundred thousand triangles smoothly).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.io import foxglove_msgs as fm

__all__ = ["ResultsMcapWriter", "write_results_mcap"]

_log = logging.getLogger(__name__)

_STATUS_SCHEMA: dict[str, Any] = {
    "title": "sea3d.OdometryStatus",
    "type": "object",
    "properties": {"timestamp": {"type": "object"}, "status": {"type": "string"}},
}


class ResultsMcapWriter:
    """Write results into a new MCAP file with Foxglove schemas.

    Use as a context manager; every method may be called any number of times, with stamps in
    any order (MCAP readers sort by log time).

    Args:
        path: the ``.mcap`` file to create; must not exist.
        world_frame: name of the fixed frame (``world``).
        camera_frame: name of the moving camera frame (``left``).
        max_mesh_triangles: decimate larger meshes to this many triangles.

    Raises:
        SessionError: the file exists or cannot be created.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        world_frame: str = "world",
        camera_frame: str = "left",
        max_mesh_triangles: int = 500_000,
    ) -> None:
        import foxglove
        from foxglove.channels import (
            FrameTransformsChannel,
            PointCloudChannel,
            PoseInFrameChannel,
            PosesInFrameChannel,
        )

        self.path = Path(path)
        if self.path.exists():
            raise SessionError(f"{self.path} already exists; refusing to overwrite it")
        self.world_frame, self.camera_frame = world_frame, camera_frame
        self.max_mesh_triangles = int(max_mesh_triangles)
        self._ctx = foxglove.Context()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = foxglove.open_mcap(self.path, context=self._ctx)
        except (OSError, RuntimeError) as err:
            raise SessionError(f"cannot create {self.path}: {err}") from err
        ctx = self._ctx
        self._tf = FrameTransformsChannel(fm.TOPICS["tf"], context=ctx)
        self._pose = PoseInFrameChannel(fm.TOPICS["pose"], context=ctx)
        self._path_ch = PosesInFrameChannel(fm.TOPICS["trajectory"], context=ctx)
        self._cloud = PointCloudChannel(fm.TOPICS["cloud"], context=ctx)
        self._mesh = foxglove.Channel(fm.TOPICS["mesh"], schema=fm.SCENE_UPDATE_SCHEMA,
                                      message_encoding="protobuf", context=ctx)
        self._status = foxglove.Channel("/odometry/status", schema=_STATUS_SCHEMA, context=ctx)
        self.counts: dict[str, int] = {"poses": 0, "clouds": 0, "meshes": 0}
        self.last_t_ns = 0
        self._closed = False

    def trajectory(
        self,
        t_ns: Sequence[int] | np.ndarray,
        T_world_left: np.ndarray,
        *,
        status: Sequence[str] | None = None,
        T_left_right: np.ndarray | None = None,
    ) -> None:
        """Poses of the left camera: ``/tf``, ``/odometry/pose`` per pose, the whole path on
        ``/odometry/trajectory`` at the last stamp.

        Args:
            t_ns: (N,) integer-nanosecond stamps.
            T_world_left: (N, 4, 4) poses (maps left-camera points into the world), metres.
            status: optional (N,) tracking status strings (``tracking``, ``lost`` ...).
            T_left_right: the rig's extrinsics, published as ``left`` -> ``right``.

        Raises:
            SessionError: shapes that do not match.
        """
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        T = np.asarray(T_world_left, dtype=np.float64)
        if T.shape != (t.size, 4, 4):
            raise SessionError(
                f"{self.path}: trajectory needs (N, 4, 4) poses for N={t.size} stamps, "
                f"got {T.shape}"
            )
        if status is not None and len(status) != t.size:
            raise SessionError(f"{self.path}: {len(status)} status values for {t.size} poses")
        if t.size == 0:
            return
        try:
            for k in range(t.size):
                tk = int(t[k])
                tfs = [fm.frame_transform(tk, self.world_frame, self.camera_frame, T[k])]
                if T_left_right is not None:
                    tfs.append(fm.frame_transform(tk, self.camera_frame, "right", T_left_right))
                self._tf.log(fm.frame_transforms(tfs), log_time=tk)
                self._pose.log(fm.pose_in_frame(tk, self.world_frame, T[k]), log_time=tk)
                if status is not None:
                    self._status.log(
                        {
                            "timestamp": {"sec": tk // 10**9, "nsec": tk % 10**9},
                            "status": str(status[k]),
                        },
                        log_time=tk,
                    )
            t_last = int(t.max())
            self._path_ch.log(
                fm.poses_in_frame(t_last, self.world_frame, T[np.argsort(t)]), log_time=t_last
            )
        except Exception as err:  # the SDK raises for unrepresentable values
            if isinstance(err, SessionError):
                raise
            raise SessionError(f"{self.path}: cannot write the trajectory: {err}") from err
        self.counts["poses"] += int(t.size)
        self.last_t_ns = max(self.last_t_ns, int(t.max()))

    def cloud(
        self,
        points: np.ndarray,
        colors_rgb: np.ndarray | None = None,
        *,
        t_ns: int | None = None,
        frame_id: str | None = None,
    ) -> None:
        """A point cloud on ``/cloud``: (M, 3) metres in ``frame_id`` (default the world),
        optional (M, 3) uint8 colours; stamped ``t_ns`` (default the last pose's stamp)."""
        t = self.last_t_ns if t_ns is None else int(t_ns)
        try:
            msg = fm.point_cloud(t, frame_id or self.world_frame, points, colors_rgb)
        except ValueError as err:
            raise SessionError(f"{self.path}: cloud: {err}") from err
        self._cloud.log(msg, log_time=t)
        self.counts["clouds"] += 1

    def mesh(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        vertex_colors_rgb: np.ndarray | None = None,
        *,
        t_ns: int | None = None,
        frame_id: str | None = None,
    ) -> None:
        """A mesh scene on ``/mesh`` (see :func:`sea3d.io.foxglove_msgs.mesh_scene`); meshes
        over ``max_mesh_triangles`` are decimated first."""
        v = np.asarray(vertices, dtype=np.float64)
        tri = np.asarray(triangles, dtype=np.int64)
        col = None if vertex_colors_rgb is None else np.asarray(vertex_colors_rgb)
        if tri.ndim == 2 and tri.shape[0] > self.max_mesh_triangles:
            v, tri, col = _decimate(v, tri, col, self.max_mesh_triangles)
        t = self.last_t_ns if t_ns is None else int(t_ns)
        try:
            msg = fm.mesh_scene(t, frame_id or self.world_frame, v, tri, col)
        except ValueError as err:
            raise SessionError(f"{self.path}: mesh: {err}") from err
        self._mesh.log(msg, log_time=t)
        self.counts["meshes"] += 1

    def close(self) -> None:
        """Finish the file (summary, indexes). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except (OSError, RuntimeError) as err:
            raise SessionError(f"cannot finish {self.path}: {err}") from err
        _log.debug("wrote %s: %s", self.path, self.counts)

    def __enter__(self) -> ResultsMcapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _decimate(
    v: np.ndarray, tri: np.ndarray, col: np.ndarray | None, target: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(tri))
    if col is not None:
        m.vertex_colors = o3d.utility.Vector3dVector(np.asarray(col, np.float64) / 255.0)
    small = m.simplify_quadric_decimation(target_number_of_triangles=int(target))
    _log.info(
        "mesh decimated from %d to %d triangles for Foxglove", tri.shape[0], len(small.triangles)
    )
    out_col = None
    if col is not None and small.has_vertex_colors():
        out_col = np.clip(np.asarray(small.vertex_colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.asarray(small.vertices), np.asarray(small.triangles), out_col


def write_results_mcap(
    path: str | os.PathLike[str],
    *,
    trajectory: tuple[np.ndarray, np.ndarray] | None = None,
    status: Sequence[str] | None = None,
    cloud: tuple[np.ndarray, np.ndarray | None] | None = None,
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None,
    rig: Any = None,
    max_mesh_triangles: int = 500_000,
) -> dict[str, int]:
    """Write a processed dive's results as one MCAP file with Foxglove schemas.

    Args:
        path: the new ``.mcap`` file.
        trajectory: ``(t_ns (N,), T_world_left (N, 4, 4))``.
        status: optional tracking status per pose.
        cloud: ``(points_world (M, 3), colors_rgb (M, 3) uint8 or None)``.
        mesh: ``(vertices (V, 3), triangles (T, 3), vertex_colors_rgb (V, 3) or None)``, world.
        rig: a :class:`~sea3d.geometry.rig.StereoRig` for ``left`` -> ``right`` in ``/tf``.
        max_mesh_triangles: decimate larger meshes.

    Returns:
        Counts written: ``poses``, ``clouds``, ``meshes``.

    Raises:
        SessionError: the file exists or cannot be written, or inputs of the wrong shape.
    """
    with ResultsMcapWriter(path, max_mesh_triangles=max_mesh_triangles) as w:
        if trajectory is not None:
            T_lr = None if rig is None else np.asarray(rig.T_left_right)
            w.trajectory(trajectory[0], trajectory[1], status=status, T_left_right=T_lr)
        if cloud is not None:
            w.cloud(cloud[0], cloud[1])
        if mesh is not None:
            w.mesh(mesh[0], mesh[1], mesh[2])
        return dict(w.counts)
