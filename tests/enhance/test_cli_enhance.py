"""``sea3d enhance`` and ``sea3d eval enhance``: files in, files out, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.enhance import compare_to_reference, grey_world, uciqe, uiqm
from sea3d.enhance._image import linear_to_srgb
from sea3d.io.depth_files import read_depth, write_depth_png_mm
from sea3d.io.session import SessionWriter, open_session


def _write_rgb(path: Path, img: np.ndarray) -> Path:
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path


@pytest.fixture
def underwater(tmp_path: Path) -> tuple[Path, Path, np.ndarray]:
    """A small synthetic underwater image (formation model, coastal-like) and its depth."""
    rng = np.random.default_rng(0)
    h, w = 90, 120
    J = rng.uniform(0.1, 0.9, size=(h, w, 3))
    J[rng.random((h, w)) < 0.03] = 0.0
    z = np.linspace(5.0, 1.0, h)[:, None].repeat(w, axis=1).astype(np.float32)
    I = J * np.exp(-np.array([0.5, 0.2, 0.3]) * z[..., None]) + np.array([0.05, 0.3, 0.25]) * (
        1 - np.exp(-np.array([0.45, 0.25, 0.3]) * z[..., None])
    )
    img = (linear_to_srgb(I.astype(np.float32)) * 255 + 0.5).astype(np.uint8)
    img_path = _write_rgb(tmp_path / "in.png", img)
    depth_path = tmp_path / "depth.npy"
    np.save(depth_path, z)
    return img_path, depth_path, img


def test_grey_world_file_round_trip(tmp_path: Path, underwater: tuple[Path, Path, np.ndarray],
                                    capsys: pytest.CaptureFixture[str]) -> None:
    img_path, _, img = underwater
    out = tmp_path / "out.png"
    assert sea3d_main(["enhance", str(img_path), "-o", str(out), "--method", "grey-world"]) == 0
    got = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(got, grey_world(img))


def test_seathru_with_depth_npy_and_png_agree(tmp_path: Path,
                                              underwater: tuple[Path, Path, np.ndarray],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    img_path, depth_path, _ = underwater
    out = tmp_path / "st.png"
    rc = sea3d_main(["enhance", str(img_path), "-o", str(out), "--depth", str(depth_path),
                     "--range", "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "ok"
    wm = summary["water_model"]  # the default: one water model, fitted to this image
    assert wm["status"] == "ok" and all(0 < b <= 5 for b in wm["beta_D_per_m"])
    rc = sea3d_main(["enhance", str(img_path), "-o", str(tmp_path / "fit.png"), "--depth",
                     str(depth_path), "--range", "--attenuation", "fit", "--json"])
    assert rc == 0
    per_image = json.loads(capsys.readouterr().out)
    assert per_image["seathru_model"]["backscatter_B_inf_betaB_Jprime_betaDprime"]
    # The same depth as a 16-bit millimetre PNG reads back to the millimetre.
    png = tmp_path / "depth.png"
    write_depth_png_mm(png, np.load(depth_path))
    np.testing.assert_allclose(read_depth(png), np.load(depth_path), atol=5e-4)
    out2 = tmp_path / "st2.png"
    assert sea3d_main(["enhance", str(img_path), "-o", str(out2), "--depth", str(png),
                       "--range"]) == 0
    a = cv2.imread(str(out)).astype(int)
    b = cv2.imread(str(out2)).astype(int)
    assert np.abs(a - b).mean() < 1.0


def test_bad_depth_inputs_give_one_line_errors(tmp_path: Path,
                                               underwater: tuple[Path, Path, np.ndarray],
                                               capsys: pytest.CaptureFixture[str]) -> None:
    img_path, depth_path, img = underwater
    out = tmp_path / "x.png"

    def run(*extra: str) -> str:
        rc = sea3d_main(["enhance", str(img_path), "-o", str(out), *extra])
        assert rc == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("sea3d: error:") and "\n" not in err
        return err

    small = tmp_path / "small.npy"
    np.save(small, np.ones((45, 60), dtype=np.float32))
    assert "60x45" in run("--depth", str(small)) and "120x90" in run("--depth", str(small))
    nan = tmp_path / "nan.npy"
    np.save(nan, np.full((90, 120), np.nan, dtype=np.float32))
    assert "cannot fit B_inf or beta_D" in run("--depth", str(nan))
    d8 = tmp_path / "depth8.png"
    cv2.imwrite(str(d8), np.full((90, 120), 100, dtype=np.uint8))
    assert "8-bit" in run("--depth", str(d8))
    assert "--depth" in run()
    grey = _write_rgb(tmp_path / "grey.png", np.repeat(img[..., :1], 3, axis=2))
    cv2.imwrite(str(grey), img[..., 1])  # a one-channel file
    rc = sea3d_main(["enhance", str(grey), "-o", str(out), "--depth", str(depth_path)])
    assert rc == 2 and "RGB" in capsys.readouterr().err
    assert not out.exists()  # nothing half-written


def test_eval_enhance_prints_full_and_no_reference_figures(
    tmp_path: Path, underwater: tuple[Path, Path, np.ndarray], capsys: pytest.CaptureFixture[str]
) -> None:
    img_path, _, img = underwater
    ref = _write_rgb(tmp_path / "ref.png", grey_world(img))
    assert sea3d_main(["eval", "enhance", str(img_path), str(ref), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"psnr_db", "ssim", "ciede2000", "ciede2000_gain", "ciede2000_diag"} <= set(out)
    assert out["ciede2000_diag"] < out["ciede2000"]  # grey world is a diagonal gain
    assert {"uiqm", "uicm", "uism", "uiconm"} <= set(out["uiqm"])
    assert "uciqe" in out["uciqe"] and out["colour_cast"] > 0
    # The command reports what the library computes on the files' pixels.
    want = compare_to_reference(img, grey_world(img))
    for key in ("psnr_db", "ssim", "ciede2000", "ciede2000_gain", "ciede2000_diag"):
        assert out[key] == pytest.approx(getattr(want, key), rel=1e-9), key
    assert out["uiqm"]["uiqm"] == pytest.approx(uiqm(img).uiqm, rel=1e-9)
    assert out["uciqe"]["uciqe"] == pytest.approx(uciqe(img).uciqe, rel=1e-9)
    assert sea3d_main(["eval", "enhance", str(img_path)]) == 0
    assert "UIQM" in capsys.readouterr().out
    other = _write_rgb(tmp_path / "other.png", img[:45])
    assert sea3d_main(["eval", "enhance", str(img_path), str(other)]) == 2


def test_session_enhancement_writes_a_new_session(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(1)
    src = tmp_path / "src"
    stamps = [0, 100_000_000, 200_000_000]
    with SessionWriter(src, format="folder") as w:
        for t in stamps:
            img = (rng.random((36, 48, 3)) * np.array([60, 200, 180])).astype(np.uint8)
            w.write_stereo(t, img, img)
            w.write_imu(t + 1, [0.0, 0.0, 9.81], [0.0, 0.0, 0.0])
        w.write_sonar(5, 1.5, 1.0)
    dst = tmp_path / "dst.mcap"
    rc = sea3d_main(["enhance", "--session", str(src), "-o", str(dst), "--method", "grey-world",
                     "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pairs"] == 3 and summary["status_counts"] == {"ok": 3}
    with open_session(src) as a, open_session(dst) as b:
        assert list(b.stamps("left")) == stamps and list(b.stamps("right")) == stamps
        assert len(b.imu()) == len(a.imu()) == 3 and len(b.sonar()) == 1
        left = b.image("left", 0)
        np.testing.assert_array_equal(left, grey_world(a.image("left", 0)))
    # The output must be new: an existing session is never overwritten.
    assert sea3d_main(["enhance", "--session", str(src), "-o", str(dst)]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.slow
def test_session_seathru_uses_our_stereo_depth(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim.scene import builtin_scene
    from sea3d.sim.survey import SurveyConfig, simulate_survey

    rig = paper_rig("none", size_px=(160, 90))
    src = tmp_path / "sim"
    cfg = SurveyConfig(frames=2, water="coastal", supersample=1, trajectory="orbit")
    with SessionWriter(src, format="folder", rig_yaml=rig_to_yaml(rig)) as w:
        simulate_survey(builtin_scene("lake"), rig, cfg, w, None)
    dst = tmp_path / "st"
    rc = sea3d_main(["enhance", "--session", str(src), "-o", str(dst), "--method", "seathru",
                     "--max-depth", "8", "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pairs"] == 2 and summary["status_counts"].get("ok", 0) == 2
    with open_session(src) as a, open_session(dst) as b:
        before, after = a.image("left", 0).astype(float), b.image("left", 0).astype(float)
    # The green-blue cast shrinks: red comes up relative to green.
    assert (after[..., 0].mean() / after[..., 1].mean()) > 1.3 * (
        before[..., 0].mean() / before[..., 1].mean()
    )
