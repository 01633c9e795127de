"""``sea3d eval sonar``: load a session, its rig's echosounder mount, poses and depth, run
:func:`sea3d.eval.sonar.evaluate_sonar`, and write the HTML report.

Where things come from:

- the echosounder mount: ``--rig`` or the session's rig (its ``sonar:`` block), else the
  simulator's ``gt/sim.json`` (``T_body_left``, ``T_body_sonar``);
- poses: ``--poses FILE.tum`` (``T_world_left``, e.g. the odometry's ``trajectory.tum``), else
  the simulator's ground truth ``gt/poses_left.tum``, else none (same-instant fit);
- depth: ``--depth DIR`` with ``DIR/depth/<t_ns>.png`` from ``sea3d depth --session`` (16-bit
  millimetres along the rectified left camera) or ``<t_ns>.npy`` / ``.tiff`` (float32 metres;
  with ``depth_frame="raw"`` along the raw left camera, as the simulator's ``gt/depth``), else
  computed here with the chosen matching engine;
- truth (simulator only): the beam cast against ``gt/scene.ply`` from the true poses.
"""

from __future__ import annotations

import base64
import html
import io
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.eval.sonar import (
    DepthView,
    SonarEvaluation,
    beam_axis,
    beam_directions,
    evaluate_sonar,
    interpolate_pose,
)
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.io.ground_truth import GroundTruth, find_ground_truth
from sea3d.stereo.recipe import DepthConfig

if TYPE_CHECKING:
    from sea3d.rectify.maps import RectifyMaps

__all__ = ["run_sonar_check", "sonar_mount", "write_sonar_report"]

_log = logging.getLogger(__name__)


def sonar_mount(rig: StereoRig, gt: GroundTruth | None) -> tuple[np.ndarray, float, str]:
    """``(T_left_sonar, beam_deg, where it came from)``.

    Raises:
        SessionError: neither the rig nor the simulator's ``sim.json`` knows the mount.
    """
    if rig.sonar is not None:
        return (
            np.asarray(rig.sonar.T_left_sonar),
            float(rig.sonar.beam_deg),
            "the rig's sonar: block",
        )
    sim = None if gt is None else gt.sim_meta
    if gt is not None and sim is not None:
        try:
            meta = gt.read_meta()
            T_body_left = np.asarray(meta["T_body_left"], dtype=np.float64)
            T_body_sonar = np.asarray(meta["T_body_sonar"], dtype=np.float64)
        except (SessionError, ValueError, KeyError) as err:
            raise SessionError(f"{sim}: no usable T_body_left / T_body_sonar ({err})") from err
        return invert_T(T_body_left) @ T_body_sonar, 0.0, f"{sim} (T_body_left, T_body_sonar)"
    raise SessionError(
        "the rig has no sonar: block (T_left_sonar) and there is no simulator gt/sim.json; "
        "add the echosounder's mount to rig.yaml and pass that rig"
    )


def _rect_camera(maps: RectifyMaps) -> PinholeCamera:
    P = maps.P_left
    return PinholeCamera(
        fx=float(P[0, 0]), fy=float(P[1, 1]), cx=float(P[0, 2]), cy=float(P[1, 2]),
        width=maps.width, height=maps.height,
    )  # fmt: skip


def _shrink(depth: np.ndarray, camera: Any, max_width_px: int | None) -> tuple[np.ndarray, Any]:
    """Every n-th pixel of a depth map (nearest: never blends across depth edges) and the
    camera that matches it.

    Sample ``k`` sits at the original pixel ``u = n k + n // 2``, so the small camera has
    ``fx' = fx / n`` and ``cx' = (cx - n // 2) / n`` (likewise in y); distortion acts before
    ``K`` and is kept, and so is a port.
    """
    if max_width_px is None or depth.shape[1] <= max_width_px:
        return depth, camera
    n = int(np.ceil(depth.shape[1] / max_width_px))
    c0 = n // 2
    small = np.ascontiguousarray(depth[c0::n, c0::n])
    h, w = small.shape
    pin = camera.lens
    moved = PinholeCamera(
        fx=pin.fx / n, fy=pin.fy / n, cx=(pin.cx - c0) / n, cy=(pin.cy - c0) / n,
        width=w, height=h, dist=pin.dist,
    )  # fmt: skip
    return small, camera.with_lens(moved)


def _poses_at(
    t_ns: np.ndarray, pose_t: np.ndarray | None, pose_T: np.ndarray | None
) -> list[np.ndarray | None]:
    if pose_t is None or pose_T is None:
        return [np.eye(4) for _ in t_ns]
    gap = int(np.median(np.diff(pose_t))) if pose_t.size > 1 else 100_000_000
    return [interpolate_pose(pose_t, pose_T, int(t), max_gap_ns=gap) for t in t_ns]


def _load_views(
    session: Any,
    rig: StereoRig,
    *,
    depth_dir: Path | None,
    depth_frame: str,
    depth: DepthConfig,
    every: int,
    pose_t: np.ndarray | None,
    pose_T: np.ndarray | None,
    max_width_px: int | None,
    progress: Callable[[int], None] | None,
) -> list[DepthView]:
    from sea3d.stereo.recipe import StereoDepth

    stereo = maps = None
    if depth_frame == "rect" or depth_dir is None:
        # the same rectification as ``sea3d depth`` with the same range
        stereo = StereoDepth(rig, depth)
        maps = stereo.maps
    views: list[DepthView] = []
    if depth_frame == "rect":
        assert maps is not None
        camera: Any = _rect_camera(maps)
        T_left_cam = np.eye(4)
        T_left_cam[:3, :3] = maps.R_rect_left_left.T
    else:
        camera = rig.left
        T_left_cam = np.eye(4)
    if depth_dir is not None:
        folder = depth_dir / "depth" if (depth_dir / "depth").is_dir() else depth_dir
        files = sorted(
            (
                p
                for p in folder.iterdir()
                if p.stem.isdigit() and p.suffix.lower() in (".png", ".npy", ".tif", ".tiff")
            ),
            key=lambda p: int(p.stem),
        )
        if not files:
            raise SessionError(f"{folder} holds no depth maps named <t_ns>.png, .npy or .tiff")
        files = files[::every]
        stamps = np.array([int(p.stem) for p in files], dtype=np.int64)
        poses = _poses_at(stamps, pose_t, pose_T)
        from sea3d.errors import StereoError
        from sea3d.io.depth_files import check_depth_grid, read_depth

        for f, t, T in zip(files, stamps.tolist(), poses, strict=True):
            if progress is not None:
                progress(1)
            if T is None:
                continue
            try:  # .npy / .tif(f) float metres (the simulator's gt/depth), .png millimetres
                d = read_depth(f)
            except StereoError as err:
                raise SessionError(f"cannot read depth map {f}: {err}") from err
            try:  # the file's grid sidecar, when it has one, must be the grid asked for
                check_depth_grid(f, d.shape, width_px=camera.width, height_px=camera.height,
                                 kind="rectified-left" if depth_frame == "rect" else "raw-left",
                                 consumer="eval sonar")
            except StereoError as err:
                raise SessionError(str(err)) from err
            if d.shape != (camera.height, camera.width):
                raise SessionError(
                    f"depth map {f} is {d.shape[1]}x{d.shape[0]} but the rig is "
                    f"{camera.width}x{camera.height}"
                )
            small, cam = _shrink(d, camera, max_width_px)
            views.append(
                DepthView(t_ns=t, depth_m=small, camera=cam, T_world_camera=T @ T_left_cam)
            )
        return views
    assert stereo is not None
    match = session.match_pairs()
    ls = session.stamps("left")
    idx = list(zip(match.left_index.tolist(), match.right_index.tolist(), strict=True))[::every]
    stamps = np.array([int(ls[i]) for i, _ in idx], dtype=np.int64)
    poses = _poses_at(stamps, pose_t, pose_T)
    for (i, j), t, T in zip(idx, stamps.tolist(), poses, strict=True):
        if progress is not None:
            progress(1)
        if T is None:
            continue
        try:
            left = session.image("left", i, by="index")
            right = session.image("right", j, by="index")
        except SessionError as err:
            _log.warning("eval sonar: skipping frame %d: %s", t, err)
            continue
        res = stereo.compute(left, right)
        small, cam = _shrink(res.depth_m, camera, max_width_px)
        views.append(DepthView(t_ns=t, depth_m=small, camera=cam, T_world_camera=T @ T_left_cam))
    return views


def _true_ranges(
    mesh_path: Path,
    pose_t: np.ndarray,
    pose_T: np.ndarray,
    sonar_t: np.ndarray,
    T_left_sonar: np.ndarray,
    beam_deg: float,
) -> np.ndarray:
    import open3d as o3d

    from sea3d.errors import ReconError
    from sea3d.io.mesh_files import read_mesh

    try:
        mesh = read_mesh(mesh_path)
    except ReconError as err:
        raise SessionError(str(err)) from err
    if len(mesh.triangles) == 0:
        raise SessionError(f"{mesh_path} holds no triangles")
    scene = o3d.t.geometry.RaycastingScene()
    tensor: Any = o3d.core.Tensor
    scene.add_triangles(tensor(np.ascontiguousarray(mesh.vertices, np.float32)),
                        tensor(np.ascontiguousarray(mesh.triangles, np.uint32)))
    gap = int(np.median(np.diff(pose_t))) if pose_t.size > 1 else 100_000_000
    out = np.full(sonar_t.shape, np.nan)
    rays, owner = [], []
    for i, t in enumerate(sonar_t.tolist()):
        T = interpolate_pose(pose_t, pose_T, int(t), max_gap_ns=gap)
        if T is None:
            continue
        o, d = beam_axis(T, T_left_sonar)
        for dk in beam_directions(d, beam_deg):
            rays.append(np.concatenate([o, dk]))
            owner.append(i)
    if not rays:
        return out
    hits = scene.cast_rays(o3d.core.Tensor(np.asarray(rays, dtype=np.float32)))  # type: ignore[call-overload,unused-ignore]
    t_hit = hits["t_hit"].numpy().astype(np.float64)
    t_hit[~np.isfinite(t_hit)] = np.nan
    for i, r in zip(owner, t_hit.tolist(), strict=True):
        if np.isfinite(r) and not (np.isfinite(out[i]) and out[i] <= r):
            out[i] = r
    return out


def run_sonar_check(
    session_path: str | os.PathLike[str],
    *,
    rig: StereoRig | None = None,
    poses_path: str | os.PathLike[str] | None = None,
    depth_dir: str | os.PathLike[str] | None = None,
    depth_frame: str = "rect",
    depth: DepthConfig | None = None,
    every: int = 1,
    beam_deg: float | None = None,
    window_s: float = 5.0,
    max_width_px: int | None = 480,
    use_truth: bool = True,
    progress: Callable[[int], None] | None = None,
) -> tuple[SonarEvaluation, dict[str, Any]]:
    """Evaluate a session's echosounder against its stereo (see the module docstring).

    ``depth`` says how stereo depth is computed (default: OpenCV's engine, ranges from the
    rig); with ``depth_dir`` in the rectified frame its rectification must be that of the run
    that wrote the maps (the same :class:`~sea3d.stereo.recipe.DepthConfig`).

    Returns:
        The :class:`~sea3d.eval.sonar.SonarEvaluation` and a dict saying where the mount,
        poses, depth and truth came from.

    Raises:
        SessionError: no echosounder samples, no rig, no sonar mount, unreadable inputs.
    """
    from sea3d.io.rig_file import resolve_rig

    depth_cfg = depth if depth is not None else DepthConfig(engine="opencv")
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory

    if depth_frame not in ("rect", "raw"):
        raise SessionError(f"depth_frame must be rect or raw, got {depth_frame!r}")
    if every < 1:
        raise SessionError(f"every must be >= 1, got {every}")
    gt = find_ground_truth(session_path)
    with open_session(session_path) as session:
        sonar = session.sonar()
        if len(sonar) == 0:
            raise SessionError(
                f"{session_path} holds no echosounder samples (/sonar or sonar.csv): nothing to "
                "compare the stereo with"
            )
        if rig is None:
            rig = resolve_rig(None, session)
        T_left_sonar, rig_beam, mount_src = sonar_mount(rig, gt)
        beam = rig_beam if beam_deg is None else float(beam_deg)
        pose_t = pose_T = None
        pose_src = "none (same-instant local fit)"
        if poses_path is not None:
            traj = read_trajectory(poses_path, "tum")
            pose_t, pose_T = traj.t_ns, traj.T_world_x
            pose_src = f"{poses_path}"
        elif gt is not None and gt.poses_left is not None:
            traj = read_trajectory(gt.poses_left, "tum")
            pose_t, pose_T = traj.t_ns, traj.T_world_x
            pose_src = f"ground truth {gt.poses_left} (simulator)"
        views = _load_views(
            session,
            rig,
            depth_dir=None if depth_dir is None else Path(depth_dir),
            depth_frame=depth_frame,
            depth=depth_cfg,
            every=every,
            pose_t=pose_t,
            pose_T=pose_T,
            max_width_px=max_width_px,
            progress=progress,
        )
    depth_src = (
        f"{depth_dir} ({depth_frame} left camera)"
        if depth_dir is not None
        else f"computed ({depth_cfg.engine})"
    )
    truth = None
    truth_src = None
    if use_truth and gt is not None and gt.scene_mesh is not None and gt.poses_left is not None:
        gt_traj = read_trajectory(gt.poses_left, "tum")
        gt_t, gt_T = gt_traj.t_ns, gt_traj.T_world_x
        truth = _true_ranges(gt.scene_mesh, gt_t, gt_T, sonar.t_ns, T_left_sonar, beam)
        truth_src = f"beam cast against {gt.scene_mesh} from the true poses"
    r = np.asarray(sonar.range_m, dtype=np.float64).copy()
    conf = np.asarray(sonar.confidence, dtype=np.float64)
    r[np.isfinite(conf) & (conf <= 0)] = np.nan  # the sensor said it had no echo
    evaluation = evaluate_sonar(
        sonar_t_ns=sonar.t_ns,
        sonar_range_m=r,
        frame_t_ns=pose_t,
        T_world_left=pose_T,
        views=views,
        T_left_sonar=T_left_sonar,
        beam_deg=beam,
        window_s=window_s,
        truth_range_m=truth,
        method_note=f"poses: {pose_src}",
    )
    info = {
        "session": os.fspath(session_path),
        "mount": mount_src,
        "beam_deg": beam,
        "poses": pose_src,
        "depth": depth_src,
        "views": len(views),
        "truth": truth_src,
    }
    return evaluation, info


def _plot_png(ev: SonarEvaluation) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = (ev.t_ns - ev.t_ns[0]) * 1e-9 if ev.t_ns.size else ev.t_ns
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    ax = axes[0]
    ax.plot(t, ev.sonar_range_m, ".", ms=4, label="echosounder")
    ax.plot(t, ev.stereo_range_m, ".", ms=4, label="stereo along the beam")
    if ev.truth_range_m is not None:
        ax.plot(t, ev.truth_range_m, "-", lw=1, color="k", alpha=0.6, label="truth")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("range (m)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[1]
    d = ev.stereo_range_m - ev.sonar_range_m
    d = d[np.isfinite(d)]
    if d.size:
        ax.hist(d * 100, bins=min(40, max(5, d.size // 3)), color="tab:orange", alpha=0.8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("stereo - echosounder (cm)")
    ax.set_ylabel("pings")
    ax.grid(True, alpha=0.3)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _row(name: str, c: Any) -> str:
    if c is None:
        return ""
    f = "—" if c.samples == 0 else None
    cells = (
        [str(c.samples)]
        + [f or f"{100 * v:.1f}" for v in (c.median_abs_diff_m, c.bias_m, c.spread_m, c.rmse_m)]
        + [f or f"{c.median_abs_diff_pct:.2f}"]
    )
    return f"<tr><td>{html.escape(name)}</td>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>"


def write_sonar_report(
    path: str | os.PathLike[str], ev: SonarEvaluation, info: dict[str, Any]
) -> Path:
    """A self-contained HTML report: the figures, where everything came from, the plot."""
    p = Path(path)
    png = base64.b64encode(_plot_png(ev)).decode("ascii")
    ds = ev.datasheet
    rows = _row("stereo vs echosounder", ev.stereo_vs_sonar)
    rows += _row("stereo vs truth", ev.stereo_vs_truth) + _row(
        "echosounder vs truth", ev.sonar_vs_truth
    )
    meta = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{html.escape(str(v))}</td></tr>" for k, v in info.items()
    )
    text = f"""<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>sea3d: echosounder against stereo</title>
<style>body{{font-family:sans-serif;margin:20px;max-width:1100px}}
table{{border-collapse:collapse}}
td,th{{padding:3px 10px;border-bottom:1px solid #ccc;text-align:right}}
td:first-child{{text-align:left}}</style>
</head><body>
<h2>Echosounder against stereo</h2>
<p>{ev.measured} of {ev.pings} pings measured by stereo. Method: {html.escape(ev.method)}.</p>
<table><tr><th></th><th>samples</th><th>median |diff| cm</th><th>bias cm</th><th>spread cm</th>
<th>RMSE cm</th><th>median |diff| %</th></tr>{rows}</table>
<p>The echosounder's own accuracy: {html.escape(ds["model"])}, range resolution
{100 * ds["resolution_fraction_of_range"]:.1f} % of range, {ds["beam_deg"]:g} degree beam
(source: {html.escape(ds["source"])}).</p>
<img alt="ranges against time and the differences" src="data:image/png;base64,{png}">
<h3>Inputs</h3><table>{meta}</table>
</body></html>
"""
    from sea3d.io.documents import write_document

    try:
        write_document(p, text)
    except OSError as err:
        raise SessionError(f"cannot write the report {p}: {err}") from err
    return p
