"""HTML reports with embedded pictures (one self-contained file, no network)."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["image_tag", "write_demo_report"]


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


def write_demo_report(
    path: Path,
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
) -> Path:
    """Write the demo's HTML report and return its path."""
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
    timings = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{v:.2f} s</td></tr>"
        for k, v in summary["timings_s"].items()
    )
    cfg = summary["config"]
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>sea3d demo</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; max-width: 1000px; color: #222; }}
img {{ max-width: 100%; display: block; margin: 0.3em 0 1em; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; }}
td, th {{ border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }}
.pair {{ display: flex; gap: 0.5em; }} .pair div {{ flex: 1; }}
.note {{ color: #555; font-size: 0.9em; }}
</style></head><body>
<h1>sea3d demo: refraction-corrected stereo depth</h1>
<p>Scene <b>{html.escape(str(cfg["scene"]))}</b>, water <b>{html.escape(str(cfg["water"]))}</b>,
the paper's rig ({summary["image_size_px"][0]}x{summary["image_size_px"][1]}, baseline 107 mm)
behind <b>{html.escape(str(cfg["port"]))}</b> ports, engine <b>{html.escape(str(cfg["engine"]))}</b>
with {summary["max_disparity_px"]} disparities. Valid depth on
{_pct(summary["valid_fraction"])} of the rectified pixels, {summary["points"]} points.</p>
<h2>Input pair (simulated, with ground truth)</h2>
<div class="pair"><div>{image_tag(left, "left image", max_width_px=640)}</div>
<div>{image_tag(right, "right image", max_width_px=640)}</div></div>
<h2>Depth against ground truth</h2>
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
<h2>Disparity</h2>
<p class="note">Rectified left view, colour scale {disparity_range[0]:.0f} (blue) to
{disparity_range[1]:.0f} px (red); black = invalid.</p>
{image_tag(disparity_rgb, "disparity")}
<h2>Depth</h2>
<p class="note">Rectified left view, {depth_range_m[0]} m (blue) to {depth_range_m[1]} m (red).</p>
{image_tag(depth_rgb, "depth")}
<h2>Depth error</h2>
<p class="note">Raw left view, estimated minus true depth,
{1000 * error_range_m[0]:.0f} mm (blue) to +{1000 * error_range_m[1]:.0f} mm (red);
green is zero.</p>
{image_tag(error_rgb, "depth error")}
<h2>Point cloud</h2>
<p class="note">cloud.ply (left camera frame, metres), seen from above and to the side.</p>
{image_tag(cloud_rgb, "point cloud")}
<h2>Timings</h2><table>{timings}</table>
<p class="note">Files beside this report: rig.yaml, depth_mm.png (16-bit millimetres, 0 =
invalid), depth_m.npy (float32 metres, NaN invalid), disparity.pfm, cloud.ply,
gt_depth_m.npy, summary.json.</p>
</body></html>
"""
    path.write_text(page)
    return path
