"""Publishing a live run while it runs: the growing mesh, the trajectory and the status, to
the Foxglove live server (:class:`~sea3d.capture.foxglove_live.FoxglovePublisher`) and the
monitor page (:class:`~sea3d.capture.monitor.MonitorServer`).

:class:`LiveFeed` is :func:`~sea3d.pipeline.live.run_live`'s ``on_update`` hook. In the live
loop's thread (the only one that changes the TSDF) it keeps the poses of the tracked frames
and, every ``mesh_interval_s`` while new frames were fused, meshes the active submap (a
finished submap is meshed once, when it reaches the store); a thread of its own encodes and
sends. The mesh goes out as ``foxglove.SceneUpdate`` entities, one per submap
(``submap-N``), on ``/mesh``: the active one each time it changed, a finished one once (and
again after a loop closure moved it, and, with a Foxglove server, every
``full_scene_interval_s`` and when a new client appears); the trajectory (tracked frames
only) on ``/odometry/trajectory``, the last pose on ``/odometry/pose`` and ``/tf``, the
status (JSON ``sea3d.LiveStatus``) on ``/live/status``. After the run the merged mesh
replaces the submaps (entity ``mesh``) and the status carries the stop reason.

The latency from a frame to its mesh update is measured per fused frame, from its arrival to
the end of the publication of the first mesh that holds it (``LiveStats.mesh_latency_s``).

Memory stays flat in the number of submaps: a finished submap's mesh is written once to the
feed's folder (``mesh_dir``: float32 vertices, int32 triangles, uint8 colours, 39 bytes a
vertex with about two triangles each) and read back only to be sent again or served as PLY;
in memory the feed keeps per finished submap its anchor, pose and sizes (about 1.4 kB), and
one mesh: the active submap's latest.

For the monitor page the feed answers ``live_state()`` (``/live.json``) and ``mesh_ply()``
(``/live/mesh.ply``); without a recorder (``--replay``) it is also the page's provider
(``stats()`` and ``latest()`` of the frames it saw).
"""

from __future__ import annotations

import io
import logging
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError
from sea3d.geometry.mesh import Mesh
from sea3d.pipeline.ordered import TRUSTED

if TYPE_CHECKING:
    from sea3d.capture.foxglove_live import FoxglovePublisher
    from sea3d.pipeline.finish import Reconstruction
    from sea3d.pipeline.live import LiveStats, LiveUpdate
    from sea3d.pipeline.ordered import OrderedStages
    from sea3d.recon.submaps import SubmapStore
    from sea3d.recon.tsdf import TsdfConfig
    from sea3d.recon.types import Submap, VoxelBlocks

__all__ = ["FeedConfig", "LiveFeed"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class FeedConfig:
    """How often the live view is updated."""

    mesh_interval_s: float = 1.0
    """Seconds between mesh updates (marching cubes of the active submap in the live loop)."""
    mesh_cpu_fraction: float = 0.1
    """At most this share of the live loop's time goes to meshing: after an update that took
    ``c`` CPU-s, the next comes no sooner than ``c / mesh_cpu_fraction`` s later (a large
    active submap is meshed less often rather than holding the odometry back)."""
    status_interval_s: float = 0.25
    """Seconds between status, pose and trajectory updates."""
    full_scene_interval_s: float = 10.0
    """Seconds between re-sends of every finished submap (for clients that missed them)."""
    max_trajectory_poses: int = 20_000
    """Longer trajectories are sent thinned to about this many poses (the last one kept)."""

    def __post_init__(self) -> None:
        if not (self.mesh_interval_s > 0 and self.status_interval_s > 0
                and self.full_scene_interval_s > 0):
            raise ConfigError("mesh_interval_s, status_interval_s and full_scene_interval_s "
                              "must be > 0")
        if not 0 < self.mesh_cpu_fraction <= 1:
            raise ConfigError(f"mesh_cpu_fraction must be in (0, 1], got "
                              f"{self.mesh_cpu_fraction}")
        if self.max_trajectory_poses < 2:
            raise ConfigError(f"max_trajectory_poses must be >= 2, got "
                              f"{self.max_trajectory_poses}")


@dataclass(eq=False)
class _Snapshot:
    t_ns: int
    status: dict[str, Any]
    trajectory: F64
    meshes: dict[str, Mesh] = field(default_factory=dict)
    arrivals: list[float] = field(default_factory=list)
    final: bool = False


@dataclass(frozen=True, kw_only=True, eq=False)
class _Finished:
    """A finished submap's mesh, on disk (in the submap's grid frame)."""

    anchor: int
    T_anchor_grid: F64
    path: Path
    vertices: int

    def load(self) -> Mesh:
        from sea3d.io.mesh_files import read_compact_mesh

        return read_compact_mesh(self.path)


class _MeshingStore:
    """A :class:`~sea3d.recon.submaps.SubmapStore` that also hands each finished submap to
    the feed; every read goes to the store it wraps."""

    def __init__(self, inner: SubmapStore, feed: LiveFeed, tsdf: TsdfConfig) -> None:
        self.inner, self.feed, self.tsdf = inner, feed, tsdf

    def put(self, submap: Submap) -> None:
        self.inner.put(submap)
        self.feed._submap_finished(submap, self.tsdf)

    def get(self, submap_id: int) -> Submap:
        return self.inner.get(submap_id)

    def ids(self) -> list[int]:
        return list(self.inner.ids())

    def head(self, submap_id: int) -> tuple[Submap, NDArray[np.int32]]:
        return self.inner.head(submap_id)

    def blocks_of(self, submap_id: int,
                  select: Callable[[NDArray[np.int32]], NDArray[np.bool_]]) -> VoxelBlocks:
        return self.inner.blocks_of(submap_id, select)


class _Frame:
    """The newest frame for the monitor and Foxglove's camera images (``t_ns``, ``image``)."""

    def __init__(self, t_ns: int, image: NDArray[Any]) -> None:
        self.t_ns, self.image = t_ns, image


class LiveFeed:
    """:func:`~sea3d.pipeline.live.run_live`'s ``on_update`` hook that publishes the run.

    Args:
        publisher: a :class:`~sea3d.capture.foxglove_live.FoxglovePublisher`, or None (the
            monitor page only).
        config: :class:`FeedConfig`.
        mesh_dir: where finished submap meshes are kept (None: a temporary folder, removed
            by :meth:`close`).
    """

    def __init__(self, publisher: FoxglovePublisher | None = None,
                 config: FeedConfig | None = None, *,
                 mesh_dir: Path | None = None) -> None:
        self.publisher = publisher
        self.config = config or FeedConfig()
        self._own_dir = mesh_dir is None
        self.mesh_dir = Path(tempfile.mkdtemp(prefix="sea3d-live-")) if mesh_dir is None \
            else Path(mesh_dir)
        self.mesh_dir.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Condition()
        self._finished: dict[int, _Finished] = {}
        self._sent_T: dict[str, F64] = {}  # finished entity: the pose it was last sent at
        self._dirty: set[int] = set()
        self._active_id: int | None = None
        self._poses: list[tuple[int, F64]] = []  # tracked frames
        self._arrivals: list[float] = []  # fused since the last mesh snapshot
        self._pending: _Snapshot | None = None
        self._last_mesh = -1e9
        self._mesh_gap_s = self.config.mesh_interval_s  # grows when meshing is expensive
        self.mesh_cpu_s = 0.0  # the loop's CPU seconds spent meshing
        self._last_status = -1e9
        self._last_full = time.monotonic()
        self._clients = 0
        self._stats: LiveStats | None = None
        self._stages: OrderedStages | None = None
        self._last_status_text: str | None = None
        self._frames: dict[str, tuple[int, _Frame]] = {}
        self._state: dict[str, Any] = {"running": True, "frames": 0, "mesh_vertices": 0,
                                       "mesh_triangles": 0, "mesh_updates": 0,
                                       "trajectory_xyz": [], "trajectory_poses": 0,
                                       "stop_reason": None}
        self._sizes: dict[str, tuple[int, int]] = {}  # what the client holds: (V, T) by entity
        self._active: tuple[str, Mesh] | None = None  # the active submap's last mesh sent
        self._final: Mesh | None = None
        self._stop = False
        self.errors: list[str] = []
        self.mesh_updates = 0
        self._thread = threading.Thread(target=self._run, name="sea3d-live-feed", daemon=True)
        self._thread.start()

    # -- wiring ----------------------------------------------------------------------------
    def wrap_store(self, store: SubmapStore, tsdf: TsdfConfig) -> SubmapStore:
        """The store to give the ordered stages: ``store``, and each finished submap meshed
        once for the live view (``tsdf``: the submaps' TSDF configuration)."""
        return _MeshingStore(store, self, tsdf)

    def _submap_finished(self, submap: Submap, tsdf: TsdfConfig) -> None:
        from sea3d.io.mesh_files import write_compact_mesh
        from sea3d.recon.tsdf import TsdfVolume

        mesh = TsdfVolume.from_blocks(submap.blocks, tsdf).extract_mesh()
        sid = int(submap.submap_id)
        path = self.mesh_dir / f"submap-{sid}.npz"
        try:
            write_compact_mesh(path, mesh)
        except OSError as err:  # the view never stops the reconstruction (the store has it)
            msg = f"live view: cannot keep submap {sid}'s mesh in {self.mesh_dir}: {err}"
            if msg not in self.errors:
                self.errors.append(msg)
                log.warning("%s", msg)
            return
        with self._lock:
            self._finished[sid] = _Finished(anchor=int(submap.anchor_keyframe_id),
                                            T_anchor_grid=np.asarray(submap.T_anchor_grid),
                                            path=path, vertices=len(mesh.vertices))
            self._dirty.add(sid)

    # -- the live loop's side --------------------------------------------------------------
    def on_update(self, u: LiveUpdate) -> None:
        """The hook (see :class:`~sea3d.pipeline.live.LiveUpdate`)."""
        est, stages = u.estimate, u.stages
        self._stats, self._stages = u.stats, stages
        late = u.late  # a late fusion: its frame was handed on
        t = int(est.t_ns) if not late or not self._poses else int(self._poses[-1][0])
        if not late:
            with self._lock:
                seq = self._frames.get("left", (0, None))[0] + 1
                self._frames["left"] = (seq, _Frame(t, u.frame.left))
                self._frames["right"] = (seq, _Frame(t, u.frame.right))
            if est.status in TRUSTED:
                self._poses.append((t, np.asarray(est.T_world_left, np.float64)))
            self._last_status_text = str(est.status.value)
        if est.loop_closure and not late:
            with self._lock:
                self._dirty.update(self._finished)
        if u.fused:
            self._arrivals.append(u.arrival_s)
        now = time.monotonic()
        mesh_due = self._arrivals and now - self._last_mesh >= self._mesh_gap_s
        if not mesh_due and now - self._last_status < self.config.status_interval_s:
            return
        snap = _Snapshot(t_ns=t, status=self._status(), trajectory=self._trajectory())
        self._last_status = now
        if mesh_due:
            self._last_mesh = now
            c0 = time.thread_time()
            snap.meshes = self._mesh_changes(stages)
            cost = time.thread_time() - c0
            self.mesh_cpu_s += cost
            self._mesh_gap_s = max(self.config.mesh_interval_s,
                                   cost / self.config.mesh_cpu_fraction)
            snap.arrivals, self._arrivals = self._arrivals, []
        self._hand_over(snap)

    def _mesh_changes(self, stages: OrderedStages) -> dict[str, Mesh]:
        """The submap meshes to send: the active one, and finished ones not sent at their
        current pose (all of them every ``full_scene_interval_s`` or for a new client)."""
        kf = stages.kf_rect
        out: dict[str, Mesh] = {}
        active = stages.fusion.active_mesh(kf)
        now = time.monotonic()
        clients = self.publisher.clients_seen() if self.publisher is not None else 0
        with self._lock:
            # every finished submap again only for a Foxglove server's clients (that may
            # have missed them); the monitor's page reads them from disk at the pose sent
            if self.publisher is not None and (
                    now - self._last_full >= self.config.full_scene_interval_s
                    or clients != self._clients):
                self._dirty.update(self._finished)
                self._last_full, self._clients = now, clients
            todo = [(sid, self._finished[sid]) for sid in sorted(self._dirty)]
            self._dirty.clear()
        for sid, fin in todo:
            T = kf.get(fin.anchor)
            if T is not None:
                T_world_grid = np.asarray(T) @ fin.T_anchor_grid
                out[f"submap-{sid}"] = fin.load().transformed(T_world_grid)
                with self._lock:
                    self._sent_T[f"submap-{sid}"] = T_world_grid
        if active is not None and active[0] not in self._finished:
            out[f"submap-{active[0]}"] = active[1]
        return out

    def _trajectory(self) -> F64:
        poses = self._poses
        n, cap = len(poses), self.config.max_trajectory_poses
        idx = range(n) if n <= cap else [*range(0, n - 1, -(-n // cap)), n - 1]
        if not poses:
            return np.zeros((0, 4, 4))
        return np.stack([poses[i][1] for i in idx])

    def _status(self) -> dict[str, Any]:
        s = self._stats
        lat = s.latency_s[-200:] if s is not None else []
        mlat = s.mesh_latency_s[-200:] if s is not None else []
        with self._lock:
            verts = sum(v for v, _ in self._sizes.values())
            tris = sum(t for _, t in self._sizes.values())
        return {"running": True, "frames": s.frames if s else 0,
                "tracked": s.tracked if s else 0, "fused": s.fused if s else 0,
                "depth_dropped": s.depth_dropped if s else 0,
                "backlog": s.backlog_max if s else 0,
                "odometry_status": self._last_status_text,
                "latency_p50_s": float(np.median(lat)) if lat else None,
                "mesh_latency_p50_s": float(np.median(mlat)) if mlat else None,
                "trajectory_poses": len(self._poses), "mesh_vertices": verts,
                "mesh_triangles": tris, "stop_reason": None}

    def _hand_over(self, snap: _Snapshot) -> None:
        with self._lock:
            old = self._pending
            if old is not None:  # not sent yet: the newer one carries both
                snap.meshes = {**old.meshes, **snap.meshes}
                snap.arrivals = old.arrivals + snap.arrivals
            self._pending = snap
            self._lock.notify_all()

    def finish(self, stats: LiveStats, reconstruction: Reconstruction) -> None:
        """After the run: the merged mesh replaces the submaps, the status says why it
        stopped; waits until that is sent, then stops the feed's thread."""
        self._stats = stats
        status = self._status()
        status.update(running=False, stop_reason=stats.stop_reason)
        t = int(self._poses[-1][0]) if self._poses else time.time_ns()
        snap = _Snapshot(t_ns=t, status=status, trajectory=self._trajectory(),
                         meshes={"mesh": reconstruction.mesh}, final=True)
        snap.arrivals, self._arrivals = self._arrivals, []
        self._hand_over(snap)
        self.close()

    def close(self) -> None:
        """Send what is pending and stop the thread (safe to call twice); a temporary mesh
        folder is removed (the merged mesh, once published, stays in memory for the page)."""
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        self._thread.join(timeout=60)
        if self._own_dir:
            shutil.rmtree(self.mesh_dir, ignore_errors=True)

    # -- the feed's thread --------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while self._pending is None and not self._stop:
                    self._lock.wait(0.5)
                snap, self._pending = self._pending, None
                if snap is None:
                    return
            try:
                self._publish(snap)
            except Exception as err:  # the view never stops the reconstruction
                msg = f"live publishing: {type(err).__name__}: {err}"
                if msg not in self.errors:
                    self.errors.append(msg)
                    log.warning("%s", msg)

    def _publish(self, snap: _Snapshot) -> None:
        pub = self.publisher
        if snap.final:
            with self._lock:
                gone = [k for k in self._sizes if k != "mesh"]
                self._sizes, self._active, self._sent_T = {}, None, {}
                self._final = snap.meshes.get("mesh")
        else:
            gone = []
        if pub is not None:
            for entity, mesh in snap.meshes.items():
                pub.publish_mesh(snap.t_ns, mesh.vertices, mesh.triangles, mesh.colors_rgb,
                                 entity_id=entity)
            if gone:
                self._delete_entities(snap.t_ns, gone)
            if len(snap.trajectory):
                pub.publish_pose(snap.t_ns, snap.trajectory[-1])
                pub.publish_trajectory(snap.t_ns, snap.trajectory)
        with self._lock:
            for entity, mesh in snap.meshes.items():
                self._sizes[entity] = (len(mesh.vertices), len(mesh.triangles))
                if entity not in self._sent_T and entity != "mesh":
                    self._active = (entity, mesh)
            verts = sum(v for v, _ in self._sizes.values())
            tris = sum(t for _, t in self._sizes.values())
        if snap.meshes:
            self.mesh_updates += 1
            done = time.monotonic()
            if self._stats is not None:
                self._stats.mesh_latency_s.extend(done - a for a in snap.arrivals)
        status = {**snap.status, "mesh_vertices": verts, "mesh_triangles": tris}
        if pub is not None:
            pub.publish_live_status(snap.t_ns, status)
        xyz = snap.trajectory[:, :3, 3]
        step = max(1, len(xyz) // 2000)
        with self._lock:
            self._state = {**status, "mesh_updates": self.mesh_updates,
                           "trajectory_xyz": np.round(xyz[::step], 4).tolist()}

    def _delete_entities(self, t_ns: int, entities: list[str]) -> None:
        from sea3d.io.foxglove_msgs import scene_deletions

        pub = self.publisher
        if pub is None or not pub.subscribed(pub.mesh):
            return
        pub.mesh.log(scene_deletions(t_ns, entities), log_time=int(t_ns))

    # -- the monitor page ------------------------------------------------------------------
    def live_state(self) -> dict[str, Any]:
        """``/live.json``: the status, the mesh's size, and the trajectory's positions
        (metres, world frame; thinned to about 2,000)."""
        with self._lock:
            return dict(self._state)

    def mesh_ply(self) -> bytes | None:
        """``/live/mesh.ply``: the mesh published so far (every entity), binary PLY; None
        before the first mesh."""
        with self._lock:
            final, active = self._final, self._active
            sent = [(self._finished[int(e.split("-")[1])], T) for e, T in self._sent_T.items()]
            if active is not None and active[0] in self._sent_T:
                active = None  # it finished: its finished mesh is in ``sent``
        if final is not None:
            meshes = [final]
        else:  # finished submaps from disk at the pose last sent, and the active one
            meshes = [fin.load().transformed(T) for fin, T in sent]
            if active is not None:
                meshes.append(active[1])
        mesh = Mesh.concatenate(meshes)
        if not len(mesh.vertices):
            return None
        return _ply_bytes(mesh)

    def stats(self) -> dict[str, Any]:
        """The monitor page's figures when no recorder runs (``--replay``)."""
        st = self.live_state()
        n = int(st.get("frames") or 0)
        return {"running": bool(st.get("running")), "mode": "live", "elapsed_s": None,
                "frames": {"left": n, "right": n}, "fps": {"left": None, "right": None},
                "dropped": {"left": 0, "right": 0}, "disk_free_bytes": None,
                "disk_left_s": None, "imu": None, "sonar": None,
                "stop_reason": st.get("stop_reason"), "live": st}

    def latest(self, stream: str) -> tuple[int, Any] | None:
        """``(seq, frame)`` of the newest frame the live loop took (``left``/``right``)."""
        with self._lock:
            return self._frames.get(stream)


def _ply_bytes(mesh: Mesh) -> bytes:
    v = np.asarray(mesh.vertices, "<f4")
    f = np.asarray(mesh.triangles, "<i4")
    col = mesh.colors_rgb
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}",
            "property float x", "property float y", "property float z"]
    if col is not None:
        head += ["property uchar red", "property uchar green", "property uchar blue"]
        rec: NDArray[Any] = np.empty(len(v), [("xyz", "<f4", 3), ("rgb", "u1", 3)])
        rec["xyz"], rec["rgb"] = v, col
    else:
        rec = v
    head += [f"element face {len(f)}", "property list uchar int vertex_indices",
             "end_header"]
    faces = np.empty(len(f), [("n", "u1"), ("idx", "<i4", 3)])
    faces["n"], faces["idx"] = 3, f
    buf = io.BytesIO()
    buf.write(("\n".join(head) + "\n").encode())
    buf.write(np.ascontiguousarray(rec).tobytes())
    buf.write(faces.tobytes())
    return buf.getvalue()
