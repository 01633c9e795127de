"""Enhancement inside ``sea3d process``: named ``--enhance`` hooks before matching, and
``--restore-colours seathru`` (the dive's one water model) and ``seathru-per-image`` on the
mesh and cloud colours after depth.

The session is a short simulated survey of the lake in coastal water with clean references
(the same views without water), through a portless rig so that no virtual pinhole is fitted.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.enhance.registry import ENHANCEMENTS, process_enhance_hook
from sea3d.errors import EnhanceError
from sea3d.io.result_cache import read_entry
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, open_session
from sea3d.pipeline.colour_stage import DiveColourConfig
from sea3d.pipeline.frame_stage import FrameResult, FrameStageConfig, _resolve_hook, process_frame
from sea3d.pipeline.process import (
    ColourConfig,
    ExecutorConfig,
    PoseConfig,
    ProcessConfig,
    run_process,
)
from sea3d.pipeline.report import _colour_html
from sea3d.refraction.presets import paper_rig
from sea3d.sim.scene import builtin_scene
from sea3d.sim.survey import SurveyConfig, simulate_survey
from sea3d.stereo.recipe import DepthConfig

SIZE_PX = (192, 108)
MAX_DEPTH_M = 8.0
# Colour cast as |log(mean R / mean G)| + |log(mean B / mean G)| against the clean view (no
# water): coastal water puts 0.84 on the raw image here (measured), Sea-thru with our stereo
# range leaves 0.23 (27 %). A restoration that did not run, ran on the wrong image, or got the
# range in the wrong unit keeps most of the cast.
CAST_KEPT_MAX = 0.4  # fraction of the raw image's cast left after Sea-thru
# The cloud and mesh are coloured by the restored frames: their log chromaticity follows the
# frames' (measured within 0.006: TSDF averaging, voxel downsampling, outlier removal); the
# raw frames' is 0.68 away in log(R/G).
FUSED_LOG_CHROMA_TOL = 0.05
# Sea-thru of the raw rectified image whatever hook fed matching: the range differs a little
# (other matches), the chromaticity by 0.001 (measured).
HOOKED_LOG_CHROMA_TOL = 0.03


def _chroma(pixels: np.ndarray) -> np.ndarray:
    """log(R/G), log(B/G) of the mean of (N, 3) pixels."""
    m = pixels.reshape(-1, 3).astype(np.float64).mean(axis=0)
    return np.log(np.array([m[0] / m[1], m[2] / m[1]]))


def _cast(pixels: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(_chroma(pixels) - _chroma(reference)).sum())


@pytest.fixture(scope="module")
def survey(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    root = tmp_path_factory.mktemp("colours")
    rig = paper_rig("none", size_px=SIZE_PX)
    src, gt = root / "lake", root / "lake_gt"
    cfg = SurveyConfig(frames=2, water="coastal", supersample=1, clean_reference=True)
    with SessionWriter(src, format="folder", rig_yaml=rig_to_yaml(rig)) as w:
        simulate_survey(builtin_scene("lake"), rig, cfg, w, gt)
    with open_session(src) as s:
        t0 = int(s.stamps("left")[0])
        left, right = s.image("left", t0), s.image("right", t0)
    clean = cv2.imread(str(gt / "clean" / "left" / f"{t0}.png"))[:, :, ::-1]
    stage = FrameStageConfig(rig=rig, depth=DepthConfig(max_depth_m=MAX_DEPTH_M))
    plain = process_frame(stage, t0, left, right)
    restored = process_frame(FrameStageConfig(rig=rig, depth=DepthConfig(max_depth_m=MAX_DEPTH_M),
                                              restore_colours="seathru"), t0, left, right)
    return {"root": root, "session": src, "gt": gt, "t0": t0, "left": left, "right": right,
            "clean": clean, "rig": rig, "plain": plain, "restored": restored}


def _zero_green_blue(img: np.ndarray) -> np.ndarray:
    """A hook that changes the matching images drastically (red channel only)."""
    out = img.copy()
    out[..., 1:] = 0
    return out


def test_seathru_after_depth_removes_the_water_cast(survey: dict[str, object]) -> None:
    plain, restored = survey["plain"], survey["restored"]
    assert isinstance(plain, FrameResult) and isinstance(restored, FrameResult)
    assert plain.status == restored.status == "ok"
    assert plain.color_left.size == 0 and plain.colour_status == ""
    assert restored.colour_status == "ok" and "restore_colours_s" in restored.timings_s
    # Depth, and the images the odometry gets, are not touched by the colour restoration.
    np.testing.assert_array_equal(restored.depth_m, plain.depth_m)
    np.testing.assert_array_equal(restored.rect_left, plain.rect_left)
    has = np.isfinite(restored.depth_m)
    assert has.mean() > 0.5
    clean = np.asarray(survey["clean"])
    raw_cast = _cast(plain.rect_left[has], clean)
    assert raw_cast > 0.6  # the test means something: coastal water is strongly blue-green
    assert _cast(restored.colors()[has], clean) < CAST_KEPT_MAX * raw_cast


def test_seathru_restores_the_camera_colours_not_the_hooked_ones(
    survey: dict[str, object],
) -> None:
    rig = survey["rig"]
    cfg = FrameStageConfig(rig=rig, depth=DepthConfig(max_depth_m=MAX_DEPTH_M),  # type: ignore[arg-type]
                           enhance=_zero_green_blue, restore_colours="seathru")
    res = process_frame(cfg, int(survey["t0"]), survey["left"], survey["right"])  # type: ignore[arg-type]
    assert res.rect_left[..., 1:].max() == 0  # matching saw the hooked images
    restored = survey["restored"]
    assert isinstance(restored, FrameResult)
    both = np.isfinite(res.depth_m) & np.isfinite(restored.depth_m)
    assert both.mean() > 0.3
    # Same camera image, nearly the same range: nearly the same restoration (green is back).
    d = np.abs(_chroma(res.colors()[both]) - _chroma(restored.colors()[both]))
    assert d.max() < HOOKED_LOG_CHROMA_TOL


def test_process_colours_mesh_and_cloud_with_the_restored_frames(
    survey: dict[str, object],
) -> None:
    out = Path(str(survey["root"])) / "out"
    res = run_process(Path(str(survey["session"])), ProcessConfig(
        out_dir=out, executor=ExecutorConfig(workers=0),
        poses=PoseConfig(poses_path=Path(str(survey["gt"])) / "poses_left.tum"),
        colours=ColourConfig(restore_colours="seathru-per-image"),
        depth=DepthConfig(max_depth_m=MAX_DEPTH_M), report=False, evaluate=False))
    colours = res.summary["colours"]
    assert {k: v for k, v in colours.items() if k not in ("per_frame", "per_frame_s")} == {
        "enhance": "none", "restore": "seathru-per-image", "restore_status": {"ok": 2}}
    assert set(colours["per_frame_s"]) == {"match_s", "restore_colours_s"}
    assert [st for _t, st in colours["per_frame"]] == ["ok", "ok"]
    restored, plain = survey["restored"], survey["plain"]
    assert isinstance(restored, FrameResult) and isinstance(plain, FrameResult)
    # report.html's colour section: each frame's status and one frame before and after.
    page = _colour_html(colours, [plain.rect_left, restored.colors()])
    assert page.count("<td>ok</td>") == 2 and "<img" in page and "ok: 2" in page
    assert _colour_html({"restore": "none"}, None) == ""
    has = np.isfinite(restored.depth_m)
    want = _chroma(restored.colors()[has])
    raw = _chroma(plain.rect_left[has])
    assert np.abs(want - raw).max() > 5 * FUSED_LOG_CHROMA_TOL  # restored and raw differ
    for name, colors in (("cloud", res.cloud_colors), ("mesh", res.mesh.colors_rgb)):
        got = _chroma(np.asarray(colors))
        assert np.abs(got - want).max() < FUSED_LOG_CHROMA_TOL, name


def test_named_enhancements_resolve_to_image_functions(rng: np.random.Generator) -> None:
    img = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    assert process_enhance_hook("none") is None
    for name, entry in ENHANCEMENTS.items():
        if entry.needs_range:
            with pytest.raises(EnhanceError, match="restore_colours"):
                process_enhance_hook(name)
            continue
        path = entry.function
        assert process_enhance_hook(name) == path
        out = _resolve_hook(path)(img)
        assert out.shape == img.shape and out.dtype == np.uint8 and not np.array_equal(out, img)
    assert process_enhance_hook("my.module:fn") == "my.module:fn"
    with pytest.raises(EnhanceError, match="unknown enhancement 'sharpen'"):
        process_enhance_hook("sharpen")


def test_cli_refuses_an_unknown_enhancement_in_one_line(
    survey: dict[str, object], capsys: pytest.CaptureFixture[str]
) -> None:
    rc = sea3d_main(["process", str(survey["session"]), "-o", str(Path(str(survey["root"])) / "x"),
                     "--enhance", "sharpen", "--workers", "0"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("sea3d: error:") and err.count("\n") == 1
    assert "sharpen" in err and "clahe" in err
    with pytest.raises(SystemExit):
        sea3d_main(["process", str(survey["session"]), "-o", "y", "--restore-colours", "fit"])


@pytest.fixture(scope="module")
def dive(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """8 frames of the lake in coastal water (a short dive), with clean references."""
    root = tmp_path_factory.mktemp("dive")
    rig = paper_rig("none", size_px=SIZE_PX)
    src, gt = root / "lake", root / "lake_gt"
    cfg = SurveyConfig(frames=8, water="coastal", supersample=1, clean_reference=True)
    with SessionWriter(src, format="folder", rig_yaml=rig_to_yaml(rig)) as w:
        simulate_survey(builtin_scene("lake"), rig, cfg, w, gt)
    return {"root": root, "session": src, "gt": gt}


def _water_run(dive: dict[str, Path], out: Path) -> object:
    return run_process(dive["session"], ProcessConfig(
        out_dir=out, executor=ExecutorConfig(workers=0),
        poses=PoseConfig(poses_path=dive["gt"] / "poses_left.tum"),
        colours=ColourConfig(restore_colours="seathru",
                             dive_colours=DiveColourConfig(fit_frames=3, fit_stride=2)),
        depth=DepthConfig(max_depth_m=MAX_DEPTH_M), report=False, evaluate=False))


def test_process_fits_one_water_model_per_run_and_the_cache_holds_no_colours(
    dive: dict[str, Path], monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sea3d.pipeline import colour_stage

    calls: list[int] = []
    real_fit = colour_stage.fit_water_model

    def counting_fit(frames, config=None):  # type: ignore[no-untyped-def]
        calls.append(len(frames))
        return real_fit(frames, config)

    monkeypatch.setattr(colour_stage, "fit_water_model", counting_fit)
    out = dive["root"] / "water"
    res = _water_run(dive, out)
    assert calls == [6]  # once per run, from 3 pairs (every 2nd of the start, both views)
    colours = res.summary["colours"]  # type: ignore[attr-defined]
    info = colours["water_model"]
    assert info["fits"] == 1 and len(info["fit_frames_t_ns"]) == 3
    model = info["water_model"]
    # The fit identifies every term on this dive (no bound or fallback status), and red is
    # lost fastest, as in the simulated coastal water (sim/optics.py: beta_D 0.60/0.22/0.32).
    assert model["status"] == "ok"
    assert int(np.argmax(model["beta_D_per_m"])) == 0
    # Every frame restored with the model, each with the model's status: none passed on early.
    assert [st for _t, st in colours["per_frame"]] == [model["status"]] * 8
    assert colours["restore_status"] == {model["status"]: 8}
    assert colours["per_frame_s"]["restore_colours_s"] > 0
    # The per-frame stage, its fingerprint and its cache are those of a run without
    # restoration: nothing cached depends on the model.
    plain = ProcessConfig(out_dir=out, colours=ColourConfig(restore_colours="none"))
    water = ProcessConfig(out_dir=out, colours=ColourConfig(restore_colours="water-model"))
    rig = paper_rig("none", size_px=SIZE_PX)
    assert water.frame_stage(rig).fingerprint() == plain.frame_stage(rig).fingerprint()
    # ``seathru`` is the dive's model (``water-model`` its older name); per image is its own.
    dive_cfg = ProcessConfig(out_dir=out, colours=ColourConfig(restore_colours="seathru"))
    assert dive_cfg.colours.per_dive and water.colours.per_dive
    assert dive_cfg.frame_stage(rig).fingerprint() == plain.frame_stage(rig).fingerprint()
    per_image = ProcessConfig(out_dir=out,
                              colours=ColourConfig(restore_colours="seathru-per-image"))
    assert per_image.frame_stage(rig).restore_colours == "seathru"
    entries = sorted((out / "cache").rglob("*.s3c"))
    assert len(entries) == 8
    assert all("color_left" not in read_entry(e)[0] for e in entries)
    # A rerun from the cache fits the same model again and colours the cloud the same way.
    again = _water_run(dive, out)
    assert again.summary["frames_from_cache"] == 8  # type: ignore[attr-defined]
    assert calls == [6, 6]
    assert again.summary["colours"]["water_model"]["water_model"] == model  # type: ignore[attr-defined]
    # (the cloud's points come out in another order: compare them sorted)
    def by_point(r: object) -> np.ndarray:
        pts, col = r.cloud_points, r.cloud_colors  # type: ignore[attr-defined]
        return np.asarray(col)[np.lexsort(np.asarray(pts).T)]

    np.testing.assert_array_equal(by_point(again), by_point(res))
    # report.html names the model, its fit status and parameters.
    page = _colour_html(colours, None)
    assert "Water model of the dive" in page and model["status"] in page
    assert f"{model['beta_D_per_m'][0]:.3f}" in page and "B_inf" in page


def test_report_says_when_the_dive_water_could_not_be_fitted() -> None:
    page = _colour_html({"restore": "water-model", "restore_status": {"fallback-grey-world": 2},
                         "per_frame": [(1, "fallback-grey-world"), (2, "fallback-grey-world")],
                         "water_model": {"water_model": None, "fit_error": "no frame with "
                                         "depth and colour to fit the water to"}}, None)
    assert "<b>not fitted</b>" in page and "no frame with depth" in page


def test_the_dive_model_keeps_the_restoration_stable_whatever_fed_matching(
    survey: dict[str, object], dive: dict[str, Path],
) -> None:
    """The frame-to-frame test above with the dive's one model: the same camera frame with
    slightly different range (other matches) restores to the same colour."""
    from sea3d.pipeline.colour_stage import DiveColours
    from sea3d.pipeline.frame_stage import stage_depth

    rig = survey["rig"]
    plain_cfg = FrameStageConfig(rig=rig, depth=DepthConfig(max_depth_m=MAX_DEPTH_M))  # type: ignore[arg-type]
    hooked_cfg = FrameStageConfig(rig=rig, depth=DepthConfig(max_depth_m=MAX_DEPTH_M),  # type: ignore[arg-type]
                                  enhance=_zero_green_blue)
    t0, left, right = int(survey["t0"]), survey["left"], survey["right"]  # type: ignore[call-overload]
    plain = process_frame(plain_cfg, t0, left, right)
    hooked = process_frame(hooked_cfg, t0, left, right)
    # Matching saw the hooked images; the colours come from the camera's own, as in process
    # (its ordered stages restore FrameResult.rect_left, which a hook does not touch there:
    # restore the plain frame's rectified image with the hooked frame's range).
    assert hooked.rect_left[..., 1:].max() == 0
    maps = stage_depth(plain_cfg).maps
    dive_colours = DiveColours(maps, DiveColourConfig(fit_frames=1))
    (a,) = dive_colours.push(plain)
    (b,) = dive_colours.push(dataclasses.replace(plain, depth_m=hooked.depth_m))
    assert dive_colours.fits == 1
    both = np.isfinite(plain.depth_m) & np.isfinite(hooked.depth_m)
    assert both.mean() > 0.3
    d = np.abs(_chroma(a.colors()[both]) - _chroma(b.colors()[both]))
    # measured 0.0012 (a water model fitted to each of the two frames: 0.08)
    assert d.max() < HOOKED_LOG_CHROMA_TOL
