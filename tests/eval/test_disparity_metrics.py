"""Disparity metrics and the ``sea3d eval disparity`` command."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import StereoError
from sea3d.eval import disparity_metrics
from sea3d.io.depth_files import read_disparity, read_pfm, write_disparity, write_pfm

EXACT_PERCENT = 1e-9


def test_metrics_known_answer() -> None:
    gt = np.array([[10.0, 10.0, 10.0, 10.0], [10.0, 10.0, 0.0, np.nan]], np.float32)
    est = np.array([[10.2, 10.7, 11.5, 13.0], [np.nan, 10.0, 99.0, 5.0]], np.float32)
    m = disparity_metrics(est, gt)
    # known GT: 6 pixels; estimate valid on 5 of them; errors 0.2 0.7 1.5 3.0 0.0
    assert m.n_gt == 6
    assert m.density == pytest.approx(100 * 5 / 6, abs=EXACT_PERCENT)
    assert m.bad_0_5 == pytest.approx(100 * 3 / 5, abs=EXACT_PERCENT)
    assert m.bad_1 == pytest.approx(100 * 2 / 5, abs=EXACT_PERCENT)
    assert m.bad_2 == pytest.approx(100 * 1 / 5, abs=EXACT_PERCENT)
    assert m.bad_4 == pytest.approx(0.0, abs=EXACT_PERCENT)
    assert m.bad_2_all == pytest.approx(100 * 2 / 6, abs=EXACT_PERCENT)
    assert m.epe_px == pytest.approx((0.2 + 0.7 + 1.5 + 3.0) / 5, abs=1e-6)


def test_metrics_bad_input() -> None:
    with pytest.raises(StereoError, match="shapes"):
        disparity_metrics(np.zeros((2, 3)), np.zeros((3, 2)))
    with pytest.raises(StereoError, match="no known pixel"):
        disparity_metrics(np.ones((2, 2)), np.zeros((2, 2)))


def test_pfm_round_trip_keeps_values_orientation_and_nan(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    d = rng.random((7, 5)).astype(np.float32) * 40
    d[1, 2] = np.nan
    write_pfm(tmp_path / "d.pfm", d)
    back = read_pfm(tmp_path / "d.pfm")
    np.testing.assert_array_equal(back, d)
    rgb = rng.random((4, 3, 3)).astype(np.float32)
    write_pfm(tmp_path / "c.pfm", rgb)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), rgb)


def test_pfm_reads_big_endian_bottom_up_files_written_by_hand(tmp_path: Path) -> None:
    # Middlebury-style: big-endian (positive scale), rows bottom to top, inf unknown
    rows_bottom_up = np.array([[3.0, np.inf], [1.0, 2.0]], dtype=">f4")
    (tmp_path / "h.pfm").write_bytes(b"Pf\n2 2\n1.0\n" + rows_bottom_up.tobytes())
    back = read_pfm(tmp_path / "h.pfm")
    np.testing.assert_array_equal(back, np.array([[1.0, 2.0], [3.0, np.nan]], np.float32))


def test_disparity_file_formats_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    d = (rng.random((6, 9)) * 30 + 1).astype(np.float32)
    d[0, 0] = np.nan
    for suffix in (".pfm", ".npy", ".tiff"):
        write_disparity(tmp_path / f"d{suffix}", d)
        np.testing.assert_array_equal(read_disparity(tmp_path / f"d{suffix}"), d)
    scaled = np.where(np.isfinite(d), np.round(d * 4), 0).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "gt.png"), scaled)
    back = read_disparity(tmp_path / "gt.png", scale=4)
    np.testing.assert_allclose(back, np.where(scaled > 0, scaled / 4.0, np.nan), equal_nan=True)
    with pytest.raises(StereoError, match="scale"):
        read_disparity(tmp_path / "gt.png")
    with pytest.raises(StereoError, match="not found"):
        read_disparity(tmp_path / "missing.pfm")
    with pytest.raises(StereoError, match="unknown disparity output"):
        write_disparity(tmp_path / "d.jpg", d)


def test_eval_disparity_cli_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = np.full((10, 12), 8.0, np.float32)
    est = gt + 0.75
    est[0, :] = np.nan
    write_disparity(tmp_path / "est.pfm", est)
    cv2.imwrite(str(tmp_path / "gt.png"), (gt * 4).astype(np.uint8))
    assert main(["eval", "disparity", str(tmp_path / "est.pfm"), str(tmp_path / "gt.png"),
                 "--scale", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["bad_0_5"] == pytest.approx(100.0)
    assert out["bad_1"] == pytest.approx(0.0)
    assert out["density"] == pytest.approx(100 * 108 / 120)
    assert out["epe_px"] == pytest.approx(0.75, abs=1e-6)
    assert main(["eval", "disparity", str(tmp_path / "est.pfm"), str(tmp_path / "gt.png")]) == 2
