"""HTML reports with embedded pictures (one self-contained file, no network)."""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from sea3d.geometry.mesh import Mesh
    from sea3d.io.trajectory_files import TrajectoryFile
    from sea3d.pipeline.process import ProcessResult

__all__ = ["colorbar_tag", "depth_check_html", "image_tag", "write_process_report"]


def image_tag(rgb: NDArray[np.uint8], alt: str, *, max_width_px: int = 960) -> str:
    """An ``<img>`` with the picture embedded as JPEG, downscaled to ``max_width_px``."""
    import cv2

    img = np.asarray(rgb)
    if img.shape[1] > max_width_px:
        scale = max_width_px / img.shape[1]
        img = np.asarray(cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA))
    ok, buf = cv2.imencode(
        ".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 88]
    )
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 RGB
        return f"<p>({html.escape(alt)}: could not encode)</p>"
    data = base64.b64encode(buf.tobytes()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/jpeg;base64,{data}">'


def _pct(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{100.0 * x:.2f} %"


def colorbar_tag(lo: float, hi: float, label: str, *, cmap: str = "turbo") -> str:
    """A horizontal colour bar (PNG) for pictures coloured with OpenCV's or matplotlib's turbo
    map over the fixed range ``lo``..``hi``."""
    from matplotlib.colorbar import ColorbarBase
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 0.75))
    ax = fig.add_axes((0.05, 0.55, 0.9, 0.3))
    ColorbarBase(ax, cmap=cmap, norm=Normalize(lo, hi), orientation="horizontal")
    ax.set_xlabel(label, fontsize=8)
    ax.tick_params(labelsize=7)
    return _figure_tag(fig, f"colour bar: {label}").replace("<img ", '<img class="bar" ', 1)


def depth_check_html(
    *,
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    disparity_rgb: NDArray[np.uint8],
    disparity_range: tuple[float, float],
    depth_rgb: NDArray[np.uint8],
    depth_range_m: tuple[float, float],
    error_rgb: NDArray[np.uint8],
    error_range_m: tuple[float, float],
    cloud_rgb: NDArray[np.uint8],
    summary: dict[str, Any],
) -> str:
    """The single-pair depth check of the demo, as an HTML fragment: the input pair, depth
    against ground truth beside the pinhole-in-water and ports-ignored baselines, disparity,
    depth and error pictures with colour bars, and the pair's point cloud."""
    ours = summary["refraction_corrected"]
    base = summary["pinhole_in_water_baseline"]
    ignored = summary.get("ports_ignored_baseline")
    rows = []
    methods = [("refraction-corrected (sea3d)", ours), ("pinhole in water (baseline)", base)]
    if ignored is not None:
        methods.append(("in-air calibration, ports ignored", ignored))
    for name, e in methods:
        rows.append(
            f"<tr><td>{name}</td><td>{e['count']}</td><td>{_pct(e['median_rel'])}</td>"
            f"<td>{1000 * e['median_abs_m']:.1f} mm</td><td>{_pct(e['p90_rel'])}</td>"
            f"<td>{_pct(e['mean_signed_rel'])}</td><td>{_pct(e['within_1pct'])}</td></tr>"
        )
    band_rows = []
    bands_base = {(b["lo_m"], b["hi_m"]): b for b in base["by_range"]}
    for b in ours["by_range"]:
        other = bands_base.get((b["lo_m"], b["hi_m"]))
        band_rows.append(
            f"<tr><td>{b['lo_m']:.0f}-{b['hi_m']:.0f} m</td><td>{b['count']}</td>"
            f"<td>{_pct(b['median_rel'])}</td>"
            f"<td>{_pct(other['median_rel']) if other else 'n/a'}</td></tr>"
        )
    return f"""<h2>One stereo pair: depth against ground truth</h2>
<p>The survey's first pair, {summary["image_size_px"][0]}x{summary["image_size_px"][1]},
matched with {summary["max_disparity_px"]} disparities: valid depth on
{_pct(summary["valid_fraction"])} of the rectified pixels, {summary["points"]} points.</p>
<div class="pair"><div>{image_tag(left, "left image", max_width_px=640)}</div>
<div>{image_tag(right, "right image", max_width_px=640)}</div></div>
<table><tr><th>method</th><th>points</th><th>median |error| / depth</th><th>median |error|</th>
<th>90th pct relative</th><th>mean signed relative</th><th>within 1 %</th></tr>
{"".join(rows)}</table>
<table><tr><th>true depth</th><th>points</th><th>sea3d median relative</th>
<th>pinhole-in-water median relative</th></tr>{"".join(band_rows)}</table>
<p class="note">Each estimated point is projected through the true refractive camera to its
pixel and its depth compared with the rendered ground truth there. The baseline uses the same
disparities with the best-fitting pinhole (z = f B / d): the paper's in-water pinhole approach,
whose virtual-pinhole fit leaves {summary["virtual_pinhole_rms_px"]:.2f} px RMS. The last row,
if shown, matches the same images again with the in-air calibration, as if the ports were not
there.</p>
<h3>Disparity</h3>
<p class="note">Rectified left view; black = invalid.</p>
{image_tag(disparity_rgb, "disparity")}
{colorbar_tag(disparity_range[0], disparity_range[1], "disparity (px)")}
<h3>Depth</h3>
<p class="note">Rectified left view; black = invalid.</p>
{image_tag(depth_rgb, "depth")}
{colorbar_tag(depth_range_m[0], depth_range_m[1], "depth (m)")}
<h3>Depth error</h3>
<p class="note">Raw left view, estimated minus true depth; black = no estimate.</p>
{image_tag(error_rgb, "depth error")}
{colorbar_tag(1000 * error_range_m[0], 1000 * error_range_m[1], "depth error (mm)")}
<h3>The pair's point cloud</h3>
<p class="note">Left camera frame, seen from above and to the side.</p>
{image_tag(cloud_rgb, "point cloud")}
"""


# ------------------------------------------------------------------------------ process report

_STATUS_COLOURS = {
    "initialising": "#9e9e9e",
    "tracking": "#2e7d32",
    "imu_only": "#f9a825",
    "lost": "#c62828",
    "relocalised": "#1565c0",
}


def _figure_tag(fig: Figure, alt: str) -> str:
    """An ``<img>`` of a matplotlib figure (PNG, embedded)."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _trajectory_figure(result: ProcessResult, gt: TrajectoryFile | None,
                       T_ref_est: NDArray[np.float64]) -> str:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 6.0))
    ax = fig.add_subplot(1, 1, 1)
    T = result.T_world_left
    if len(T):
        p = T[:, :3, 3] @ T_ref_est[:3, :3].T + T_ref_est[:3, 3]
        trusted = np.array([s.value in ("tracking", "relocalised") for s in result.statuses])
        ax.plot(p[:, 0], p[:, 1], "-", color="#1565c0", lw=1.4, label="estimate")
        if (~trusted).any():
            ax.plot(p[~trusted, 0], p[~trusted, 1], "x", color="#c62828", ms=4,
                    label="not trusted (lost / IMU only / initialising)")
        ax.plot(p[0, 0], p[0, 1], "o", color="#1565c0", ms=6)
    if gt is not None:
        g = gt.T_world_x[:, :3, 3]
        ax.plot(g[:, 0], g[:, 1], "--", color="#444444", lw=1.0, label="ground truth")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("camera path seen from above" + (" (estimate aligned to ground truth, SE(3))"
                                                  if gt is not None else ""), fontsize=10)
    return _figure_tag(fig, "trajectory from above")


def _timeline_figure(result: ProcessResult, status_rows: list[dict[str, str]]) -> str:
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    n = len(result.statuses)
    fig = Figure(figsize=(9.0, 2.6))
    ax = fig.add_subplot(1, 1, 1)
    t0 = int(result.t_ns[0]) if len(result.t_ns) else 0
    t = (np.asarray(result.t_ns, np.float64) - t0) * 1e-9
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    for row, (key, colours) in enumerate((("status", _STATUS_COLOURS),
                                          ("fusion", {"integrated": "#2e7d32"}))):
        for i in range(n):
            value = result.statuses[i].value if key == "status" else status_rows[i]["fusion"]
            c = colours.get(value, "#e0e0e0")
            ax.broken_barh([(t[i] - dt / 2, dt)], (1 - row + 0.1, 0.8), color=c, lw=0)
    kf = [t[i] for i in range(n) if status_rows[i]["keyframe_id"] != ""]
    ax.plot(kf, [2.05] * len(kf), "|", color="#333333", ms=6)
    lc = [t[i] for i in range(n) if status_rows[i]["loop_closure"] == "1"]
    ax.plot(lc, [2.25] * len(lc), "v", color="#6a1b9a", ms=7)
    ax.set_yticks([0.5, 1.5, 2.1])
    ax.set_yticklabels(["fused", "odometry", "keyframes / loops"])
    ax.set_ylim(0, 2.45)
    ax.set_xlabel("session time (s)")
    handles = [Patch(color=c, label=k.replace("_", " ")) for k, c in _STATUS_COLOURS.items()]
    handles.append(Patch(color="#e0e0e0", label="not fused"))
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.35), ncol=6,
              fontsize=7, frameon=False)
    return _figure_tag(fig, "status timeline")


def _fmt(x: float | None, unit: str = "", scale: float = 1.0, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "n/a"
    return f"{x * scale:.{digits}f}{unit}"


def _files_note(path: Path, result: ProcessResult) -> str:
    """Where the run's files are, relative to the report (the demo's report sits one folder up)."""
    import os

    base = Path(path).parent
    names = [os.path.relpath(f, base) for k, f in result.files.items()
             if k != "report" and Path(f).exists()]
    out = os.path.relpath(result.out_dir, base)
    where = "beside this report" if out == "." else f"in {html.escape(out)}/"
    extra = "" if out == "." else f"{html.escape(out)}/"
    return (f'<p class="note">Files {where}: {html.escape(", ".join(names))}; '
            f"{extra}cache/ (per-frame results that let a rerun resume) and {extra}submaps/. "
            "results.mcap opens in Foxglove (trajectory, mesh, cloud).</p>")


def _water_model_html(info: object) -> str:
    """The dive's water model (``--restore-colours seathru``): its fit status, checks and
    parameters, or why it could not be fitted."""
    if not isinstance(info, dict):
        return ""
    frames = len(info.get("fit_frames_t_ns", []))
    model = info.get("water_model")
    if not isinstance(model, dict):
        why = html.escape(str(info.get("fit_error", "not fitted")))
        return (f"<p>Water model: <b>not fitted</b> ({why}); every frame got grey world "
                "(fallback-grey-world).</p>")

    def rgb(key: str) -> str:
        return " / ".join(f"{float(v):.3f}" for v in model.get(key, ()))

    checks = "".join(f"<li>{html.escape(str(c))}</li>" for c in model.get("checks", []))
    span = model.get("range_span_m", (0.0, 0.0))
    return (f"<p>Water model of the dive: one fit to {frames} frames (every "
            f"{info.get('fit_stride', 1)}-th frame of the start), status <b>"
            f"{html.escape(str(model.get('status')))}</b>, range seen {float(span[0]):.2f}-"
            f"{float(span[1]):.2f} m.</p><table><tr><th>R / G / B</th><th></th></tr>"
            f"<tr><td>B_inf (linear)</td><td>{rgb('B_inf_rgb')}</td></tr>"
            f"<tr><td>beta_B (1/m)</td><td>{rgb('beta_B_per_m')}</td></tr>"
            f"<tr><td>beta_D (1/m)</td><td>{rgb('beta_D_per_m')}</td></tr>"
            f"<tr><td>white-balance gains</td><td>{rgb('wb_gains')}</td></tr>"
            f"<tr><td>exposure gain</td><td>{float(model.get('exposure_gain', 1.0)):.3f}"
            "</td></tr></table>"
            + (f"<p>First fit over {info.get('fit_frames_wanted')} frames: "
               f"{html.escape(str(info.get('first_fit_status')))}; fitted again over more "
               "frames.</p>" if info.get("first_fit_status") else "")
            + (f"<p>Checks that failed (by parameter):</p><ul>{checks}</ul>" if checks else ""))


def _colour_html(colours: object, pictures: Sequence[NDArray[np.uint8]] | None) -> str:
    """The colour section: the restoration's status counts, each frame's status, and one
    frame before and after (``sea3d process --restore-colours``)."""
    if not isinstance(colours, dict) or colours.get("restore", "none") == "none":
        return ""
    counts = ", ".join(f"{html.escape(str(k))}: {v}"
                       for k, v in sorted(colours.get("restore_status", {}).items()))
    per = colours.get("per_frame", [])
    cells = "".join(f"<tr><td>{t}</td><td>{html.escape(str(st))}</td></tr>" for t, st in per)
    pics = ""
    if pictures is not None and len(pictures) == 2:
        a, b = (np.asarray(p, np.uint8) for p in pictures)
        a, b = (np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x for x in (a, b))
        pics = (image_tag(np.hstack([a, b]),
                          "first restored frame: rectified left before (left) and after")
                + '<p class="note">The first restored frame: as recorded (left) and restored '
                  "(right).</p>")
    return (f"<h2>Colours</h2><p>{html.escape(str(colours['restore']))} on every frame "
            f"({counts}).</p>{_water_model_html(colours.get('water_model'))}{pics}"
            "<details><summary>status per frame</summary><table>"
            f"<tr><th>t (ns)</th><th>colour status</th></tr>{cells}</table></details>")


def _ground_truth_of(s: dict[str, Any]) -> tuple[TrajectoryFile | None, NDArray[np.float64]]:
    """The ground-truth path beside the session and ``T_ref_est``, or ``(None, I)``."""
    from sea3d.io.trajectory_files import read_trajectory

    gt = None
    T_ref_est = np.eye(4)
    tv = s.get("trajectory_vs_gt")
    if isinstance(tv, dict) and "T_ref_est" in tv and s.get("ground_truth"):
        from sea3d.io.ground_truth import GroundTruth

        gt_path = GroundTruth(Path(s["ground_truth"])).poses_left_path
        if gt_path.is_file():
            gt = read_trajectory(gt_path)
            T_ref_est = np.asarray(tv["T_ref_est"], np.float64)
    return gt, T_ref_est


def _mesh_picture_html(mesh: Mesh, T_ref_est: NDArray[np.float64]) -> str:
    """The mesh shaded from above (in the ground truth's frame), or a line saying it is empty."""
    from sea3d.recon.render import render_mesh, view_from_above

    if not mesh.empty:
        mesh_w = mesh.transformed(T_ref_est)
        view = view_from_above(mesh_w.vertices, tilt_deg=30.0)
        return image_tag(render_mesh(mesh_w, view, size_px=(960, 540)), "mesh")
    return "<p>(the mesh is empty: no frame was fused)</p>"


def _facts_rows_html(s: dict[str, Any]) -> str:
    """The run's figures as table rows."""
    facts = [
        ("stereo frames", s["frames"]),
        ("keyframes", s["keyframes"]),
        ("frames lost", s["frames_lost"]),
        ("frames on the IMU only", s["frames_imu_only"]),
        ("frames fused into the TSDF", s["frames_fused"]),
        ("loop closures", s["loop_closures"]),
        ("re-links across lost frames", s.get("relinks", 0)),
        ("segments", s["segments"]),
        ("path length", _fmt(s["path_length_m"], " m", digits=2)),
        ("frames per second (frame loop)", _fmt(s.get("frames_per_second"), "", digits=2)),
        ("frames taken from the cache", s["frames_from_cache"]),
        ("mesh", f"{s['mesh']['vertices']} vertices, {s['mesh']['triangles']} triangles"),
        ("cloud", f"{s['cloud']['points']} points ({s['cloud']['outliers_removed']} outliers "
                  "removed)"),
    ]
    return "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(str(v))}</td></tr>"
                   for k, v in facts)


def _trajectory_vs_gt_html(tv: object) -> str:
    """The trajectory against the ground truth (ATE, RPE), or why it was not evaluated."""
    gt_html = "<p class=\"note\">The session has no ground truth beside it.</p>"
    if isinstance(tv, dict) and "ate_m" in tv:
        ate = tv["ate_m"]
        rpe = "".join(
            f"<tr><td>RPE over {r['delta_m']:g} m</td><td>"
            f"{_fmt(r['translation_m']['rmse'], ' mm', 1000, 1)} RMSE "
            f"({_fmt(r['drift_pct'], ' %', digits=2)} drift), "
            f"{_fmt(r['rotation_deg']['rmse'], ' deg', digits=2)}</td></tr>" for r in tv["rpe"])
        gt_html = (
            "<table><tr><th>trajectory (trusted frames)</th><th></th></tr>"
            f"<tr><td>poses matched</td><td>{tv['matched']}</td></tr>"
            f"<tr><td>ATE RMSE</td><td>{_fmt(ate['rmse'], ' mm', 1000, 1)} "
            f"({_fmt(tv.get('ate_rmse_pct_of_path'), ' % of the path', digits=3)})</td></tr>"
            f"<tr><td>ATE median / max</td><td>{_fmt(ate['median'], ' mm', 1000, 1)} / "
            f"{_fmt(ate['max'], ' mm', 1000, 1)}</td></tr>{rpe}</table>"
        )
    elif isinstance(tv, dict) and "error" in tv:
        gt_html = f"<p>Trajectory not evaluated: {html.escape(tv['error'])}</p>"
    return gt_html


def _mesh_vs_gt_html(mv: object) -> str:
    """The mesh against the scene (accuracy, completeness, F-scores), or nothing."""
    mesh_html = ""
    if isinstance(mv, dict) and "accuracy_m" in mv:
        acc, comp = mv["accuracy_m"], mv["completeness_m"]
        thr = "".join(
            f"<tr><td>within {1000 * t:.0f} mm</td><td>{100 * p:.1f} %</td>"
            f"<td>{100 * r:.1f} %</td><td>{100 * f:.1f} %</td></tr>"
            for t, p, r, f in zip(mv["thresholds_m"], mv["precision"], mv["recall"],
                                  mv["fscore"], strict=True))
        mesh_html = (
            "<table><tr><th>mesh against the scene</th><th>median</th><th>90th pct</th></tr>"
            f"<tr><td>accuracy (mesh to scene)</td><td>{_fmt(acc['median'], ' mm', 1000, 1)}"
            f"</td><td>{_fmt(acc['p90'], ' mm', 1000, 1)}</td></tr>"
            f"<tr><td>completeness (seen surface to mesh)</td>"
            f"<td>{_fmt(comp['median'], ' mm', 1000, 1)}</td>"
            f"<td>{_fmt(comp['p90'], ' mm', 1000, 1)}</td></tr></table>"
            "<table><tr><th>threshold</th><th>precision</th><th>recall</th><th>F-score</th></tr>"
            f"{thr}</table><p class=\"note\">Completeness reference: "
            f"{html.escape(str(mv.get('completeness_reference', '')))}.</p>"
        )
    return mesh_html


def _timing_rows_html(s: dict[str, Any]) -> tuple[str, str, float]:
    """``(pipeline rows, per-frame worker rows, one-off warm-up s)`` of the timings section."""
    timings = s["timings_s"]
    trows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.2f} s</td></tr>"
                    for k, v in timings.items())
    wt = s.get("worker_timings_s", {})
    wrows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.2f} s</td></tr>"
                    for k, v in wt.items() if k != "warmup_s" and not k.startswith("pyramid"))
    warm = wt.get("warmup_s", 0.0)
    n_cached = int(s.get("frames_from_cache", 0) or 0)
    if n_cached:
        wrows += ("<tr><td colspan=2>" + (
            f"all {n_cached} frames came from the cache: no matching ran in this run"
            if n_cached >= int(s.get("frames", 0) or 0) else
            f"{n_cached} frames came from the cache (not matched again, not counted above)")
            + "</td></tr>")
    return trows, wrows, warm


def write_process_report(path: Path, result: ProcessResult, *, title: str | None = None,
                         intro_html: str = "", sections_html: str = "",
                         colour_pictures: Sequence[NDArray[np.uint8]] | None = None) -> Path:
    """Write ``report.html`` of a ``sea3d process`` run and return its path.

    The page holds: the run's figures, the path seen from above (against the ground truth
    when the session has one), a shaded picture of the mesh (CPU ray casting), the status
    timeline, and the timings (one-off kernel compilation shown apart). ``title``,
    ``intro_html`` and ``sections_html`` (inserted before the trajectory) let the demo put its
    own parts on the same page; ``colour_pictures`` (one frame's rectified left before and
    after ``--restore-colours``) go into the colour section with each frame's status.
    """
    from sea3d.io.documents import write_document
    from sea3d.io.process_outputs import read_status_csv

    s = result.summary
    gt, T_ref_est = _ground_truth_of(s)
    tv = s.get("trajectory_vs_gt")
    rows = read_status_csv(result.files["status"])
    traj_img = _trajectory_figure(result, gt, T_ref_est)
    timeline_img = _timeline_figure(result, rows)
    mesh_img = _mesh_picture_html(result.mesh, T_ref_est)
    fact_rows = _facts_rows_html(s)
    gt_html = _trajectory_vs_gt_html(tv)
    mesh_html = _mesh_vs_gt_html(s.get("mesh_vs_gt"))
    timings = s["timings_s"]
    trows, wrows, warm = _timing_rows_html(s)
    page_title = html.escape(title or "sea3d process report")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{page_title}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; max-width: 1000px; color: #222; }}
img {{ max-width: 100%; display: block; margin: 0.3em 0 1em; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; }}
td, th {{ border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }}
.note {{ color: #555; font-size: 0.9em; }}
.pair {{ display: flex; gap: 0.5em; }} .pair div {{ flex: 1; }}
img.bar {{ max-width: 520px; margin-top: -0.6em; }}
</style></head><body>
<h1>{html.escape(title or "sea3d process: " + Path(s["session"]).name)}</h1>
{intro_html}
<p>{s["frames"]} stereo frames at {s["image_size_px"][0]}x{s["image_size_px"][1]}
({"refractive rig, depth triangulated with refracted rays" if s["refractive"] else "pinhole rig"}),
poses from <b>{html.escape(str(s["odometry"]))}</b>, TSDF voxels of {1000 * s["voxel_m"]:.0f} mm,
per-frame stage on {html.escape(str(s["executor"]["kind"]))}
({s["executor"]["workers"]} workers).</p>
<table>{fact_rows}</table>
{sections_html}
{_colour_html(s.get("colours"), colour_pictures)}
<h2>Trajectory</h2>
{traj_img}
{gt_html}
<h2>Mesh</h2>
<p class="note">mesh.ply, shaded by CPU ray casting, seen from above
{"(placed in the ground truth's frame)" if gt is not None else ""}.</p>
{mesh_img}
{mesh_html}
<h2>Status timeline</h2>
<p class="note">Odometry status of every frame, keyframes (ticks), loop closures (triangles)
and which frames the TSDF fused; per-frame figures are in status.csv.</p>
{timeline_img}
<h2>Timings</h2>
<table><tr><th>pipeline stage (wall time, this process)</th><th></th></tr>{trows}</table>
<table><tr><th>per-frame stage, summed over workers</th><th></th></tr>{wrows}</table>
<p class="note">One-off: {warm:.2f} s of kernel compilation (or loading from numba's cache) on
the workers' first frames is counted apart, not in the figures above; the rectification maps
took {timings.get("rectify_maps_s", 0.0):.2f} s once.</p>
{_files_note(path, result)}
</body></html>
"""
    write_document(path, page)
    return path
