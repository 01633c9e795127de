"""Monocular depth as a plug-in: ONNX networks built by the tests, alignment to metric depth.

References: exact answers by construction. A network returning the mean of its (normalised)
input maps an image whose grey value is affine in inverse depth to an affine function of inverse
depth, so the alignment must recover the metric depth up to 8-bit quantisation and resizing; a
network returning a baked-in map of the simulator's true inverse depth is an oracle whose
alignment to our stereo depth (SGM on a simulated pair) must fill stereo's holes with the true
depth.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import ConfigError, MonoDepthError
from sea3d.monodepth import MonoDepthConfig, OnnxDepthModel, align_depth, select_providers

EXACT_REL = 1e-6  # exact affine inverse-depth prediction (float32 output map)
QUANTISED_REL = 0.01  # 8-bit image through a 2x resize: measured 0.3 %
HOLES_REL = 0.05  # oracle network, holes of SGM at 320x180 (measured about 2 %)


def _plane_depth(h: int, w: int) -> np.ndarray:
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    return 1.0 + 5.0 * (uu / (w - 1)) * 0.7 + 5.0 * (vv / (h - 1)) * 0.3  # 1 m to 6 m


def test_alignment_in_inverse_depth_is_exact_despite_holes_and_outliers() -> None:
    rng = np.random.default_rng(0)
    z = _plane_depth(60, 80)
    pred = 0.37 / z + 0.05
    sparse = z.copy()
    sparse[rng.random(z.shape) < 0.7] = np.nan  # holes
    out = rng.random(z.shape) < 0.1
    sparse[out] *= 1.5  # gross outliers
    depth, al = align_depth(pred, sparse, kind="inverse")
    assert al.status == "ok"
    np.testing.assert_allclose(depth, z, rtol=EXACT_REL)
    assert al.scale == pytest.approx(1 / 0.37, rel=1e-9)
    assert al.shift == pytest.approx(-0.05 / 0.37, rel=1e-6)
    valid = np.isfinite(sparse)
    assert al.samples == int(valid.sum()) and al.inliers == int((valid & ~out).sum())
    # relative depth networks are fitted in depth, metric ones by scale alone
    d2, _ = align_depth(2.0 * z + 0.5, sparse, kind="depth")
    np.testing.assert_allclose(d2, z, rtol=EXACT_REL)
    d3, al3 = align_depth(0.8 * z, sparse, kind="metric")
    np.testing.assert_allclose(d3, z, rtol=EXACT_REL)
    assert al3.shift == 0.0 and al3.scale == pytest.approx(1.25)


def test_alignment_reports_failures() -> None:
    z = _plane_depth(30, 40)
    sparse = np.full(z.shape, np.nan)
    sparse[0, :5] = z[0, :5]
    _, al = align_depth(1 / z, sparse)
    assert al.status == "failed" and "5 sparse" in al.message
    # a network that returns depth taken for inverse depth: no positive scale fits
    depth, al = align_depth(z, z, kind="inverse")
    assert al.status == "failed" and "output_kind" in al.message and np.isnan(depth).all()
    with pytest.raises(MonoDepthError, match="same"):
        align_depth(z, z[:-1])


def test_cli_aligns_to_a_depth_map_with_holes_through_a_resizing_network(
    make_net: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(0)
    net = make_net("mean", 48, 64)  # type: ignore[operator]
    z = _plane_depth(96, 128)
    inv = 1.0 / z
    grey = np.round(20 + 230 * (inv - inv.min()) / (inv.max() - inv.min())).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "img.png"), grey)
    sparse = z.astype(np.float32).copy()
    holes = rng.random(z.shape) < 0.5
    sparse[holes] = np.nan
    np.save(tmp_path / "sparse.npy", sparse)
    out = tmp_path / "depth.npy"
    assert main(["mono-depth", str(tmp_path / "img.png"), "--model", str(net), "-o", str(out),
                 "--align-depth", str(tmp_path / "sparse.npy"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["metric"] is True and summary["alignment"]["status"] == "ok"
    assert summary["filled_fraction"] == pytest.approx(holes.mean(), abs=1e-9)
    depth = np.load(out)
    np.testing.assert_array_equal(depth[~holes], sparse[~holes])  # the given depth is kept
    rel = np.abs(depth[holes] - z[holes]) / z[holes]
    # away from the border (the 2x resize there is one-sided)
    inner = np.zeros(z.shape, bool)
    inner[4:-4, 4:-4] = True
    assert float(np.median(rel)) < QUANTISED_REL
    assert float(np.percentile(np.abs(depth - z)[holes & inner] / z[holes & inner], 95)) < \
        3 * QUANTISED_REL


def test_cli_fills_stereo_holes_with_the_aligned_network(
    make_net: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sea3d.geometry.se3 import look_at
    from sea3d.io.rig_file import save_rig
    from sea3d.rectify import rectify_rig
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import simulate_pair

    rig = paper_rig("dome", size_px=(320, 180))
    T = look_at([0.6, -1.4, 1.3], [0.0, 0.0, 0.0])
    left, right, gt = simulate_pair(rig, "lake", T, "clear")
    maps = rectify_rig(rig, depth_range_m=(0.5, 10.0))
    # true depth in the rectified left view (the rectifying rotation of this rig is tiny)
    z_rect = cv2.remap(gt.depth_m, maps.map_left_x, maps.map_left_y, cv2.INTER_NEAREST,
                       borderValue=np.nan)
    inv = np.nan_to_num(1.0 / z_rect, nan=0.0)  # nothing hit: infinitely far
    net = make_net("constant", 90, 160,  # type: ignore[operator]
                   constant=cv2.resize(inv, (160, 90), interpolation=cv2.INTER_AREA))
    for name, img in (("L.png", left), ("R.png", right)):
        cv2.imwrite(str(tmp_path / name), img[:, :, ::-1])
    save_rig(rig, tmp_path / "rig.yaml")
    out = tmp_path / "depth.npy"
    assert main(["mono-depth", str(tmp_path / "L.png"), "--model", str(net), "-o", str(out),
                 "--rig", str(tmp_path / "rig.yaml"), "--right", str(tmp_path / "R.png"),
                 "--engine", "opencv", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frame"] == "rect_left" and summary["alignment"]["status"] == "ok"
    assert summary["alignment"]["scale"] == pytest.approx(1.0, rel=0.05)
    depth = np.load(out)
    holes = np.isfinite(z_rect) & (z_rect < 10.0)
    assert 0.0 < summary["filled_fraction"] < 1.0
    filled = holes & np.isfinite(depth)
    rel = np.abs(depth[filled] - z_rect[filled]) / z_rect[filled]
    assert float(np.median(rel)) < HOLES_REL


def test_bad_models_and_outputs_are_named(make_net: object, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    img = tmp_path / "img.png"
    cv2.imwrite(str(img), np.zeros((48, 64, 3), np.uint8))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"this is not a protobuf")
    for model, expect in ((junk, "not a loadable ONNX model"),
                          (make_net("mean", 48, 64, channels=1),  # type: ignore[operator]
                           "unexpected input shape [1, 1, 48, 64]"),
                          (tmp_path / "missing.onnx", "model file not found")):
        assert main(["mono-depth", str(img), "--model", str(model), "-o",
                     str(tmp_path / "o.npy")]) == 2
        err = capsys.readouterr().err
        assert str(model) in err and expect in err
    net = make_net("mean", 48, 64)  # type: ignore[operator]
    # unaligned relative output cannot become millimetres
    assert main(["mono-depth", str(img), "--model", str(net), "-o", str(tmp_path / "o.png")]) == 2
    assert "relative" in capsys.readouterr().err
    assert main(["mono-depth", str(img), "--model", str(net), "-o", str(tmp_path / "o.npy")]) == 0
    np.save(tmp_path / "small.npy", np.ones((10, 10), np.float32))
    assert main(["mono-depth", str(img), "--model", str(net), "-o", str(tmp_path / "o.npy"),
                 "--align-depth", str(tmp_path / "small.npy")]) == 2
    err = capsys.readouterr().err
    assert "small.npy" in err and "10x10" in err


def test_providers_and_dynamic_input_size(make_net: object) -> None:
    assert select_providers("cpu", ["CUDAExecutionProvider", "CPUExecutionProvider"]) == [
        "CPUExecutionProvider"]
    assert select_providers("auto", ["CUDAExecutionProvider", "CPUExecutionProvider"])[0] == \
        "CUDAExecutionProvider"
    assert select_providers("auto", ["CPUExecutionProvider"]) == ["CPUExecutionProvider"]
    with pytest.raises(MonoDepthError, match="CUDA"):
        select_providers("cuda", ["CPUExecutionProvider"])
    dyn = OnnxDepthModel(make_net("mean", 48, 64, dynamic=True))  # type: ignore[operator]
    assert dyn.input_size(1920, 1080) == (518, 294)  # long side 518, multiples of 14
    y, _ = dyn.predict(np.zeros((1080, 1920, 3), np.uint8))
    assert y.shape == (1080, 1920)
    with pytest.raises(ConfigError):
        MonoDepthConfig(output_kind="disparity")


SFM_REL = 1e-3  # oracle network aligned to exact SfM points (float32 map; measured ~1e-6);
# a half-pixel slip in COLMAP's pixel convention costs about 1 % on this plane


def test_cli_aligns_to_the_points_of_a_colmap_model(
    make_net: object, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import pycolmap

    h, w, f = 48, 64, 50.0
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.0 + 5.0 * uu / (w - 1) + 0.5 * vv / (h - 1)  # a tilted plane, 1-6.5 m
    net = make_net("constant", h, w, constant=2.3 / z + 0.1)  # type: ignore[operator]
    cv2.imwrite(str(tmp_path / "left.png"), np.full((h, w), 128, np.uint8))
    # a COLMAP model of one image seeing 200 points on the plane at whole pixels
    rng = np.random.default_rng(0)
    uv = np.round(rng.uniform([2, 2], [w - 3, h - 3], (200, 2)))
    zp = z[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    cx, cy = w / 2 - 0.5, h / 2 - 0.5  # our convention: the top-left pixel centre is (0, 0)
    xyz = np.column_stack([(uv[:, 0] - cx) / f * zp, (uv[:, 1] - cy) / f * zp, zp])
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(
        model="PINHOLE", width=w, height=h, params=[f, f, cx + 0.5, cy + 0.5], camera_id=1))
    rec.add_image_with_trivial_frame(
        pycolmap.Image(name="left.png", keypoints=uv + 0.5, camera_id=1, image_id=1),
        pycolmap.Rigid3d())
    for k in range(len(xyz)):
        track = pycolmap.Track()
        track.add_element(1, k)
        rec.add_point3D(xyz[k], track)
    model = tmp_path / "sparse"
    model.mkdir()
    rec.write_binary(str(model))
    out = tmp_path / "depth.npy"
    assert main(["mono-depth", str(tmp_path / "left.png"), "--model", str(net), "-o", str(out),
                 "--align-sfm", str(model), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    n_pixels = len(np.unique(uv, axis=0))  # one sample per pixel (the nearest point)
    assert summary["alignment"]["status"] == "ok"
    assert summary["alignment"]["samples"] == n_pixels
    depth = np.load(out)
    assert float(np.max(np.abs(depth - z) / z)) < SFM_REL
    # an image the model does not hold is named
    cv2.imwrite(str(tmp_path / "other.png"), np.full((h, w), 128, np.uint8))
    assert main(["mono-depth", str(tmp_path / "other.png"), "--model", str(net), "-o",
                 str(out), "--align-sfm", str(model)]) == 2
    assert "no registered image named like 'other.png'" in capsys.readouterr().err
