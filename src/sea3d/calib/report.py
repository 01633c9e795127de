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

from sea3d.calib.stereo import StereoCalibration
from sea3d.errors import CalibrationError

__all__ = ["rectified_pair", "render_report"]

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
    img, s = _canvas(cam.image_size)
    for v in result.views:
        uv = v.corners_left_px if side == "left" else v.corners_right_px
        res = v.residuals_left_px if side == "left" else v.residuals_right_px
        for (u, vv), (du, dv) in zip(uv, res, strict=True):
            p0 = (round(u * s), round(vv * s))
            p1 = (round((u + gain * du) * s), round((vv + gain * dv) * s))
            cv2.circle(img, p0, 1, (120, 120, 120), -1)
            cv2.line(img, p0, p1, (200, 30, 30), 1, cv2.LINE_AA)
    cv2.putText(img, f"{side}: residuals x{gain:g}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)
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
    if result.ok and result.left is not None and result.right is not None:
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
    if result.ok and result.left is not None:
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
