"""A self-contained HTML report of a stereo calibration.

One file, no external resources: summary numbers, the verdict and plain-words guidance,
per-view errors (bars), the reasons for every rejected view, per-image detection status,
residual vectors, a coverage heat map, and the rectified sample pair with epipolar lines.
Images are embedded as base64 PNG.
"""

from __future__ import annotations

import base64
import html
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.calib.port import PortRigCalibration, assess_port
from sea3d.calib.stereo import StereoCalibration
from sea3d.errors import CalibrationError

__all__ = ["rectified_pair", "render_port_report", "render_report"]

_CSS = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1200px;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:.9em}td,th{padding:3px 8px;border-bottom:1px solid #eee;
text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}
.verdict{padding:.6em 1em;border-radius:6px;font-weight:600;display:inline-block}
.trusted{background:#d8f3dc}.care{background:#fff3bf}.not{background:#ffd6d6}
img{max-width:100%;border:1px solid #ddd}.bad{color:#b00}.figs{display:flex;gap:1em;flex-wrap:wrap}
.figs div{flex:1;min-width:300px}
"""


def _png(img: NDArray[Any]) -> str:
    """``<img>`` tag of an RGB or grey uint8 image."""
    arr = np.asarray(img)
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", arr)
    if not ok:  # pragma: no cover - cv2 always encodes uint8
        return ""
    return f'<img src="data:image/png;base64,{base64.b64encode(buf.tobytes()).decode()}">'


def _canvas(size: tuple[int, int], max_width: int = 800) -> tuple[NDArray[np.uint8], float]:
    w, h = size
    scale = min(1.0, max_width / w)
    return np.full((round(h * scale), round(w * scale), 3), 255, np.uint8), scale


def _residual_image(result: StereoCalibration, side: str, gain: float) -> NDArray[np.uint8]:
    cam = result.left if side == "left" else result.right
    assert cam is not None
    corners = [v.corners_left_px if side == "left" else v.corners_right_px
               for v in result.views]
    residuals = [v.residuals_left_px if side == "left" else v.residuals_right_px
                 for v in result.views]
    return _arrows(cam.image_size, np.concatenate(corners) if corners else np.zeros((0, 2)),
                   np.concatenate(residuals) if residuals else np.zeros((0, 2)), gain,
                   f"{side}: residuals x{gain:g}")


def _arrows(size: tuple[int, int], uv: NDArray[Any], res: NDArray[Any], gain: float,
            label: str) -> NDArray[np.uint8]:
    """Corners (grey) and their residuals (red arrows, magnified ``gain`` times)."""
    img, s = _canvas(size)
    for (u, vv), (du, dv) in zip(uv, res, strict=True):
        p0 = (round(u * s), round(vv * s))
        p1 = (round((u + gain * du) * s), round((vv + gain * dv) * s))
        cv2.circle(img, p0, 1, (120, 120, 120), -1)
        cv2.line(img, p0, p1, (200, 30, 30), 1, cv2.LINE_AA)
    cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _coverage_image(result: StereoCalibration, side: str,
                    background: NDArray[Any] | None) -> NDArray[np.uint8]:
    cam = result.left if side == "left" else result.right
    assert cam is not None
    counts = cam.coverage_counts.astype(np.float64)
    img, s = _canvas(cam.image_size)
    if background is not None:
        bg = np.asarray(background)
        if bg.ndim == 2:
            bg = np.stack([bg] * 3, axis=2)
        img = np.asarray(cv2.resize(bg[:, :, :3].astype(np.uint8),
                                    (img.shape[1], img.shape[0])), dtype=np.uint8)
    norm = np.clip(counts / max(1.0, float(counts.max())), 0, 1)
    heat = cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    heat = cv2.cvtColor(heat, cv2.COLOR_BGR2RGB)
    heat = cv2.resize(heat, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST)
    empty = cv2.resize((counts == 0).astype(np.uint8), (img.shape[1], img.shape[0]),
                       interpolation=cv2.INTER_NEAREST).astype(bool)
    heat[empty] = (255, 80, 80)
    out = cv2.addWeighted(img, 0.45, heat, 0.55, 0)
    for v in result.views:
        uv = v.corners_left_px if side == "left" else v.corners_right_px
        for u, vv in uv:
            cv2.circle(out, (round(u * s), round(vv * s)), 1, (255, 255, 255), -1)
    cv2.putText(out, f"{side}: coverage {cam.coverage:.0%} (red: no corners)", (8, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 2, cv2.LINE_AA)
    cv2.putText(out, f"{side}: coverage {cam.coverage:.0%} (red: no corners)", (8, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return np.asarray(out, dtype=np.uint8)


def rectified_pair(result: StereoCalibration, left_image: NDArray[Any],
                   right_image: NDArray[Any], n_lines: int = 16) -> NDArray[np.uint8]:
    """The pair rectified with the calibration, side by side, with horizontal epipolar lines.

    Args:
        result: a successful calibration.
        left_image, right_image: ``(H, W)`` or ``(H, W, 3)`` RGB uint8 images of the calibrated
            size.
        n_lines: number of epipolar lines drawn.

    Returns:
        ``(H, 2W, 3)`` RGB uint8 image.

    Raises:
        CalibrationError: the calibration failed or the images have another size.
    """
    if not result.ok or result.left is None or result.right is None:
        raise CalibrationError("cannot rectify with a failed calibration")
    size = result.left.image_size
    imgs = []
    for im in (left_image, right_image):
        a = np.asarray(im)
        if a.shape[1] != size[0] or a.shape[0] != size[1]:
            raise CalibrationError(f"sample image is {a.shape[1]}x{a.shape[0]}, calibration is "
                                   f"{size[0]}x{size[1]}")
        if a.ndim == 2:
            a = np.stack([a] * 3, axis=2)
        imgs.append(a[:, :, :3].astype(np.uint8))
    T_right_left = np.linalg.inv(result.T_left_right)
    R, T = T_right_left[:3, :3], T_right_left[:3, 3]
    R1, R2, P1, P2, _Q, _r1, _r2 = cv2.stereoRectify(
        result.left.K, result.left.dist, result.right.K, result.right.dist, size, R, T,
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    out = []
    for im, cam, Rr, P in ((imgs[0], result.left, R1, P1), (imgs[1], result.right, R2, P2)):
        mx, my = cv2.initUndistortRectifyMap(cam.K, cam.dist, Rr, P, size, cv2.CV_32FC1)
        out.append(cv2.remap(im, mx, my, cv2.INTER_LINEAR))
    pair = np.concatenate(out, axis=1)
    h = pair.shape[0]
    colours = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48)]
    for k in range(n_lines):
        y = round((k + 0.5) * h / n_lines)
        cv2.line(pair, (0, y), (pair.shape[1] - 1, y), colours[k % len(colours)], 1)
    return np.asarray(pair, dtype=np.uint8)


def _bar(value: float, vmax: float, colour: str) -> str:
    if not math.isfinite(value):
        return ""
    width = 0 if vmax <= 0 else min(160, round(160 * value / vmax))
    return (f'<svg width="165" height="10"><rect width="{width}" height="10" fill="{colour}"/>'
            f"</svg>")


def render_report(result: StereoCalibration, *, sample_pair: tuple[NDArray[Any], NDArray[Any]]
                  | None = None, title: str = "sea3d stereo calibration",
                  residual_gain: float | None = None) -> str:
    """The calibration report as one HTML document.

    Args:
        result: the calibration (a failed one gives a short report with the reasons).
        sample_pair: a left/right image pair (RGB) for the rectified view and as the coverage
            background; optional.
        title: page title.
        residual_gain: scale of the residual arrows (default: 8 px for the RMS).

    Returns:
        The HTML text (UTF-8, self-contained).
    """
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{e(title)}</h1>"]
    cls = {"trusted": "trusted", "usable with care": "care"}.get(result.verdict, "not")
    parts.append(f"<p class='verdict {cls}'>Verdict: {e(result.verdict)}</p>")
    parts.append("<ul>" + "".join(f"<li>{e(g)}</li>" for g in result.guidance) + "</ul>")
    parts.append(f"<p>{e(result.message)}</p>")
    if result.detector:
        rows_d = "".join(
            f"<tr><td>{e(t.detector)}{' (chosen)' if t.detector == result.detector else ''}"
            f"</td><td>{e(t.status)}</td><td class=n>{_num(t.rms_px)}</td>"
            f"<td class=n>{_num(t.holdout_px)}</td><td class=n>{_num(t.common_holdout_px)}"
            f"</td><td class=n>{t.pairs_used}</td></tr>" for t in result.detector_trials)
        how = ("Every checkerboard detector was tried; the one whose calibration predicts "
               "held-out pairs best is kept (the RMS on a detector's own corners does not "
               "tell). " if result.detector_trials else "Corners: ")
        parts.append(f"<h2>Corner detector</h2><p>{how}{e(result.detector_reason)}.</p>")
        if rows_d:
            parts.append("<table><tr><th>detector</th><th>status</th><th>RMS px</th>"
                         "<th>holdout px</th><th>holdout on common pairs px</th><th>pairs</th>"
                         "</tr>" + rows_d + "</table>")
    if result.left is not None and result.right is not None:
        L, R = result.left, result.right
        rows = [("RMS, both cameras", f"{result.rms_px:.3f} px"),
                ("Holdout (leave one pair out)", f"{result.holdout_px:.3f} px"),
                ("RMS left / right", f"{L.rms_px:.3f} / {R.rms_px:.3f} px"),
                ("Baseline", f"{result.baseline_m * 1e3:.2f} mm"),
                ("Pairs used / rejected", f"{len(result.views)} / {len(result.views_rejected)}"),
                ("Coverage left / right", f"{L.coverage:.0%} / {R.coverage:.0%}"),
                ("Left fx fy cx cy", f"{L.fx:.2f} {L.fy:.2f} {L.cx:.2f} {L.cy:.2f}"),
                ("Right fx fy cx cy", f"{R.fx:.2f} {R.fy:.2f} {R.cx:.2f} {R.cy:.2f}"),
                ("Left distortion", " ".join(f"{v:.5g}" for v in L.dist)),
                ("Right distortion", " ".join(f"{v:.5g}" for v in R.dist)),
                ("Distortion model", result.config.distortion)]
        parts.append("<h2>Summary</h2><table>" + "".join(
            f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in rows) + "</table>")
        vmax = max([max(v.rms_left_px, v.rms_right_px,
                        v.holdout_px if math.isfinite(v.holdout_px) else 0)
                    for v in result.views] + [1e-9])
        parts.append("<h2>Per-view errors</h2><table><tr><th>left</th><th>right</th>"
                     "<th>RMS left px</th><th>RMS right px</th><th>holdout px</th>"
                     "<th>distance m</th><th>tilt deg</th></tr>")
        for v in result.views:
            parts.append(
                f"<tr><td>{e(v.left)}</td><td>{e(v.right)}</td>"
                f"<td class=n>{v.rms_left_px:.3f} {_bar(v.rms_left_px, vmax, '#4c72b0')}</td>"
                f"<td class=n>{v.rms_right_px:.3f} {_bar(v.rms_right_px, vmax, '#55a868')}</td>"
                f"<td class=n>{v.holdout_px:.3f} {_bar(v.holdout_px, vmax, '#c44e52')}</td>"
                f"<td class=n>{v.distance_m:.3f}</td><td class=n>{v.tilt_deg:.1f}</td></tr>")
        parts.append("</table>")
    if result.views_rejected:
        parts.append("<h2>Rejected views</h2><table><tr><th>left</th><th>right</th>"
                     "<th>reason</th></tr>" + "".join(
                         f"<tr><td>{e(r.left)}</td><td>{e(r.right)}</td>"
                         f"<td class=bad>{e(r.reason)}</td></tr>"
                         for r in result.views_rejected) + "</table>")
    if result.left is not None and result.right is not None:
        gain = residual_gain or (8.0 / max(result.rms_px, 1e-3))
        gain = float(f"{gain:.2g}")
        parts.append("<h2>Residual vectors</h2><p>Detected corners (grey) and their "
                     f"reprojection errors (red), magnified {gain:g} times. Errors that point "
                     "the same way in a region mean a model error there (distortion, a bent "
                     "board); random directions are detection noise.</p><div class=figs>")
        for side in ("left", "right"):
            parts.append(f"<div>{_png(_residual_image(result, side, gain))}</div>")
        parts.append("</div><h2>Coverage</h2><p>Corners of the used views per image cell. Red "
                     "cells have none: distortion there is extrapolated.</p><div class=figs>")
        for k, side in enumerate(("left", "right")):
            bg = sample_pair[k] if sample_pair is not None else None
            parts.append(f"<div>{_png(_coverage_image(result, side, bg))}</div>")
        parts.append("</div>")
        if sample_pair is not None:
            try:
                pair = rectified_pair(result, sample_pair[0], sample_pair[1])
            except CalibrationError as err:
                parts.append(f"<p class=bad>No rectified pair: {e(str(err))}</p>")
            else:
                scale = min(1.0, 1400 / pair.shape[1])
                small = cv2.resize(pair, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                parts.append("<h2>Rectified pair</h2><p>After rectification, every point must "
                             "lie on the same row in both images: check features along the "
                             "coloured lines.</p>" + _png(small))
    if result.detections:
        parts.append("<h2>Detection per image</h2><table><tr><th>image</th><th>status</th>"
                     "<th>details</th></tr>" + "".join(
                         f"<tr><td>{e(n)}</td><td{' class=bad' if s != 'detected' else ''}>"
                         f"{e(s)}</td><td>{e(m)}</td></tr>" for n, s, m in result.detections)
                     + "</table>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _num(x: float, fmt: str = ".3f") -> str:
    return format(x, fmt) if math.isfinite(x) else "-"


def render_port_report(result: PortRigCalibration, *, title: str = "sea3d port calibration",
                       residual_gain: float | None = None) -> str:
    """The port calibration report as one HTML document.

    Sections: verdict and guidance (:func:`sea3d.calib.port.assess_port`), summary (stereo
    RMS, baseline, extrinsics with standard deviations), each camera's port (dome centre or
    flat-port normal and distance, with standard deviations), per-view errors through the
    refractive model, the rejected views and their reasons, and residual vectors through each
    camera's port model.

    Args:
        result: the port calibration (a failed one gives a short report with the reasons).
        title: page title.
        residual_gain: scale of the residual arrows (default: 8 px for the RMS).

    Returns:
        The HTML text (UTF-8, self-contained).
    """
    e = html.escape
    verdict, guidance = assess_port(result)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{e(title)}</h1>"]
    cls = {"trusted": "trusted", "usable with care": "care"}.get(verdict, "not")
    parts.append(f"<p class='verdict {cls}'>Verdict: {e(verdict)}</p>")
    parts.append("<ul>" + "".join(f"<li>{e(g)}</li>" for g in guidance) + "</ul>")
    parts.append(f"<p>{e(result.message)}</p>")
    t = result.T_left_right[:3, 3] * 1e3
    std = result.T_left_right_std
    rows = [("Stereo RMS through both port models", f"{_num(result.rms_px)} px"),
            ("Baseline", f"{np.linalg.norm(t):.2f} mm"),
            ("Right camera centre in the left frame",
             f"({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) mm +- ("
             + ", ".join(_num(v * 1e3, ".3f") for v in std[3:6]) + ") mm"),
            ("Rotation std (rotation vector)",
             "(" + ", ".join(_num(v * 1e3, ".3f") for v in std[:3]) + ") mrad"),
            ("Pairs used / left out", f"{len(result.views)} / {len(result.views_rejected)}")]
    parts.append("<h2>Summary</h2><table>" + "".join(
        f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in rows) + "</table>")
    parts.append("<h2>Ports</h2><table><tr><th>camera</th><th>port</th><th>estimate</th>"
                 "<th>standard deviation</th><th>RMS px</th><th>pinhole start RMS px</th>"
                 "<th>focal scale</th><th>views</th></tr>")
    for side, r in (("left", result.left), ("right", result.right)):
        if np.isfinite(r.dome_center_m).all():
            c, sd = r.dome_center_m * 1e3, r.dome_center_std_m * 1e3
            kind = "dome centre"
            est = f"({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) mm"
            unc = "(" + ", ".join(_num(v) for v in sd) + ") mm"
        else:
            kind = "flat port"
            n = r.normal
            est = (f"normal ({n[0]:.5f}, {n[1]:.5f}, {n[2]:.5f}), distance "
                   f"{r.distance_m * 1e3:.3f} mm")
            unc = (f"normal x/y {_num(r.port_std[0], '.2e')} / {_num(r.port_std[1], '.2e')}, "
                   f"distance {_num(r.port_std[2] * 1e3)} mm")
        scale = (f"{r.focal_scale:.5f} +- {r.focal_scale_std:.5f}" if r.focal_scale_std
                 else "1 (fixed)")
        parts.append(f"<tr><td>{side}</td><td>{kind}</td><td>{e(est)}</td><td>{e(unc)}</td>"
                     f"<td class=n>{_num(r.rms_px)}</td><td class=n>{_num(r.initial_rms_px)}"
                     f"</td><td>{e(scale)}</td><td class=n>{len(r.views)}</td></tr>")
    parts.append("</table><p>Standard deviations are from the fit's covariance "
                 "(sigma^2 (J^T J)^-1): they hold when the corners' errors are random; a "
                 "model error (wrong indices, thickness or in-air intrinsics) is not in them."
                 "</p>")
    # Per-view errors: each camera's fit through its port, and the stereo fit per pair.
    rms_l = dict(zip(result.left.views, result.left.per_view_rms_px, strict=False))
    rms_r = dict(zip(result.right.views, result.right.per_view_rms_px, strict=False))
    dist_l = {n: float(np.linalg.norm(T[:3, 3]))
              for n, T in zip(result.left.views, result.left.T_cam_board, strict=False)}
    rows_v = [(a, b, rms_l.get(a, math.nan), rms_r.get(b, math.nan), float(r_pair),
               dist_l.get(a, math.nan))
              for (a, b), r_pair in zip(result.views, result.per_pair_rms_px, strict=False)]
    if rows_v:
        vmax = max([max(x for x in row[2:5] if math.isfinite(x)) for row in rows_v] + [1e-9])
        parts.append("<h2>Per-view errors</h2><p>Reprojection RMS through the refractive "
                     "model: each camera's port fit, and the stereo fit of the pair.</p>"
                     "<table><tr><th>left</th><th>right</th><th>left px</th><th>right px</th>"
                     "<th>stereo px</th><th>distance m</th></tr>")
        for a, b, rl, rr, rp, d in rows_v:
            parts.append(
                f"<tr><td>{e(a)}</td><td>{e(b)}</td>"
                f"<td class=n>{_num(rl)} {_bar(rl, vmax, '#4c72b0')}</td>"
                f"<td class=n>{_num(rr)} {_bar(rr, vmax, '#55a868')}</td>"
                f"<td class=n>{_num(rp)} {_bar(rp, vmax, '#c44e52')}</td>"
                f"<td class=n>{_num(d)}</td></tr>")
        parts.append("</table>")
    rejected = list(result.views_rejected)
    for side, r in (("left", result.left), ("right", result.right)):
        listed = {a if side == "left" else b for a, b, _ in result.views_rejected}
        rejected += [(n, "", f"{side} port fit: {why}") if side == "left"
                     else ("", n, f"{side} port fit: {why}")
                     for n, why in r.views_rejected if n not in listed]
    if rejected:
        parts.append("<h2>Rejected views</h2><table><tr><th>left</th><th>right</th>"
                     "<th>reason</th></tr>" + "".join(
                         f"<tr><td>{e(a)}</td><td>{e(b)}</td><td class=bad>{e(why)}</td></tr>"
                         for a, b, why in rejected) + "</table>")
    cams = [(side, r) for side, r in (("left", result.left), ("right", result.right))
            if r.camera is not None and len(r.corners_px) == len(r.residuals_px) > 0]
    if cams:
        rms = max(r.rms_px for _, r in cams)
        gain = float(f"{residual_gain or (8.0 / max(rms, 1e-3)):.2g}")
        parts.append("<h2>Residual vectors through the port</h2><p>Detected corners (grey) and "
                     f"their reprojection errors through each camera's port model (red), "
                     f"magnified {gain:g} times. Errors that point the same way in a region "
                     "mean a model error there (port geometry, indices, distortion); random "
                     "directions are detection noise.</p><div class=figs>")
        for side, r in cams:
            assert r.camera is not None
            size = (r.camera.width, r.camera.height)
            fig = _arrows(size, r.corners_px, r.residuals_px, gain, f"{side}: residuals x{gain:g}")
            parts.append(f"<div>{_png(fig)}</div>")
        parts.append("</div>")
    parts.append("</body></html>")
    return "\n".join(parts)

