"""Benchmark: structure from motion (sea3d.sfm on pycolmap) on real and simulated data.

Sections (all by default; pick with --only):

- ``ports``: the residual of the virtual pinhole for the paper's dome, decentred domes and a
  flat port: OpenCV-distortion fits at the camera centre and at the rays' closest point, and
  the exact remap at the closest point (sea3d.rectify.virtual_pinhole_maps).
- ``sift``: 20 field frames with the default SIFT (first octave -1) and the ``--fast`` preset.
- ``field``: the real 100-frame field sequence ``underwater/sea3d_field_left`` (1920x1080,
  monocular, self-calibrated): registered frames, mean reprojection error, points, wall and CPU
  time per stage; beside it COLMAP's stock pipeline through pycolmap on the same images in the
  same process (``extract_features``, ``match_sequential``, ``incremental_mapping`` with
  COLMAP's default options and the same overlap), unless ``--no-reference``.
- ``stereo``: simulated stereo sequences (orbit, lawnmower) of the lake scene through the
  paper's domes: the scale error of ``--camera stereo`` (Sim(3) scale against the ground truth),
  the metric ATE (SE(3)-aligned, no scale), the point error (distance of the model's points to
  the true scene surface after that alignment), and the same for monocular SfM scaled by the
  IMU (sea3d.sfm.imu_scale), plus a hand-held pass (the orbit's locked heading is degenerate for
  the IMU: see docs/sfm.md).
- ``refraction``: with and without the refraction correction on orbits through the paper's
  dome, a dome 10 mm off centre and a flat port: no correction (the in-air pinhole), the virtual
  pinhole at the rays' closest point, and that plus refractive bundle adjustment.

Rendered sequences are cached in ``--cache`` (default ``benchmarks/.cache``). Trajectory errors
use ``sea3d.eval.trajectory.umeyama`` (Sim(3) for the scale, SE(3) for the ATE).

    python benchmarks/bench_sfm.py [--only ports|sift|field|stereo|imu|refraction] [--size 640x360]
        [--frames 40] [--refraction-frames 20] [--no-reference]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.eval.trajectory import umeyama
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.refraction.presets import paper_rig
from sea3d.sfm import SfmConfig, SfmFrame, run_sfm

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("SEA3D_TEST_DATA", str(ROOT / ".." / "shared" / "data")))


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime


def _load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.1f} {b:.1f} {c:.1f} on {os.cpu_count() or 1} cores"


# ------------------------------------------------------------------------------ field data
def bench_field(reference: bool, overlap: int) -> None:
    import cv2

    folder = DATA / "underwater" / "sea3d_field_left"
    paths = sorted(folder.glob("*.jpg"))
    if not paths:
        print(f"field: {folder} not found (set SEA3D_TEST_DATA); skipped")
        return

    def read(p: Path) -> np.ndarray:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        return np.ascontiguousarray(img[:, :, ::-1])

    frames = [SfmFrame(name=p.stem, t_s=float(i), left=(lambda p=p: read(p)), source=str(p))
              for i, p in enumerate(paths)]
    print(f"field: {len(paths)} frames of {folder.name} (1920x1080), {_load()}")
    cfg = SfmConfig(sequential_overlap=overlap)
    c0, w0 = _cpu_s(), time.perf_counter()
    res = run_sfm(frames, cfg)
    wall, cpu = time.perf_counter() - w0, _cpu_s() - c0
    t = res.timings_s
    print(f"  sea3d : {res.registered}/{res.frames} registered, {len(res.points_world)} points, "
          f"mean reprojection error {res.mean_reprojection_error_px:.3f} px, "
          f"{wall:.1f} s wall, {cpu:.1f} s CPU")
    print("          stages: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()))
    print(f"          config: max_image_px {cfg.max_image_px}, max_features {cfg.max_features}, "
          f"first_octave {cfg.sift_first_octave}, peak_threshold {cfg.sift_peak_threshold}, "
          f"overlap {cfg.sequential_overlap}")
    print(f"          after: {_load()}")
    if not reference:
        return
    import shutil
    import tempfile

    import pycolmap

    wd = Path(tempfile.mkdtemp(prefix="bench_colmap_"))
    try:
        pycolmap.logging.minloglevel = 2
        c0, w0 = _cpu_s(), time.perf_counter()
        eo = pycolmap.FeatureExtractionOptions()
        eo.max_image_size = cfg.max_image_px
        pycolmap.extract_features(wd / "db.db", folder, camera_mode=pycolmap.CameraMode.SINGLE,
                                  extraction_options=eo, device=pycolmap.Device.cpu)
        t1 = time.perf_counter()
        po = pycolmap.SequentialPairingOptions()
        po.overlap = overlap
        pycolmap.match_sequential(wd / "db.db", pairing_options=po, device=pycolmap.Device.cpu)
        t2 = time.perf_counter()
        opts = pycolmap.IncrementalPipelineOptions()
        recs = pycolmap.incremental_mapping(wd / "db.db", folder, wd, opts)
        t3 = time.perf_counter()
        cpu_ref = _cpu_s() - c0
        rec = max(recs.values(), key=lambda r: r.num_reg_frames()) if recs else None
        n_reg = rec.num_reg_frames() if rec else 0
        print(f"  COLMAP: {n_reg}/{len(paths)} registered, "
              f"{rec.num_points3D() if rec else 0} points, mean reprojection error "
              f"{rec.compute_mean_reprojection_error() if rec else float('nan'):.3f} px, "
              f"{t3 - w0:.1f} s wall, {cpu_ref:.1f} s CPU (stock options: first_octave -1, "
              f"8192 features)")
        print(f"          stages: extract_s {t1 - w0:.1f} s, match_s {t2 - t1:.1f} s, "
              f"map_s {t3 - t2:.1f} s")
        print(f"  ratio sea3d/COLMAP: wall {wall / (t3 - w0):.2f}, CPU {cpu / cpu_ref:.2f}")
    finally:
        shutil.rmtree(wd, ignore_errors=True)


def bench_sift(start: int = 40, count: int = 20) -> None:
    """The default SIFT (first octave -1) against the fast preset on a stretch of field frames."""
    import cv2

    folder = DATA / "underwater" / "sea3d_field_left"
    paths = sorted(folder.glob("*.jpg"))[start:start + count]
    if not paths:
        print(f"sift: {folder} not found (set SEA3D_TEST_DATA); skipped")
        return
    frames = [SfmFrame(name=p.stem, t_s=float(i),
                       left=(lambda p=p: np.ascontiguousarray(cv2.imread(str(p))[:, :, ::-1])),
                       source=str(p)) for i, p in enumerate(paths)]
    print(f"sift: field frames {start}-{start + count - 1}, default against --fast, {_load()}")
    for label, cfg in (("default (first_octave -1)", SfmConfig()),
                       ("fast (first_octave 0, peak 0.001)", SfmConfig.fast())):
        res = run_sfm(frames, cfg)
        t = res.timings_s
        print(f"  {label:34s} {res.registered}/{res.frames} registered, "
              f"{len(res.points_world)} points, {res.mean_reprojection_error_px:.3f} px; CPU s: "
              f"extract {t['extract_cpu_s']:.1f}, match {t['match_cpu_s']:.1f}, map "
              f"{t['map_cpu_s']:.1f}")


# ------------------------------------------------------------------------------ simulation
class _Sink:
    def __init__(self) -> None:
        self.left: list[np.ndarray] = []
        self.right: list[np.ndarray] = []
        self.t: list[int] = []
        self.imu: list[tuple[float, ...]] = []

    def write_stereo(self, t_ns: int, left: np.ndarray, right: np.ndarray) -> None:
        self.t.append(t_ns)
        self.left.append(left)
        self.right.append(right)

    def write_imu(self, t_ns: int, accel: Any, gyro: Any) -> None:
        self.imu.append((t_ns, *np.asarray(accel), *np.asarray(gyro)))

    def write_sonar(self, *args: Any, **kwargs: Any) -> None:
        pass


def simulate(cache: Path, rig: StereoRig, tag: str, trajectory: str, frames: int, fps: float,
             size: tuple[int, int]) -> dict[str, np.ndarray]:
    from sea3d.sim import SurveyConfig, builtin_scene, simulate_survey
    from sea3d.sim.motion import Mount

    path = cache / f"{tag}_{trajectory}_{size[0]}x{size[1]}_{frames}at{fps:g}.npz"
    if path.is_file():
        return dict(np.load(path))
    cache.mkdir(parents=True, exist_ok=True)
    sink = _Sink()
    cfg = SurveyConfig(frames=frames, fps=fps, trajectory=trajectory, water="coastal")
    t0 = time.perf_counter()
    res = simulate_survey(builtin_scene("lake"), rig, cfg, sink)
    mount = Mount.default(baseline_m=rig.baseline_m, camera_tilt_deg=cfg.tilt_deg())
    data = {"left": np.stack(sink.left), "right": np.stack(sink.right),
            "t_ns": np.array(sink.t), "T_world_left": res.T_world_left,
            "imu": np.array(sink.imu), "T_body_left": mount.T_body_left}
    np.savez_compressed(path, **data)
    print(f"  (rendered {tag} {trajectory}: {frames} frames at {size[0]}x{size[1]} in "
          f"{time.perf_counter() - t0:.0f} s)")
    return data


def _frames(data: dict[str, np.ndarray]) -> list[SfmFrame]:
    return [SfmFrame(name=str(int(t)), t_s=int(t) * 1e-9, left=data["left"][k],
                     right=data["right"][k], source=f"sim t_ns={int(t)}")
            for k, t in enumerate(data["t_ns"])]


_SURFACE: Any = None


def _point_error_m(points_world: np.ndarray) -> float:
    """Median distance of points to the lake scene's true surface."""
    import open3d as o3d

    from sea3d.sim import builtin_scene

    global _SURFACE
    if _SURFACE is None:
        mesh = o3d.t.geometry.TriangleMesh.from_legacy(builtin_scene("lake").combined_mesh())
        _SURFACE = o3d.t.geometry.RaycastingScene()
        _SURFACE.add_triangles(mesh)
    d = _SURFACE.compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()
    return float(np.median(d))


def _errors(res: Any, data: dict[str, np.ndarray], scale: float = 1.0) -> dict[str, float]:
    idx = [int(np.nonzero(data["t_ns"] == int(n))[0][0]) for n in res.names]
    est = res.T_world_left[:, :3, 3] * scale
    gt = data["T_world_left"][idx][:, :3, 3]
    _, _, s = umeyama(est, gt, with_scale=True)
    R, t, _ = umeyama(est, gt, with_scale=False)
    ate = float(np.sqrt(np.mean(np.sum((est @ R.T + t - gt) ** 2, axis=1))))
    pts = (res.points_world * scale) @ R.T + t
    # rotation error: mean angle between estimated and true orientations after alignment
    rot = []
    for k, i in enumerate(idx):
        Rk = R @ res.T_world_left[k, :3, :3]
        dR = Rk.T @ data["T_world_left"][i][:3, :3]
        rot.append(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
    return {"scale_err_pct": 100 * (1 / s - 1), "ate_m": ate,
            "rot_deg": float(np.mean(rot)), "point_err_m": _point_error_m(pts),
            "registered": float(len(idx))}


def _row(label: str, res: Any, err: dict[str, float], extra: str = "") -> None:
    print(f"  {label:34s} {int(err['registered']):3d}/{res.frames:<3d} "
          f"scale {err['scale_err_pct']:+7.3f} %  ATE {1e3 * err['ate_m']:7.2f} mm  "
          f"rot {err['rot_deg']:.3f} deg  points {1e3 * err['point_err_m']:6.2f} mm  "
          f"reproj {res.mean_reprojection_error_px:.3f} px  "
          f"{res.timings_s.get('total_s', 0):.0f} s{extra}")


def _imu_row(label: str, res: Any, data: dict[str, np.ndarray]) -> None:
    """The monocular model scaled by the IMU: slerped SfM rotations, and the rotations smoothed
    with the gyroscope (``gyro_radps=``, what ``sea3d sfm --imu-scale`` does)."""
    from sea3d.sfm.imu_scale import estimate_imu_scale

    imu = data["imu"]
    for how, gyro in (("", None), (" + gyro", imu[:, 4:7])):
        est = estimate_imu_scale(res.t_s, res.T_world_left, imu[:, 0] * 1e-9, imu[:, 1:4],
                                 invert_T(data["T_body_left"]), gyro_radps=gyro)
        if est.status == "failed":
            print(f"  {label + how:34s} IMU scale failed: {est.message}")
            continue
        err = _errors(res, data, scale=est.scale)
        _row(label + how, res, err, f"  [IMU {est.status}: +-{100 * est.relative_std:.2f} % "
                                    f"1 sigma, chi2/dof {est.chi2_per_dof:.2f}]")


def bench_imu(cache: Path, size: tuple[int, int], frames: int, fps: float) -> None:
    """Only the monocular runs of the stereo section, scaled by the IMU."""
    rig = paper_rig("dome", size_px=size)
    print(f"imu: monocular SfM scaled by the IMU, paper dome rig at {size[0]}x{size[1]}, "
          f"{frames} frames at {fps:g} fps, {_load()}")
    for traj in ("lawnmower", "handheld"):
        data = simulate(cache, rig, "paper_dome", traj, frames, fps, size)
        mono = run_sfm(_frames(data), SfmConfig(camera="left"), rig=rig)
        _imu_row(f"{traj} monocular x IMU scale", mono, data)


def bench_stereo(cache: Path, size: tuple[int, int], frames: int, fps: float) -> None:
    rig = paper_rig("dome", size_px=size)
    print(f"stereo: lake scene, coastal water, paper dome rig at {size[0]}x{size[1]}, {frames} "
          f"frames at {fps:g} fps, {_load()}")
    cfg = SfmConfig(camera="stereo")
    for traj in ("orbit", "lawnmower", "handheld"):
        data = simulate(cache, rig, "paper_dome", traj, frames, fps, size)
        if traj != "handheld":
            res = run_sfm(_frames(data), cfg, rig=rig)
            _row(f"{traj} stereo (virtual pinhole)", res, _errors(res, data))
        mono = run_sfm(_frames(data), replace(cfg, camera="left"), rig=rig)
        _imu_row(f"{traj} monocular x IMU scale", mono, data)


def bench_refraction(cache: Path, size: tuple[int, int], frames: int, fps: float,
                     use: int) -> None:
    """In-air pinhole, virtual pinhole, and + refractive BA on the first ``use`` frames of each
    port's orbit (refractive BA only where ``--refractive-ba auto`` would run it)."""
    use = min(use, frames)
    print(f"refraction: orbit through three ports at {size[0]}x{size[1]}, stereo, the first "
          f"{use} of {frames} frames at {fps:g} fps, {_load()}")
    cases = [
        ("paper dome", paper_rig("dome", size_px=size)),
        ("dome 10 mm off axis", paper_rig("dome", size_px=size,
                                          dome_center_left_m=(0.003, 0.0, 0.010),
                                          dome_center_right_m=(0.003, 0.0, 0.010))),
        ("flat port", paper_rig("flat", size_px=size)),
    ]
    for tag, rig in cases:
        data = simulate(cache, rig, tag.replace(" ", "_"), "orbit", frames, fps, size)
        data = {k: (v[:use] if k in ("left", "right", "t_ns", "T_world_left") else v)
                for k, v in data.items()}
        air = StereoRig(left=rig.left.pinhole, right=rig.right.pinhole,  # type: ignore[attr-defined]
                        T_left_right=rig.T_left_right)
        cfg = SfmConfig(camera="stereo", refractive_ba="off")
        res = run_sfm(_frames(data), cfg, rig=air)
        _row(f"{tag}: in-air pinhole", res, _errors(res, data))
        res = run_sfm(_frames(data), cfg, rig=rig)
        rep = res.virtual["left"]
        _row(f"{tag}: virtual pinhole", res, _errors(res, data),
             f"  [residual RMS {rep.rms_px:.3f} max {rep.max_px:.3f} px]")
        if rep.max_px <= 0.25:
            print(f"  {tag + ': + refractive BA':34s} not run: residual max {rep.max_px:.3f} "
                  "px <= 0.25 px (what --refractive-ba auto decides)")
            continue
        res = run_sfm(_frames(data), replace(cfg, refractive_ba="on"), rig=rig)
        ba = res.refractive_ba
        _row(f"{tag}: + refractive BA", res, _errors(res, data),
             f"  [rays {ba.rms_before_px:.3f} -> {ba.rms_after_px:.3f} px]" if ba else "")


def bench_ports(size: tuple[int, int] = (960, 540), depth_range_m: tuple[float, float] = (
        0.5, 5.0)) -> None:
    """Residual of the virtual pinhole per port camera (the table of docs/sfm.md)."""
    from sea3d.rectify import fit_virtual_pinhole, virtual_pinhole_maps

    print(f"ports: virtual-pinhole residual at {size[0]}x{size[1]} over {depth_range_m[0]}-"
          f"{depth_range_m[1]} m")
    cases = [
        ("paper dome", paper_rig("dome", size_px=size).left),
        ("dome 10 mm behind centre, on axis",
         paper_rig("dome", size_px=size, dome_center_left_m=(0.0, 0.0, 0.010)).left),
        ("dome (3, 0, 10) mm off centre",
         paper_rig("dome", size_px=size, dome_center_left_m=(0.003, 0.0, 0.010)).left),
        ("flat port 10 mm + 10 mm acrylic", paper_rig("flat", size_px=size).left),
    ]
    for name, cam in cases:
        _, at_cam = fit_virtual_pinhole(cam, depth_range_m)
        _, at_rays = fit_virtual_pinhole(cam, depth_range_m, center="rays")
        vm = virtual_pinhole_maps(cam, depth_range_m)
        c = ", ".join(f"{1e3 * v:.2f}" for v in vm.center_m)
        print(f"  {name:34s} OpenCV fit at camera centre RMS {at_cam.rms_px:.3f} px, at the "
              f"closest point {at_rays.rms_px:.3f} px; exact remap at ({c}) mm: RMS "
              f"{vm.report.rms_px:.4f} max {vm.report.max_px:.4f} px")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only",
                        choices=["ports", "sift", "field", "stereo", "imu", "refraction"])
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--fps", type=float, default=2.0)
    parser.add_argument("--refraction-frames", type=int, default=20,
                        help="frames of each orbit used by the refraction section")
    parser.add_argument("--overlap", type=int, default=8)
    parser.add_argument("--no-reference", action="store_true")
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / ".cache")
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    if args.only in (None, "ports"):
        bench_ports()
    if args.only in (None, "sift"):
        bench_sift()
    if args.only in (None, "field"):
        bench_field(not args.no_reference, args.overlap)
    if args.only in (None, "stereo"):
        bench_stereo(args.cache, (w, h), args.frames, args.fps)
    if args.only == "imu":
        bench_imu(args.cache, (w, h), args.frames, args.fps)
    if args.only in (None, "refraction"):
        bench_refraction(args.cache, (w, h), args.frames, args.fps, args.refraction_frames)


if __name__ == "__main__":
    main()
