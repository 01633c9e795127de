"""The end-to-end demo at a small size: dive, one-pair check, process, one report."""

import json
from pathlib import Path

import pytest

from sea3d.cli import main
from sea3d.errors import ConfigError
from sea3d.pipeline.demo import DemoConfig

# At 320x180 a pixel covers 36x the area of the paper's 1920x1080, so depth is coarser; 3 %
# median relative error still separates working metric depth from a scale or refraction bug.
MEDIAN_REL_ERROR_SMALL = 0.03
# Mesh accuracy with the simulator's poses at 320x180 and 2 cm voxels (measured 4.3 mm).
MESH_MEDIAN_TOL_M = 0.01


@pytest.mark.slow
def test_demo_runs_the_whole_chain_into_one_report(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--size", "320x180", "--frames", "8",
                 "--workers", "0", "--json"])
    assert code == 0
    s = json.loads(capsys.readouterr().out)
    assert s == json.loads((out / "summary.json").read_text())
    pair = s["depth_check"]
    assert pair["image_size_px"] == [320, 180]
    assert pair["refraction_corrected"]["median_rel"] < MEDIAN_REL_ERROR_SMALL
    # Ignoring the domes (in-air calibration underwater) must be clearly worse.
    assert pair["ports_ignored_baseline"]["median_rel"] > 2 * pair["refraction_corrected"][
        "median_rel"]
    p = s["process"]
    assert p["frames"] == 8 and p["frames_fused"] == 8
    assert p["mesh_vs_gt"]["accuracy_m"]["median"] < MESH_MEDIAN_TOL_M
    assert "ate_m" in p["trajectory_vs_gt"]
    assert s["timings_s"]["compile_s"] >= 0 and s["timings_s"]["total_s"] > 0
    for name in ("report.html", "summary.json", "session/rig.yaml", "session/gt/poses_left.tum",
                 "process/trajectory.tum", "process/mesh.ply", "process/cloud.ply"):
        assert (out / name).is_file(), name
    html = (out / "report.html").read_text()
    assert html.count("<h1>") == 1
    for part in ("One stereo pair", "Trajectory", "Mesh", "Status timeline", "Timings",
                 "colour bar: depth (m)", "one-off"):
        assert part in html, part
    # The report sends the user where the files are, results.mcap included.
    assert "Files in process/: process/trajectory.tum" in html and "process/results.mcap" in html
    assert Path(s["files"]["results_mcap"]) == out / "process" / "results.mcap"


def test_demo_rejects_tiny_images(tmp_path):
    with pytest.raises(ConfigError, match="at least 64x48"):
        DemoConfig(out_dir=tmp_path, size_px=(32, 32))
    with pytest.raises(ConfigError, match="at least 3 frames"):
        DemoConfig(out_dir=tmp_path, frames=2)
