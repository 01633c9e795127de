"""Echosounder against stereo on a synthetic seafloor whose every range is known.

The world: a sloped plane ``z = Z0 + SX x + SY y`` (world z up) with a smooth random texture,
seen by a pinhole stereo rig on the simulator's default mount (cameras 60 degrees down, the
echosounder looking straight down, 30 degrees off the optical axis and so outside the view at
the same instant), flying along x at 0.3 m/s, 10 frames and pings per second. Images are
rendered exactly (each pixel's ray meets the plane; the texture is looked up there), so the
stereo is real matching on real images; true ranges are ray-plane intersections.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from _textures import smooth_noise, stretch
from sea3d.cli import main
from sea3d.errors import OdometryError
from sea3d.eval.sonar import (
    DepthView,
    beam_axis,
    compare_ranges,
    evaluate_sonar,
    interpolate_pose,
    stereo_range,
)
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import SonarSpec, StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter
from sea3d.io.trajectory_files import read_trajectory, write_tum
from sea3d.sim.motion import Mount

W, H, FX, B = 320, 180, 220.0, 0.12
Z0, SX, SY = -1.5, 0.08, -0.05  # seafloor 1.5 m below the start, gently sloped
SPEED, FPS, N = 0.3, 10.0, 40
SONAR_NOISE = 0.005  # 0.5 % of range, as the Ping's datasheet and the simulator
GEOMETRY_M = 1e-3  # exact depth maps: only the 1 cm march and the plane fit remain
STEREO_MEDIAN_M = 0.02  # OpenCV SGBM at 320x180 on this texture: about 1 cm at 1.5 m


def _rig() -> StereoRig:
    pin = PinholeCamera(fx=FX, fy=FX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)
    T = np.eye(4)
    T[0, 3] = B
    mount = Mount.default(baseline_m=B, camera_tilt_deg=60.0)
    T_left_sonar = invert_T(mount.T_body_left) @ mount.T_body_sonar
    return StereoRig(
        left=pin, right=pin, T_left_right=T, sonar=SonarSpec(T_left_sonar=T_left_sonar)
    )


def _poses() -> tuple[np.ndarray, np.ndarray]:
    mount = Mount.default(baseline_m=B, camera_tilt_deg=60.0)
    t_ns = (np.arange(N) * 1e9 / FPS).astype(np.int64)
    T = np.repeat(np.eye(4)[None], N, axis=0)
    T[:, 0, 3] = SPEED * t_ns * 1e-9
    T[:, 1, 3] = 0.02 * np.sin(t_ns * 1e-9)  # a little sway
    return t_ns, T @ mount.T_body_left  # T_world_left


_NORMAL = np.array([-SX, -SY, 1.0]) / np.linalg.norm([-SX, -SY, 1.0])


def _hit(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Ray parameter where rays meet the plane (n . p = n . p0, p0 = (0, 0, Z0))."""
    num = _NORMAL @ np.array([0.0, 0.0, Z0]) - origins @ _NORMAL
    return num / (dirs @ _NORMAL)


_TEX_M_PER_PX = 0.005  # 5 mm texels over a 7 m square from (-1, -3.5)


def _render(cam: PinholeCamera, T_world_cam: np.ndarray, tex: np.ndarray):
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    d_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    d_cam = d_cam.reshape(-1, 3)
    d_w = d_cam @ T_world_cam[:3, :3].T
    o_w = np.broadcast_to(T_world_cam[:3, 3], d_w.shape)
    s = _hit(o_w, d_w)
    p = o_w + s[:, None] * d_w
    mx = ((p[:, 0] + 1.0) / _TEX_M_PER_PX).reshape(H, W).astype(np.float32)
    my = ((p[:, 1] + 3.5) / _TEX_M_PER_PX).reshape(H, W).astype(np.float32)
    img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR)
    depth = (s * d_cam[:, 2]).reshape(H, W).astype(np.float32)  # z along the camera axis
    rgb = np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    return rgb, depth


def _true_range(T_world_left: np.ndarray, rig: StereoRig) -> float:
    o, d = beam_axis(T_world_left, rig.sonar.T_left_sonar)
    return float(_hit(o[None], d[None])[0])


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    rig = _rig()
    tex = (stretch(smooth_noise(np.random.default_rng(7), (1400, 1400), 2.5)) * 220
           + 20).astype(np.float32)
    t_ns, T_wl = _poses()
    root = tmp_path_factory.mktemp("seafloor")
    session = root / "dive.mcap"
    gt = root / "dive_gt"
    (gt / "depth").mkdir(parents=True)
    rng = np.random.default_rng(0)
    truth = np.array([_true_range(T, rig) for T in T_wl])
    sonar = truth * (1 + SONAR_NOISE * rng.standard_normal(N))
    with SessionWriter(session, rig_yaml=rig_to_yaml(rig)) as w:
        for k in range(N):
            left, depth = _render(rig.left, T_wl[k], tex)
            right, _ = _render(rig.right, T_wl[k] @ np.asarray(rig.T_left_right), tex)
            w.write_sonar(int(t_ns[k]), float(sonar[k]), 1.0)
            w.write_stereo(int(t_ns[k]), left, right)
            np.save(gt / "depth" / f"{int(t_ns[k])}.npy", depth)
    write_tum(gt / "poses_left.tum", t_ns.tolist(), T_wl)
    return {"rig": rig, "t_ns": t_ns, "T": T_wl, "session": session, "gt": gt,
            "truth": truth, "sonar": sonar}  # fmt: skip


def _exact_views(world) -> list[DepthView]:
    return [
        DepthView(
            t_ns=int(t),
            depth_m=np.load(world["gt"] / "depth" / f"{int(t)}.npy"),
            camera=world["rig"].left,
            T_world_camera=T,
        )
        for t, T in zip(world["t_ns"], world["T"], strict=True)
    ]


def test_exact_depth_gives_the_true_range_along_the_beam(world):
    views = _exact_views(world)
    ev = evaluate_sonar(
        sonar_t_ns=world["t_ns"], sonar_range_m=world["sonar"], frame_t_ns=world["t_ns"],
        T_world_left=world["T"], views=views, T_left_sonar=world["rig"].sonar.T_left_sonar,
        truth_range_m=world["truth"],
    )  # fmt: skip
    assert ev.measured >= N - 12  # the first pings' footprint was not seen yet
    assert ev.stereo_vs_truth.median_abs_diff_m < GEOMETRY_M
    assert abs(ev.stereo_vs_truth.bias_m) < GEOMETRY_M
    # against the echosounder, what remains is its own noise (0.5 % of 1.5 m = 7.5 mm sd)
    assert ev.stereo_vs_sonar.spread_m == pytest.approx(SONAR_NOISE * 1.5, rel=0.5)
    assert not np.isfinite(ev.stereo_range_m[0])  # nothing seen before the first ping


def test_beam_outside_the_view_needs_the_poses(world):
    views = [
        DepthView(t_ns=v.t_ns, depth_m=v.depth_m, camera=v.camera, T_world_camera=np.eye(4))
        for v in _exact_views(world)
    ]
    ev = evaluate_sonar(
        sonar_t_ns=world["t_ns"], sonar_range_m=world["sonar"], frame_t_ns=None,
        T_world_left=None, views=views, T_left_sonar=world["rig"].sonar.T_left_sonar,
    )  # fmt: skip
    assert ev.measured == 0 and "same-instant" in ev.method
    assert ev.stereo_vs_sonar.samples == 0


def test_cone_finds_the_nearest_surface_inside_the_beam(world):
    views = _exact_views(world)
    k = N - 5
    o, d = beam_axis(world["T"][k], world["rig"].sonar.T_left_sonar)
    axis = stereo_range(views, o, d, int(world["t_ns"][k]), beam_deg=0.0)
    cone = stereo_range(views, o, d, int(world["t_ns"][k]), beam_deg=30.0)
    h = float(_NORMAL @ (o - np.array([0.0, 0.0, Z0])))  # perpendicular distance to the plane
    assert axis.range_m == pytest.approx(world["truth"][k], abs=GEOMETRY_M)
    assert h - GEOMETRY_M < cone.range_m < axis.range_m


def test_pose_interpolation_and_comparison_known_answers():
    T0, T1 = np.eye(4), np.eye(4)
    a = np.radians(40)
    T1[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    T1[:3, 3] = (2.0, 0.0, -1.0)
    t = np.array([0, 100], dtype=np.int64)
    mid = interpolate_pose(t, np.stack([T0, T1]), 25, max_gap_ns=100)
    assert mid is not None
    np.testing.assert_allclose(mid[:3, 3], (0.5, 0.0, -0.25))
    assert np.degrees(np.arctan2(mid[1, 0], mid[0, 0])) == pytest.approx(10.0)
    assert interpolate_pose(t, np.stack([T0, T1]), 400, max_gap_ns=100) is None
    c = compare_ranges([1.0, 2.1, np.nan, 3.0], [1.1, 2.0, 5.0, 3.0])
    assert c.samples == 3 and c.median_abs_diff_m == pytest.approx(0.1)
    assert c.bias_m == pytest.approx(0.0) and c.rmse_m == pytest.approx(np.sqrt(0.02 / 3))


def test_tum_round_trip_and_bad_lines(world, tmp_path):
    traj = read_trajectory(world["gt"] / "poses_left.tum", "tum")
    t, T = traj.t_ns, traj.T_world_x
    assert t.tolist() == world["t_ns"].tolist()
    np.testing.assert_allclose(T, world["T"], atol=1e-8)
    bad = tmp_path / "bad.tum"
    bad.write_text("# t x y z qx qy qz qw\n0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0\n")
    with pytest.raises(OdometryError, match=r"bad\.tum:3: expected 8 values"):
        read_trajectory(bad, "tum")


def test_cli_stereo_against_echosounder_against_truth(world, tmp_path, capsys):
    report = tmp_path / "sonar.html"
    argv = ["eval", "sonar", str(world["session"]), "--json", "--report", str(report),
            "--no-truth", "--every", "2"]  # fmt: skip
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] >= N - 12
    assert out["median_abs_diff_m"] < STEREO_MEDIAN_M
    assert abs(out["bias_m"]) < STEREO_MEDIAN_M and out["spread_m"] < 2 * STEREO_MEDIAN_M
    assert out["datasheet"]["resolution_fraction_of_range"] == 0.005
    assert "ground truth" in out["inputs"]["poses"] and "computed" in out["inputs"]["depth"]
    page = report.read_text()
    assert "Echosounder against stereo" in page and "data:image/png;base64," in page
    # the exact depth maps of gt/ through the raw camera model: the truth itself
    assert main(["eval", "sonar", str(world["session"]), "--depth", str(world["gt"] / "depth"),
                 "--depth-frame", "raw"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "stereo vs echosounder" in text and "Ping2: resolution 0.5 % of range" in text


def test_session_without_an_echosounder_is_a_one_line_error(tmp_path, capsys):
    path = tmp_path / "dry.mcap"
    img = np.zeros((H, W, 3), np.uint8)
    with SessionWriter(path, rig_yaml=rig_to_yaml(_rig())) as w:
        w.write_stereo(0, img, img)
    assert main(["eval", "sonar", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds no echosounder samples" in err[0]


def test_rig_without_a_sonar_mount_is_named(world, tmp_path, capsys):
    rig = _rig()
    bare = tmp_path / "bare.yaml"
    bare.write_text(
        rig_to_yaml(StereoRig(left=rig.left, right=rig.right, T_left_right=rig.T_left_right))
    )
    path = tmp_path / "copy.mcap"  # no dive_gt/ next to it, so no sim.json either
    path.write_bytes(world["session"].read_bytes())
    assert main(["eval", "sonar", str(path), "--rig", str(bare)]) == 2
    assert "no sonar: block" in capsys.readouterr().err
