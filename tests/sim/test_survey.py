"""Simulated sessions read back through the session reader, with consistent ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.errors import SimulationError
from sea3d.io.ground_truth import read_gt_depth, write_gt_depth
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, open_session
from sea3d.refraction.presets import paper_rig
from sea3d.sim.motion import Mount, Orbit
from sea3d.sim.scene import builtin_scene
from sea3d.sim.survey import SurveyConfig, simulate_survey

SONAR_REL_TOL = 0.03  # 0.5 % range noise, 3 sigma plus beam footprint on a bumpy floor
TUM_TOL_M = 1e-8


@pytest.mark.parametrize("fmt", ["folder", "mcap"])
def test_simulated_session_reads_back_with_all_streams(tmp_path: Path, fmt: str) -> None:
    rig = paper_rig("dome", size_px=(96, 54))
    scene = builtin_scene("lake")
    config = SurveyConfig(frames=3, fps=10.0, water="coastal", supersample=1, trajectory="orbit")
    out = tmp_path / ("s.mcap" if fmt == "mcap" else "s")
    gt = tmp_path / "gt"
    with SessionWriter(out, format=fmt, rig_yaml=rig_to_yaml(rig)) as w:
        result = simulate_survey(scene, rig, config, w, gt)
    with open_session(out) as s:
        pairs = list(s.pairs())
        imu = s.imu()
        sonar = s.sonar()
    assert [p.t_ns for p in pairs] == result.frame_t_ns.tolist() == [0, 100_000_000, 200_000_000]
    assert pairs[0].left.shape == (54, 96, 3)
    assert len(imu) == 41 and imu.t_ns[-1] == 200_000_000  # 200 Hz over 0.2 s
    assert len(sonar) == 3
    depth = read_gt_depth(gt / "depth" / "100000000.tiff")
    assert depth.dtype == np.float32 and depth.shape == (54, 96) and np.isfinite(depth).any()
    tum = np.loadtxt(gt / "poses_left.tum")
    np.testing.assert_allclose(tum[:, 1:4], result.T_world_left[:, :3, 3], atol=TUM_TOL_M)
    assert (gt / "scene.ply").stat().st_size > 0


def test_echosounder_measures_the_distance_to_the_floor_below() -> None:
    scene = builtin_scene("lake")
    traj = Orbit(
        target_m=(0.0, 0.0, 0.0), radius_m=1.5, height_m=1.0, duration_s=1.0, camera_tilt_deg=30.0
    )
    mount = Mount.default()
    rig = paper_rig("none", size_px=(32, 18))

    class Sink:
        def __init__(self) -> None:
            self.sonar: list[tuple[int, float, float]] = []

        def write_stereo(self, *a: object) -> None:
            pass

        def write_imu(self, *a: object) -> None:
            pass

        def write_sonar(self, t_ns: int, r: float, c: float = 0.0) -> None:
            self.sonar.append((t_ns, r, c))

    sink = Sink()
    config = SurveyConfig(frames=1, water="none", supersample=1, imu_noise=False)
    simulate_survey(scene, rig, config, sink, None, trajectory=traj, mount=mount)
    _t_ns, r, conf = sink.sonar[0]
    from sea3d.sim.motion import poses

    T = poses(traj, np.array([0.0]))[0] @ mount.T_body_sonar
    origin, down = T[:3, 3], -T[:3, 2]
    # The floor height along the beam, found by bisection on the scene's height function.
    lo, hi = 0.0, 5.0
    for _ in range(60):
        mid = (lo + hi) / 2
        p = origin + mid * down
        if p[2] > scene.floor_height(np.array([p[0]]), np.array([p[1]]))[0]:
            lo = mid
        else:
            hi = mid
    assert conf == 1.0 and r == pytest.approx(lo, rel=SONAR_REL_TOL)


def test_scale_rig_keeps_pixel_centres_and_ports() -> None:
    rig = paper_rig("dome")
    small = rig.scaled(960, 540)
    assert (small.width, small.height) == (960, 540)
    assert small.left.pinhole.fx == pytest.approx(rig.left.pinhole.fx / 2)
    assert small.left.pinhole.cx == pytest.approx((rig.left.pinhole.cx + 0.5) / 2 - 0.5)
    assert small.left.port == rig.left.port


def test_cli_calibration_writes_images_and_true_board_poses(tmp_path: Path) -> None:
    out = tmp_path / "cal"
    status = sea3d_main(
        [
            "sim",
            "calibration",
            "--board",
            "checkerboard:9x6:40mm",
            "--views",
            "2",
            "--size",
            "320x180",
            "--distance",
            "0.8",
            "1.4",
            "--medium",
            "air",
            "--out",
            str(out),
        ]
    )
    assert status == 0
    import json

    boards = json.loads((out / "gt" / "boards.json").read_text())
    assert len(boards) == 2 and np.asarray(boards[0]["T_left_board"]).shape == (4, 4)
    assert (
        len(list((out / "left").glob("*.png"))) == 2
        and len(list((out / "right").glob("*.png"))) == 2
    )
    # Rendered in air: the true rig has no ports (it had the paper's domes before the fix).
    from sea3d.io.rig_file import load_rig

    true_rig = load_rig(out / "rig_true.yaml")
    assert true_rig.left.port is None and true_rig.right.port is None


def test_cli_rejects_a_missing_output_and_unknown_scene(tmp_path: Path) -> None:
    assert sea3d_main(["sim", "--scene", "lake", "--frames", "1"]) == 2
    assert (
        sea3d_main(["sim", "--scene", "atlantis", "--frames", "1", "--out", str(tmp_path / "x")])
        == 2
    )


def test_cli_survey_with_a_rig_file_writes_a_folder_session(tmp_path: Path) -> None:
    from sea3d.io.rig_file import load_rig, save_rig

    rig_path = save_rig(paper_rig("flat", size_px=(1920, 1080)), tmp_path / "rig.yaml")
    out = tmp_path / "run"
    argv = [
        "sim",
        "--scene",
        "tank",
        "--rig",
        str(rig_path),
        "--frames",
        "2",
        "--size",
        "96x54",
        "--water",
        "turbid",
        "--trajectory",
        "handheld",
        "--out",
        str(out),
        "--format",
        "folder",
    ]
    assert sea3d_main(argv) == 0
    with open_session(out) as s:
        assert len(list(s.pairs())) == 2
        stored = s.rig_yaml
    assert stored is not None and "96" in stored
    assert load_rig(rig_path).width == 1920  # the input file is untouched
    assert len(list((out / "gt" / "depth").glob("*.tiff"))) == 2


def test_ground_truth_depth_is_stored_bit_for_bit_and_smaller_than_npy(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    # A rough surface (the lake's sand is no smoother) with holes where nothing is hit.
    v, u = np.mgrid[0:120, 0:160]
    depth = (1.5 + 0.002 * u + 0.01 * np.sin(v / 7.0) + 1e-4 * rng.standard_normal(v.shape))
    depth = depth.astype(np.float32)
    depth[:10, :40] = np.nan
    path = tmp_path / "d.tiff"
    write_gt_depth(path, depth)
    back = read_gt_depth(path)
    assert back.dtype == np.float32 and np.array_equal(back, depth, equal_nan=True)
    assert path.stat().st_size < 0.8 * depth.nbytes
    with pytest.raises(SimulationError, match="cannot read"):
        read_gt_depth(tmp_path / "missing.tiff")


def test_cli_one_frame_survey_with_imu_noise_writes_one_of_each(tmp_path: Path, capsys) -> None:
    out = tmp_path / "one.mcap"
    argv = ["sim", "--frames", "1", "--size", "64x36", "--supersample", "1", "--out", str(out)]
    assert sea3d_main(argv) == 0
    printed = capsys.readouterr().out
    # The cost is said before the run starts, and counts read as English.
    assert "simulating 1 stereo pair of lake" in printed and "of ground truth" in printed
    assert "1 stereo frame, 1 IMU sample and 1 echosounder sample" in printed
    with open_session(out) as s:
        assert len(list(s.pairs())) == 1 and len(s.imu()) == 1
    assert len(list((tmp_path / "one_gt" / "depth").glob("*.tiff"))) == 1


def test_cli_refuses_a_run_the_disk_cannot_hold_and_cleans_up_a_failed_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    import sea3d.sim.survey as survey

    out = tmp_path / "big.mcap"
    monkeypatch.setattr(survey, "disk_free_bytes", lambda _p: 10_000_000)
    assert sea3d_main(["sim", "--frames", "300", "--out", str(out)]) == 2
    assert "the run needs about 3.1 GB but" in capsys.readouterr().err
    assert not out.exists()
    monkeypatch.undo()

    def broken(*_a: object, **_k: object) -> None:
        raise SimulationError("broken before the first frame")

    monkeypatch.setattr(survey, "simulate_survey", broken)
    assert sea3d_main(["sim", "--frames", "2", "--size", "64x36", "--out", str(out)]) == 2
    assert not out.exists() and not (tmp_path / "big_gt").exists()


def test_cost_estimate_counts_the_start_up_and_a_first_compilation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A short run is dominated by its fixed costs: the estimate once said "about 1 s" for 30
    # frames at 320x180 that took 5-6 CPU-s with the kernels cached and 41 s on a first run.
    import sea3d.sim.survey as survey
    from sea3d.sim import SurveyConfig

    config = SurveyConfig(frames=30, water="coastal")
    monkeypatch.setattr(survey, "renderer_is_compiled", lambda: True)
    warm = survey.estimate_survey_cost(320, 180, config)
    assert not warm.compiles and 3.0 <= warm.total_seconds <= 10.0
    assert warm.total_seconds == pytest.approx(warm.seconds + warm.startup_seconds)
    monkeypatch.setattr(survey, "renderer_is_compiled", lambda: False)
    cold = survey.estimate_survey_cost(320, 180, config)
    assert cold.compiles and cold.total_seconds >= warm.total_seconds + 30.0
    assert cold.seconds == warm.seconds  # the per-frame part does not change


def test_renderer_cache_is_found_where_numba_writes_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sea3d.sim import _kernels
    from sea3d.sim.survey import renderer_is_compiled

    beside = Path(_kernels.__file__).resolve().parent / "__pycache__"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    if not any(beside.glob("_kernels.*.nbi")):
        assert not renderer_is_compiled()
    (tmp_path / "_kernels.shade-1.py311.nbi").write_bytes(b"")
    assert renderer_is_compiled()
