"""``sea3d rig plan`` through the CLI entry point."""

from __future__ import annotations

import json

import pytest

from sea3d.cli import main
from sea3d.io.rig_file import save_rig
from sea3d.refraction.presets import paper_rig


def _plan_json(capsys, argv):
    assert main(["rig", "plan", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_plan_json_has_min_range_and_rows(capsys):
    out = _plan_json(
        capsys,
        [
            "--fx-px",
            "500",
            "--baseline-mm",
            "100",
            "--size",
            "320x180",
            "--max-disparity",
            "50",
            "--disparity-noise-px",
            "0.5",
        ],
    )
    # f B / N = 500 px * 0.1 m / 50 px
    assert out["min_range_m"] == pytest.approx(1.0, rel=2e-3)
    assert len(out["rows"]) >= 5
    for row in out["rows"]:
        z = row["range_m"]
        assert row["depth_error_m"] == pytest.approx(
            z * z * 0.5 / (out["focal_rectified_px"] * 0.1)
        )


def test_options_override_the_rig_file(tmp_path, capsys):
    rig_path = tmp_path / "rig.yaml"
    save_rig(paper_rig("none", size_px=(320, 180)), rig_path)
    base = _plan_json(capsys, [str(rig_path), "--range-m", "1", "3"])
    wide = _plan_json(capsys, [str(rig_path), "--range-m", "1", "3", "--baseline-mm", "214"])
    assert base["baseline_m"] == pytest.approx(0.107, rel=1e-6)
    assert wide["baseline_m"] == pytest.approx(0.214, rel=1e-6)
    assert wide["min_range_m"] == pytest.approx(2 * base["min_range_m"], rel=1e-6)
    assert wide["rows"][0]["depth_error_m"] == pytest.approx(
        base["rows"][0]["depth_error_m"] / 2, rel=1e-6
    )
    assert base["rows"][0]["range_m"] == pytest.approx(1.0)
    assert base["rows"][-1]["range_m"] == pytest.approx(3.0)


def test_port_rig_table_and_plot(tmp_path, capsys):
    png = tmp_path / "plan.png"
    assert main(["rig", "plan", "--size", "320x180", "--port", "flat", "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    assert "in water (virtual pinhole)" in text and "bias if ports ignored" in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_range_is_a_one_line_error(capsys):
    assert main(["rig", "plan", "--range-m", "3", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sea3d: error:") and "MIN < MAX" in err
