"""Board specs, object points, detection (rendered boards and real photos), printable PDFs."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.calib.printable import PT_PER_M, board_pdf, paper_size_mm
from sea3d.calib.targets import (
    BoardSpec,
    DetectionStatus,
    _version_offset_px,
    board_origin_offset_m,
    corner_convention_offset_px,
    detect_board,
    diagnose_checkerboard_size,
    load_board,
    parse_board,
    render_board,
)
from sea3d.errors import ConfigError

# Rendered boards are sharp and noise-free: OpenCV's detectors find corners to a small fraction
# of a pixel there (measured 0.02-0.05 px); 0.15 px leaves room for interpolation effects.
RENDERED_CORNER_TOL_PX = 0.15
# AprilTag corners of a rendered tag (measured below 0.01 px on a sharp rendering).
RENDERED_TAG_CORNER_TOL_PX = 0.1
PDF_SCALE_TOL_PT = 1e-3  # the PDF writes 4 decimals of a point (1 pt = 0.353 mm)


def _expected_px(board: BoardSpec, points_m: np.ndarray, px_per_m: float,
                 margin_m: float) -> np.ndarray:
    ox, oy = board_origin_offset_m(board)
    return np.stack([(margin_m + ox + points_m[:, 0]) * px_per_m - 0.5,
                     (margin_m + oy + points_m[:, 1]) * px_per_m - 0.5], axis=1)


def test_parse_checkerboard_spec_gives_inner_corners_and_metres() -> None:
    b = parse_board("checkerboard:9x6:25mm")
    assert (b.kind, b.cols, b.rows) == ("checkerboard", 9, 6)
    assert b.square_m == pytest.approx(0.025)
    assert b.n_corners == 54
    assert parse_board(b.name).name == b.name
    assert parse_board("checkerboard:9x6:2.5cm").square_m == pytest.approx(0.025)


def test_parse_charuco_and_tag_specs() -> None:
    c = parse_board("charuco:5x7:40mm:30mm:DICT_6X6_250")
    assert (c.cols, c.rows, c.corner_grid) == (5, 7, (4, 6))
    assert c.marker_m == pytest.approx(0.03)
    assert c.n_corners == 24
    a = parse_board("apriltag:7x5:91.4mm:114.3mm")
    assert a.dictionary == "DICT_APRILTAG_36h11"
    assert (a.marker_m, a.square_m) == (pytest.approx(0.0914), pytest.approx(0.1143))
    assert a.n_corners == 7 * 5 * 4
    assert parse_board(a.name).name == a.name
    shifted = parse_board("aruco:2x2:40mm:50mm:DICT_4X4_50:first=10")
    assert shifted.ids_grid().tolist() == [[10, 11], [12, 13]]


@pytest.mark.parametrize("spec", [
    "checkerboard:9x6", "checkerboard:9by6:25mm", "checkerboard:9x6:25", "checkerboard:1x6:25mm",
    "charuco:5x7:40mm", "charuco:5x7:40mm:50mm:DICT_6X6_250", "circles:4x11:20mm",
    "charuco:5x7:40mm:30mm:DICT_NOPE", "checkerboard:9x6:-25mm",
])
def test_malformed_board_specs_raise_config_error_naming_the_spec(spec: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(spec.split(":")[0]) + "|board|kind|DICT"):
        parse_board(spec)


def test_object_points_start_at_first_inner_corner_x_along_first_count() -> None:
    b = parse_board("checkerboard:4x3:10mm")
    ids, pts = b.object_points()
    assert ids.tolist() == list(range(12))
    np.testing.assert_allclose(pts[0], [0, 0, 0])
    np.testing.assert_allclose(pts[1], [0.01, 0, 0])  # x along the first count
    np.testing.assert_allclose(pts[4], [0, 0.01, 0])  # y along the second
    np.testing.assert_allclose(pts[-1], [0.03, 0.02, 0])
    assert np.all(pts[:, 2] == 0)


def test_tag_grid_corners_are_clockwise_from_top_left() -> None:
    b = parse_board("apriltag:2x1:80mm:100mm")
    ids, pts = b.object_points()
    assert ids[:4].tolist() == [0, 1, 2, 3]
    np.testing.assert_allclose(pts[:4, :2], [[0, 0], [0.08, 0], [0.08, 0.08], [0, 0.08]])
    np.testing.assert_allclose(pts[4, :2], [0.1, 0])  # next tag one pitch along x


def test_board_yaml_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "board.yaml"
    path.write_text("type: apriltag\ncols: 2\nrows: 2\nsquare_mm: 50\nmarker_mm: 40\n"
                    "ids: [[5, 6], [7, 8]]\n")
    b = load_board(path)
    assert b.ids_grid().tolist() == [[5, 6], [7, 8]]
    assert parse_board(str(path)).ids_grid().tolist() == [[5, 6], [7, 8]]
    bad = tmp_path / "bad.yaml"
    bad.write_text("type: checkerboard\ncols: 9\n")
    with pytest.raises(ConfigError, match=r"bad.yaml.*rows"):
        load_board(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_board(tmp_path / "missing.yaml")


@pytest.mark.parametrize("use_sb", [True, False])
def test_rendered_checkerboard_is_detected_at_true_corner_positions(use_sb: bool) -> None:
    board = parse_board("checkerboard:7x5:20mm")
    px_per_m, margin = 1500.0, 0.02
    img = render_board(board, px_per_m=px_per_m, margin_m=margin)
    img = cv2.GaussianBlur(img, (3, 3), 0.8)
    det = detect_board(img, board, use_sector_based=use_sb)
    assert det.status is DetectionStatus.DETECTED
    expected = _expected_px(board, det.points_board_m, px_per_m, margin)
    err = np.linalg.norm(det.corners_px - expected, axis=1)
    assert err.max() < RENDERED_CORNER_TOL_PX


def test_rendered_charuco_and_tag_grid_are_detected_with_ids() -> None:
    ch = parse_board("charuco:5x7:30mm:22mm:DICT_6X6_250")
    px_per_m = 2000.0
    img = cv2.copyMakeBorder(render_board(ch, px_per_m=px_per_m), 40, 40, 40, 40,
                             cv2.BORDER_CONSTANT, value=255)
    det = detect_board(img, ch)
    assert det.status is DetectionStatus.DETECTED and len(det) == 24
    expected = _expected_px(ch, det.points_board_m, px_per_m, 40 / px_per_m)
    assert np.linalg.norm(det.corners_px - expected, axis=1).max() < RENDERED_CORNER_TOL_PX
    tags = parse_board("apriltag:3x2:40mm:50mm")
    img = render_board(tags, px_per_m=3000.0, margin_m=0.01)
    det = detect_board(img, tags)
    assert det.status is DetectionStatus.DETECTED and len(det) == 24
    expected = _expected_px(tags, det.points_board_m, 3000.0, 0.01)
    assert np.linalg.norm(det.corners_px - expected, axis=1).max() < RENDERED_TAG_CORNER_TOL_PX
    # ArUco dictionaries use cornerSubPix refinement, whose corners are already pixel-centred
    # (OpenCV 4.10-4.14): a fixed half-pixel shift put them 0.71 px off.
    aruco = parse_board("aruco:3x2:40mm:50mm:DICT_4X4_50")
    img = render_board(aruco, px_per_m=3000.0, margin_m=0.01)
    det = detect_board(img, aruco)
    assert det.status is DetectionStatus.DETECTED and len(det) == 24
    expected = _expected_px(aruco, det.points_board_m, 3000.0, 0.01)
    assert np.linalg.norm(det.corners_px - expected, axis=1).max() < RENDERED_CORNER_TOL_PX


@pytest.mark.parametrize("refinement", ["charuco", "apriltag", "subpix"])
def test_corner_convention_measured_at_run_time_matches_the_table_of_known_versions(
        refinement: str) -> None:
    # The run-time measurement is what detection uses; the table (OpenCV 4.10-4.14, measured
    # in docs/calibration.md) is its fallback. Disagreement means a new OpenCV changed the
    # convention again: detection is still right, but the table and the docs need a line.
    assert corner_convention_offset_px(refinement) == _version_offset_px(refinement)


def test_missing_and_wrong_size_boards_get_a_status_not_an_exception() -> None:
    board = parse_board("checkerboard:7x5:20mm")
    blank = np.full((200, 300), 128, np.uint8)
    assert detect_board(blank, board).status is DetectionStatus.NOT_FOUND
    assert detect_board(np.zeros((0, 0)), board).status is DetectionStatus.UNREADABLE
    other = render_board(parse_board("checkerboard:6x5:20mm"), px_per_m=1500.0, margin_m=0.02)
    det = detect_board(other, board)
    assert det.status is DetectionStatus.NOT_FOUND and len(det) == 0
    assert diagnose_checkerboard_size(other, board) == (6, 5)
    tags = parse_board("apriltag:2x2:40mm:50mm:first=100")
    img = render_board(parse_board("apriltag:2x2:40mm:50mm"), px_per_m=3000.0, margin_m=0.01)
    assert detect_board(img, tags).status is DetectionStatus.WRONG_SIZE


@pytest.mark.data
def test_real_charuco_photos(data_dir: Path) -> None:
    board = parse_board("charuco:5x7:40mm:20mm:DICT_6X6_250")
    folder = data_dir / "calib" / "charuco_opencv"
    full = detect_board(cv2.imread(str(folder / "choriginal.jpg"))[:, :, ::-1], board)
    assert full.status is DetectionStatus.DETECTED and len(full) == 24  # SOURCE.md: 24/24
    occluded = detect_board(cv2.imread(str(folder / "chocclusion.jpg"))[:, :, ::-1], board)
    # SOURCE.md: OpenCV's CharucoDetector finds 1 of the 24 corners behind the occlusion.
    assert occluded.status is DetectionStatus.PARTIAL and len(occluded) == 1


@pytest.mark.data
def test_apriltags_are_detected_in_real_deep_sea_images(data_dir: Path) -> None:
    folder = data_dir / "underwater" / "camhd_apriltag"
    board = load_board(folder / "april_poster_45in.yml")
    assert board.ids_grid()[0].tolist() == [96, 97, 98, 99, 100, 101, 102]
    valid_ids = set(board.object_points()[0].tolist())
    images = sorted(folder.glob("*.jpg"))
    assert len(images) == 3
    for path in images:
        det = detect_board(cv2.imread(str(path))[:, :, ::-1], board)
        # SOURCE.md: OpenCV's DICT_APRILTAG_36h11 finds 3-8 tags per zoom6 image.
        assert det.status is DetectionStatus.DETECTED, (path.name, det.message)
        assert len(det) >= 12 and len(det) % 4 == 0
        assert set(det.ids.tolist()) <= valid_ids
        # The four corners of every tag form a convex quadrilateral of plausible size.
        for k in range(0, len(det), 4):
            quad = det.corners_px[k:k + 4].astype(np.float32)
            assert cv2.isContourConvex(quad)
            assert 100 < cv2.contourArea(quad) < 1920 * 1080 / 4


def _pdf_objects(data: bytes) -> dict[int, bytes]:
    # Every xref offset must point at its object: the file is well-formed.
    xref = int(data[data.rindex(b"startxref") + 9:].split()[0])
    table = data[xref:].split(b"\n")
    n = int(table[1].split()[1])
    objs = {}
    for i in range(1, n):
        off = int(table[2 + i].split()[0])
        assert data[off:].startswith(f"{i} 0 obj".encode())
        objs[i] = data[off:data.index(b"endobj", off)]
    return objs


def _content(objs: dict[int, bytes]) -> str:
    body = objs[4]
    stream = body[body.index(b"stream\n") + 7:body.rindex(b"\nendstream")]
    return zlib.decompress(stream).decode("latin-1")


def test_board_pdf_has_true_scale_squares_on_a0() -> None:
    board = parse_board("checkerboard:9x6:95mm")
    objs = _pdf_objects(board_pdf(board, "A0"))
    media = [float(v) for v in re.search(rb"/MediaBox \[([^\]]+)\]", objs[3]).group(1).split()]
    a0_w, a0_h = paper_size_mm("A0")
    # 950 mm wide: only fits A0 in landscape.
    assert media[2] == pytest.approx(a0_h * 1e-3 * PT_PER_M, abs=PDF_SCALE_TOL_PT)
    assert media[3] == pytest.approx(a0_w * 1e-3 * PT_PER_M, abs=PDF_SCALE_TOL_PT)
    rects = [[float(v) for v in m.groups()] for m in re.finditer(
        r"([-0-9.]+) ([-0-9.]+) ([-0-9.]+) ([-0-9.]+) re f", _content(objs))]
    squares = [r for r in rects if r[3] > 10]  # the scale bar is 1.5 pt high
    assert len(squares) == 35  # 10 x 7 squares, half of them black
    side_pt = 0.095 * PT_PER_M  # 95 mm = 269.29 pt
    for r in squares:
        assert r[2] == pytest.approx(side_pt, abs=PDF_SCALE_TOL_PT)
        assert r[3] == pytest.approx(side_pt, abs=PDF_SCALE_TOL_PT)
    xs = sorted({round(r[0], 3) for r in squares})
    np.testing.assert_allclose(np.diff(xs), side_pt, atol=2 * PDF_SCALE_TOL_PT)
    bar = next(r for r in rects if r[3] <= 10)
    assert bar[2] == pytest.approx(0.1 * PT_PER_M, abs=PDF_SCALE_TOL_PT)  # 100 mm scale bar


def test_raster_board_pdf_places_the_image_at_true_size() -> None:
    board = parse_board("charuco:5x7:30mm:22mm:DICT_6X6_250")
    objs = _pdf_objects(board_pdf(board, "A4"))
    m = re.search(r"q ([0-9.]+) 0 0 ([0-9.]+) [-0-9.]+ [-0-9.]+ cm /Im1 Do Q", _content(objs))
    assert m is not None
    assert float(m.group(1)) == pytest.approx(0.15 * PT_PER_M, abs=PDF_SCALE_TOL_PT)
    assert float(m.group(2)) == pytest.approx(0.21 * PT_PER_M, abs=PDF_SCALE_TOL_PT)
    assert b"/Subtype /Image" in objs[6]


def test_board_too_large_for_the_paper_is_refused() -> None:
    with pytest.raises(ConfigError, match="does not fit on A4"):
        board_pdf(parse_board("checkerboard:9x6:95mm"), "A4")
    with pytest.raises(ConfigError, match="unknown paper"):
        paper_size_mm("B7")
