"""Structure from motion on pycolmap: SIFT, sequential or exhaustive matching, incremental
mapping, bundle adjustment, with our cameras and rigs.

- Without a rig the intrinsics are self-calibrated (one shared camera, COLMAP refines it).
- With a rig the rig's intrinsics are used and held fixed. Pinhole cameras go to COLMAP as
  they are (``PINHOLE``, ``OPENCV`` or ``FULL_OPENCV``); port cameras (dome, flat) are remapped
  into an ideal virtual pinhole placed where their water rays pass closest
  (:func:`sea3d.rectify.virtual_pinhole_maps`), whose residual over the working range is
  reported; flat ports and large dome offsets can then be refined by the refractive bundle
  adjustment (:mod:`sea3d.sfm.refractive`) over the true per-observation rays.
- ``camera="stereo"`` puts both cameras of each frame into one COLMAP rig (the left virtual
  camera is the reference sensor) with the calibrated extrinsics held fixed, so the model comes
  out metric.
- Pose priors (positions of the left camera over time, e.g. from odometry or ground truth) go to
  COLMAP as position priors; the model is then in the priors' (metric) world.

Images are loaded one at a time, prepared (remapped for port cameras) and written as PNG into
``workdir`` (a temporary folder by default) with COLMAP's database; COLMAP's own extractor then
reads them with its threads (pycolmap's in-memory extractor holds the GIL, and worker processes
would re-import the caller's main script). Keep ``import cv2`` (or any ``sea3d`` module) before
``import pycolmap``: the other order makes OpenCV's PNG writer crash in pycolmap's zlib.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2  # noqa: F401 - loaded before pycolmap (see above), not called here
import numpy as np

from sea3d._typing import F64
from sea3d.errors import SfmError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.rectify.virtual import VirtualPinholeMaps, virtual_pinhole_maps
from sea3d.sfm.types import PosePriors, SfmConfig, SfmFrame, SfmResult

__all__ = ["run_sfm"]

log = logging.getLogger(__name__)
Progress = Callable[[str, int, int], None]

# ------------------------------------------------------------------------------ features
def _extraction_options(config: SfmConfig, threads: int) -> Any:
    import pycolmap

    eo = pycolmap.FeatureExtractionOptions()
    eo.max_image_size = int(config.max_image_px)
    eo.num_threads = int(threads)
    eo.sift.max_num_features = int(config.max_features)
    eo.sift.first_octave = int(config.sift_first_octave)
    eo.sift.peak_threshold = float(config.sift_peak_threshold)
    return eo


# ------------------------------------------------------------------------------ sensors
@dataclass(eq=False)
class _Sensor:
    """One camera as COLMAP sees it."""

    name: str
    camera_id: int
    width: int
    height: int
    colmap_model: str
    params: list[float]
    fixed: bool
    model: CameraModel | None = None
    maps: VirtualPinholeMaps | None = None

    @property
    def T_cam_virtual(self) -> F64:
        return self.maps.T_camera_virtual if self.maps is not None else np.eye(4)

    def colmap_camera(self) -> Any:
        import pycolmap

        cam = pycolmap.Camera(camera_id=self.camera_id, model=self.colmap_model,
                              width=self.width, height=self.height, params=self.params)
        cam.has_prior_focal_length = self.fixed
        return cam

    def prepare(self, image: np.ndarray) -> np.ndarray:
        return self.maps.remap(image) if self.maps is not None else image


def _sensor_from_camera(name: str, camera_id: int, cam: CameraModel,
                        config: SfmConfig) -> _Sensor:
    # The lens if ``cam`` is a pinhole or a port that reduces to it exactly.
    pin = None if cam.is_refractive else cam.lens
    w, h = cam.width, cam.height
    if pin is not None:
        base = [pin.fx, pin.fy, pin.cx + 0.5, pin.cy + 0.5]
        d = np.asarray(pin.dist, dtype=np.float64)
        if d.size == 0 or not np.any(d):
            return _Sensor(name, camera_id, w, h, "PINHOLE", base, True, cam)
        if d.size == 4:
            return _Sensor(name, camera_id, w, h, "OPENCV", base + d.tolist(), True, cam)
        if d.size in (5, 8):
            full = np.zeros(8)
            full[: d.size] = d  # k1 k2 p1 p2 k3 k4 k5 k6: OpenCV's and COLMAP's order agree
            return _Sensor(name, camera_id, w, h, "FULL_OPENCV", base + full.tolist(), True, cam)
    # Port cameras, and distortion COLMAP has no model for: an exact remap to an ideal pinhole.
    maps = virtual_pinhole_maps(cam, config.depth_range_m, center="rays")
    v = maps.virtual
    log.info("%s camera: remapped to a virtual pinhole at %s mm; parallax residual (how far a "
             "point off the nominal %.2f m depth lands from where that pinhole puts it) RMS "
             "%.4f px, max %.4f px over %.2f-%.2f m", name,
             np.round(maps.center_m * 1e3, 3).tolist(), maps.nominal_depth_m,
             maps.report.rms_px, maps.report.max_px, *config.depth_range_m)
    return _Sensor(name, camera_id, w, h, "PINHOLE", [v.fx, v.fy, v.cx + 0.5, v.cy + 0.5], True,
                   cam, maps)


def _self_calibrated(name: str, camera_id: int, width: int, height: int,
                     config: SfmConfig) -> _Sensor:
    f = 1.2 * max(width, height)
    cx, cy = width / 2.0, height / 2.0
    params = {
        "SIMPLE_PINHOLE": [f, cx, cy],
        "PINHOLE": [f, f, cx, cy],
        "SIMPLE_RADIAL": [f, cx, cy, 0.0],
        "RADIAL": [f, cx, cy, 0.0, 0.0],
        "OPENCV": [f, f, cx, cy, 0.0, 0.0, 0.0, 0.0],
    }[config.self_calibration_model]
    return _Sensor(name, camera_id, width, height, config.self_calibration_model, params, False)


# ------------------------------------------------------------------------------ images
def _load(image: Any, source: str) -> np.ndarray:
    arr = image() if callable(image) else image
    arr = np.asarray(arr)
    if arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., :3]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3) or arr.size == 0:
        raise SfmError(f"{source}: expected an (H, W) or (H, W, 3) image, got shape {arr.shape}")
    if arr.dtype != np.uint8:
        if arr.dtype == np.uint16:
            arr = (arr >> 8).astype(np.uint8)
        elif np.issubdtype(arr.dtype, np.floating):
            arr = np.clip(arr * 255.0, 0, 255).astype(np.uint8)
        else:
            raise SfmError(f"{source}: unsupported image dtype {arr.dtype}")
    return arr


@contextmanager
def _quiet_colmap() -> Iterator[None]:
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _rigid(T: F64) -> Any:
    import pycolmap

    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.ascontiguousarray(T[:3, :3])),
                            np.ascontiguousarray(T[:3, 3]))


def _T_of(rigid: Any) -> F64:
    T = np.eye(4)
    T[:3, :4] = np.asarray(rigid.matrix(), dtype=np.float64)
    return T


def _prior_poses(priors: PosePriors, t_s: F64, max_gap_s: float) -> F64:
    """Left-camera poses at ``t_s``: positions interpolated linearly between samples,
    rotations of the nearest sample; NaN where the nearest sample is more than ``max_gap_s``
    away."""
    tp = np.asarray(priors.t_s, dtype=np.float64)
    T = np.asarray(priors.T_world_left, dtype=np.float64)
    out = np.full((len(t_s), 4, 4), np.nan)
    if len(tp) == 0:
        return out
    nearest = np.clip(np.searchsorted(tp, t_s), 0, len(tp) - 1)
    prev = np.clip(nearest - 1, 0, len(tp) - 1)
    closer = np.abs(tp[prev] - t_s) < np.abs(tp[nearest] - t_s)
    nearest = np.where(closer, prev, nearest)
    ok = np.abs(tp[nearest] - t_s) <= max_gap_s
    out[ok] = T[nearest[ok]]
    for k in range(3):
        out[ok, k, 3] = np.interp(t_s[ok], tp, T[:, k, 3])
    return out


# ------------------------------------------------------------------------------ the stage
def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (the SIFT workers)."""
    import resource

    me = resource.getrusage(resource.RUSAGE_SELF)
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime


def _check_frames(frames: Sequence[SfmFrame], config: SfmConfig, rig: StereoRig | None) -> None:
    if len(frames) < config.min_frames:
        where = frames[0].source if frames else "the input"
        raise SfmError(
            f"{where}: {len(frames)} frame(s) given; structure from motion needs at least "
            f"{config.min_frames}"
        )
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise SfmError("frame names must be unique")
    if config.camera in ("right", "stereo"):
        missing = [f for f in frames if f.right is None]
        if missing:
            raise SfmError(
                f"{missing[0].source or missing[0].name}: no right image; camera "
                f"{config.camera} needs a right camera in every frame ({len(missing)} of "
                f"{len(frames)} frames have none)"
            )
    if config.camera == "stereo" and rig is None:
        raise SfmError("SfmConfig.camera='stereo' needs the rig (its extrinsics fix the "
                       "scale); give run_sfm a rig")


# Image pairs COLMAP has matched so far (it writes one row per pair tried, matched or not).
_PAIRS_DONE = "SELECT COUNT(*) FROM matches"


def _sequential_pairs(n: int, overlap: int) -> int:
    """Pairs COLMAP's sequential matcher tries: ``overlap`` next frames plus ``i + 2**k``."""
    pairs = set()
    for i in range(n):
        for k in range(1, overlap + 1):
            if i + k < n:
                pairs.add((i, i + k))
        for k in range(overlap):
            if i + 2**k < n:
                pairs.add((i, i + 2**k))
    return len(pairs)


def _count_rows(db_path: Path, count_sql: str) -> int | None:
    """``count_sql``'s count in COLMAP's database while COLMAP writes it, or None when it
    cannot be read at this moment.

    pycolmap links its own copy of SQLite and keeps the database in WAL mode, its ``-shm``
    file (the WAL index) mapped into memory. Python's ``sqlite3`` is another copy of the
    library in the same process: POSIX locks do not tell it that COLMAP's copy holds the file,
    so a connection of its own took itself for the first one and truncated the ``-shm`` file
    to reset it, under COLMAP's mapping (COLMAP then died of SIGBUS if it touched the file
    before it grew again). ``readonly_shm=1`` opens the ``-shm`` file read-only, so this
    connection never resets it: it reads the WAL itself, and sees what COLMAP wrote.
    """
    import contextlib
    import sqlite3

    uri = f"file:{db_path}?mode=ro&readonly_shm=1"
    try:
        with contextlib.closing(sqlite3.connect(uri, uri=True, timeout=0.1)) as con:
            return int(con.execute(count_sql).fetchone()[0])
    except sqlite3.Error:
        return None  # COLMAP holds a write lock for a moment: try at the next poll


def _watched(call: Callable[[], object], db_path: Path, count_sql: str, stage: str, total: int,
             progress: Progress | None, poll_s: float = 0.5) -> None:
    """Run a pycolmap stage with no callback of its own, reporting progress from its database.

    pycolmap releases the GIL while it works, so this thread polls the row count of
    ``count_sql`` (images with keypoints, pairs matched) while a worker thread runs ``call``;
    its exceptions are raised here.
    """
    if progress is None:
        call()
        return
    import threading

    failure: list[BaseException] = []

    def work() -> None:
        try:
            call()
        except BaseException as err:  # re-raised in the calling thread below
            failure.append(err)

    worker = threading.Thread(target=work, name=f"pycolmap-{stage}", daemon=True)
    worker.start()
    progress(stage, 0, total)
    while worker.is_alive():
        worker.join(poll_s)
        done = _count_rows(db_path, count_sql)
        if done is not None:
            progress(stage, min(done, total), total)
    if failure:
        raise failure[0]
    progress(stage, total, total)


def run_sfm(
    frames: Sequence[SfmFrame],
    config: SfmConfig,
    *,
    rig: StereoRig | None = None,
    pose_priors: PosePriors | None = None,
    workdir: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
    image_sink: Callable[[str, np.ndarray], None] | None = None,
) -> SfmResult:
    """Structure from motion of a sequence of frames.

    Args:
        frames: the input, in time order (:class:`SfmFrame`; images are loaded one at a time).
        config: :class:`SfmConfig`.
        rig: the stereo rig (intrinsics used and held fixed, extrinsics for ``stereo``); None
            to self-calibrate a monocular camera.
        pose_priors: left-camera positions over time (metric); None for none.
        workdir: scratch folder for COLMAP's database (a temporary one, removed afterwards,
            when None).
        progress: called as ``progress(stage, done, total)`` (``prepare``, ``extract``,
            ``match``: pairs tried, ``map``).
        image_sink: called as ``image_sink(name, image)`` with every image as COLMAP sees it
            (remapped into the virtual pinhole for port cameras) and its model name
            (``left/<frame name>.png``), e.g. to write them next to the model.

    Returns:
        :class:`SfmResult`. A run that finds no model (no overlap, too few matches) returns
        ``status="failed"`` with a message, it does not raise.

    Raises:
        SfmError: too few frames, images of mixed or wrong sizes, a missing right image or
            rig for ``camera="stereo"``, no right image for ``camera="right"``.
    """
    import pycolmap

    _check_frames(frames, config, rig)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    threads = config.num_threads if config.num_threads > 0 else (os.cpu_count() or 1)
    own_workdir = workdir is None
    wd = Path(tempfile.mkdtemp(prefix="sea3d_sfm_")) if own_workdir else Path(workdir)  # type: ignore[arg-type]
    wd.mkdir(parents=True, exist_ok=True)
    db_path = wd / "database.db"
    if db_path.exists():
        db_path.unlink()
    try:
        with _quiet_colmap():
            return _run(frames, config, rig, pose_priors, wd, db_path, threads, timings,
                        t_start, progress, image_sink, pycolmap)
    finally:
        if own_workdir:
            shutil.rmtree(wd, ignore_errors=True)


def _sensors(frames: Sequence[SfmFrame], config: SfmConfig, rig: StereoRig | None,
             first: np.ndarray) -> list[_Sensor]:
    wanted = ["left", "right"] if config.camera == "stereo" else [config.camera]
    ids = {"left": 1, "right": 2}
    if rig is None:
        h, w = first.shape[:2]
        return [_self_calibrated(wanted[0], ids[wanted[0]], w, h, config)]
    return [_sensor_from_camera(n, ids[n], rig.left if n == "left" else rig.right, config)
            for n in wanted]


def _write_rig(db: Any, sensors: list[_Sensor], rig: StereoRig | None,
               pycolmap: Any) -> dict[str, Any]:
    """Write the cameras and the one COLMAP rig; return each sensor's ``sensor_t`` by name."""
    for s in sensors:
        db.write_camera(s.colmap_camera(), use_camera_id=True)
    cam_sensor = {s.name: pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=s.camera_id)
                  for s in sensors}
    prig = pycolmap.Rig(rig_id=1)
    prig.add_ref_sensor(cam_sensor[sensors[0].name])
    if len(sensors) == 2 and rig is not None:
        # COLMAP's sensor_from_rig of the right virtual camera: the rig frame is the left
        # virtual camera.  T_vright_vleft = T_vright_right T_right_left T_left_vleft.
        T = invert_T(sensors[1].T_cam_virtual) @ rig.T_right_left @ sensors[0].T_cam_virtual
        prig.add_sensor(cam_sensor["right"], _rigid(T))
    db.write_rig(prig, use_rig_id=True)
    return cam_sensor


def _write_images(
    db: Any,
    frames: Sequence[SfmFrame],
    sensors: list[_Sensor],
    first_img: np.ndarray,
    first_src: str,
    image_dir: Path,
    progress: Progress | None,
    image_sink: Callable[[str, np.ndarray], None] | None,
    pycolmap: Any,
) -> tuple[list[list[int]], list[str]]:
    """Prepare every frame's images, write them as scratch PNGs and into the database.

    Returns ``(image_ids, names)``: each frame's image ids (one per sensor) and every image's
    name relative to ``image_dir``.

    Raises:
        SfmError: an image of another size than the first (or the rig's), or a PNG that cannot
            be written.
    """
    from sea3d.io.image_files import image_writer

    scratch = image_writer(image_dir, lambda msg: SfmError(f"scratch image: {msg}"),
                           png_compression=1)
    n_images = len(frames) * len(sensors)
    image_ids: list[list[int]] = []
    names: list[str] = []
    iid = 0
    for k, fr in enumerate(frames):
        ids_k = []
        for s in sensors:
            iid += 1
            src = fr.source or fr.name
            raw = first_img if (k == 0 and s is sensors[0]) else _load(
                fr.left if s.name == "left" else fr.right, f"{src} ({s.name})")
            if raw.shape[:2] != (s.height, s.width):
                what = "the rig" if s.fixed else f"the first image ({first_src})"
                raise SfmError(
                    f"{src}: {s.name} image is {raw.shape[1]}x{raw.shape[0]} but {what} "
                    f"is {s.width}x{s.height}; all images must have one size"
                )
            img = s.prepare(raw)
            name = f"{s.name}/{fr.name}.png"
            if image_sink is not None:
                image_sink(name, img)
            scratch(name, img)
            db.write_image(pycolmap.Image(name=name, camera_id=s.camera_id, image_id=iid),
                           use_image_id=True)
            names.append(name)
            ids_k.append(iid)
            if progress is not None:
                progress("prepare", iid, n_images)
        image_ids.append(ids_k)
    return image_ids, names


def _write_priors(
    db: Any,
    frames: Sequence[SfmFrame],
    priors: PosePriors,
    config: SfmConfig,
    sensors: list[_Sensor],
    rig: StereoRig | None,
    image_ids: list[list[int]],
    cam_sensor: dict[str, Any],
    pycolmap: Any,
) -> int:
    """Write a position prior for every frame that has one; return how many were written
    (fewer than 3 is logged as a warning: the mapper then ignores them)."""
    n_priors = 0
    t_s = np.array([f.t_s for f in frames], dtype=np.float64)
    T_prior = _prior_poses(priors, t_s, config.prior_max_gap_s)
    ref = sensors[0]
    # The prior is on the reference (virtual) camera's centre.
    T_left_vref = ref.T_cam_virtual if ref.name == "left" or rig is None else (
        rig.T_left_right @ ref.T_cam_virtual)
    for k, ids_k in enumerate(image_ids):
        if not np.all(np.isfinite(T_prior[k])):
            continue
        c = (T_prior[k] @ T_left_vref)[:3, 3]
        pp = pycolmap.PosePrior(
            corr_data_id=pycolmap.data_t(sensor_id=cam_sensor[ref.name], id=ids_k[0]),
            position=np.asarray(c, dtype=np.float64).reshape(3, 1),
            position_covariance=np.eye(3) * config.prior_position_std_m**2,
            coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
        )
        db.write_pose_prior(pp)
        n_priors += 1
    if n_priors < 3:
        log.warning("%s: only %d frames have a pose prior within %.2f s; priors ignored",
                    priors.source, n_priors, config.prior_max_gap_s)
    return n_priors


def _match(config: SfmConfig, db_path: Path, names: list[str], threads: int,
           progress: Progress | None, pycolmap: Any) -> None:
    """COLMAP's sequential or exhaustive matcher over the database's images."""
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = threads
    if config.matcher == "sequential":
        po = pycolmap.SequentialPairingOptions()
        po.overlap = int(config.sequential_overlap)
        po.quadratic_overlap = True
        po.loop_detection = False
        _watched(lambda: pycolmap.match_sequential(
            str(db_path), matching_options=mo, pairing_options=po, device=pycolmap.Device.cpu),
            db_path, _PAIRS_DONE, "match",
            _sequential_pairs(len(names), int(config.sequential_overlap)), progress)
    else:
        n = len(names)
        _watched(lambda: pycolmap.match_exhaustive(
            str(db_path), matching_options=mo, device=pycolmap.Device.cpu),
            db_path, _PAIRS_DONE, "match", n * (n - 1) // 2, progress)


def _mapping_options(config: SfmConfig, n_frames: int, rig: StereoRig | None, threads: int,
                     use_priors: bool, pycolmap: Any) -> Any:
    """The incremental mapper's options: seeded, the rig's intrinsics and extrinsics held
    fixed when there is a rig, position priors used when there are enough."""
    opts = pycolmap.IncrementalPipelineOptions()
    opts.extract_colors = False
    opts.num_threads = threads
    opts.random_seed = int(config.seed)
    opts.mapper.random_seed = int(config.seed)
    opts.min_model_size = min(10, max(2, n_frames // 3))
    opts.ba_global_frames_ratio = float(config.ba_global_ratio)
    opts.ba_global_points_ratio = float(config.ba_global_ratio)
    if rig is not None:
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.mapper.abs_pose_refine_focal_length = False
        opts.mapper.abs_pose_refine_extra_params = False
        opts.ba_refine_sensor_from_rig = False
    if use_priors:
        opts.use_prior_position = True
    return opts


def _run(
    frames: Sequence[SfmFrame],
    config: SfmConfig,
    rig: StereoRig | None,
    priors: PosePriors | None,
    wd: Path,
    db_path: Path,
    threads: int,
    timings: dict[str, float],
    t_start: float,
    progress: Progress | None,
    image_sink: Callable[[str, np.ndarray], None] | None,
    pycolmap: Any,
) -> SfmResult:
    t0 = time.perf_counter()
    first_src = frames[0].source or frames[0].name
    first_img = _load(frames[0].right if config.camera == "right" else frames[0].left, first_src)
    sensors = _sensors(frames, config, rig, first_img)
    timings["prepare_s"] = time.perf_counter() - t0

    # ---------------------------------------------------------------- database + images
    t0 = time.perf_counter()
    db = pycolmap.Database.open(str(db_path))
    cam_sensor = _write_rig(db, sensors, rig, pycolmap)
    image_dir = wd / "images"
    image_ids, names = _write_images(db, frames, sensors, first_img, first_src, image_dir,
                                     progress, image_sink, pycolmap)
    for k, ids_k in enumerate(image_ids):
        f = pycolmap.Frame(frame_id=k + 1, rig_id=1)
        for s, i in zip(sensors, ids_k, strict=True):
            f.add_data_id(pycolmap.data_t(sensor_id=cam_sensor[s.name], id=i))
        db.write_frame(f, use_frame_id=True)
    n_priors = 0
    if priors is not None:
        n_priors = _write_priors(db, frames, priors, config, sensors, rig, image_ids,
                                 cam_sensor, pycolmap)
    db.close()
    timings["prepare_s"] += time.perf_counter() - t0
    # COLMAP's own extractor: its reader and SIFT threads run outside the GIL.
    t0, c0 = time.perf_counter(), _cpu_s()
    _watched(lambda: pycolmap.extract_features(
        str(db_path), str(image_dir), image_names=names,
        extraction_options=_extraction_options(config, threads), device=pycolmap.Device.cpu),
        db_path, "SELECT COUNT(*) FROM keypoints", "extract", len(names), progress)
    timings["extract_s"] = time.perf_counter() - t0
    timings["extract_cpu_s"] = _cpu_s() - c0

    # ---------------------------------------------------------------- matching
    t0, c0 = time.perf_counter(), _cpu_s()
    _match(config, db_path, names, threads, progress, pycolmap)
    timings["match_s"] = time.perf_counter() - t0
    timings["match_cpu_s"] = _cpu_s() - c0

    # ---------------------------------------------------------------- mapping
    t0, c0 = time.perf_counter(), _cpu_s()
    use_priors = n_priors >= 3
    opts = _mapping_options(config, len(frames), rig, threads, use_priors, pycolmap)
    models_dir = wd / "models"
    models_dir.mkdir(exist_ok=True)
    registered = 0

    def on_next_image() -> None:
        nonlocal registered
        registered += 1
        if progress is not None:
            progress("map", min(registered, len(frames)), len(frames))

    recs = pycolmap.incremental_mapping(str(db_path), str(wd), str(models_dir), opts,
                                        next_image_callback=on_next_image)
    timings["map_s"] = time.perf_counter() - t0
    timings["map_cpu_s"] = _cpu_s() - c0
    n_img = len(frames) * len(sensors)
    metric = (rig is not None and len(sensors) == 2) or use_priors
    if not recs:
        timings["total_s"] = time.perf_counter() - t_start
        return _failed(frames, n_img, "no model: too few matches between the images (no "
                       "overlap?)", timings, sensors)
    rec = max(recs.values(), key=lambda r: r.num_reg_frames())

    from sea3d.sfm import refractive

    ba_report = None
    ba_wanted = config.refractive_ba == "on" or (
        config.refractive_ba == "auto"
        and any(s.maps is not None and s.maps.report.max_px > config.refractive_ba_threshold_px
                for s in sensors)
    )
    if ba_wanted and rig is not None:
        t0 = time.perf_counter()
        ba_report = refractive.refine(rec, sensors, rig, fix_scale=not metric)
        timings["refractive_ba_s"] = time.perf_counter() - t0
    rec.extract_colors_for_all_images(str(image_dir))
    result = _result(rec, frames, sensors, rig, n_img, len(recs), metric, timings, ba_report)
    timings["total_s"] = time.perf_counter() - t_start
    return result


def _failed(frames: Sequence[SfmFrame], n_img: int, message: str, timings: dict[str, float],
            sensors: list[_Sensor]) -> SfmResult:
    return SfmResult(
        status="failed", message=message, frames=len(frames), images=n_img, names=[],
        t_s=np.zeros(0), T_world_left=np.zeros((0, 4, 4)), registered_images=0,
        points_world=np.zeros((0, 3)), colors_rgb=np.zeros((0, 3), np.uint8),
        point_error_px=np.zeros(0), mean_reprojection_error_px=float("nan"), metric=False,
        models=0, cameras=_camera_info(sensors, None), timings_s=timings,
    )


# The horizontal field of view of a physical lens on a camera COLMAP can model: a long
# telephoto narrows to about 10 degrees, a fisheye (as a pinhole with distortion) widens to
# about 170. A self-calibrated focal length outside is a degenerate model, not a camera.
FOV_RANGE_DEG = (10.0, 170.0)


def implausible_camera(cameras: dict[str, dict[str, Any]]) -> str | None:
    """Why a self-calibrated camera cannot be a real one, or None.

    Args:
        cameras: :attr:`SfmResult.cameras` (model, params, width, height, fixed per sensor).

    Returns:
        A one-line reason when a focal length (not fixed by a rig) gives a horizontal field of
        view outside :data:`FOV_RANGE_DEG`, i.e. outside ``width / (2 tan(fov / 2))``.
    """
    lo, hi = FOV_RANGE_DEG
    for name, cam in cameras.items():
        if cam.get("fixed") or not cam.get("params"):
            continue
        width = float(cam["width"])
        f = float(cam["params"][0])  # f (SIMPLE_*, RADIAL) or fx (PINHOLE, OPENCV...)
        fov = float(np.degrees(2.0 * np.arctan2(width, 2.0 * f))) if f > 0 else 180.0
        if not lo <= fov <= hi:
            f_lo = width / (2.0 * np.tan(np.radians(hi) / 2.0))
            f_hi = width / (2.0 * np.tan(np.radians(lo) / 2.0))
            return (
                f"the self-calibrated {name} camera is implausible: a focal length of {f:,.0f} "
                f"px on a {width:.0f}-px-wide image is a {fov:.1f} deg field of view, outside "
                f"the {lo:g}-{hi:g} deg of a physical lens ({f_lo:,.0f}..{f_hi:,.0f} px); "
                "give a calibrated rig, or more frames with more parallax"
            )
    return None


def _camera_info(sensors: list[_Sensor], rec: Any) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for s in sensors:
        params = list(s.params)
        if rec is not None and s.camera_id in rec.cameras:
            params = [float(p) for p in rec.cameras[s.camera_id].params]
        out[s.name] = {"model": s.colmap_model, "params": params, "width": s.width,
                       "height": s.height, "fixed": s.fixed,
                       "virtual_pinhole": s.maps is not None}
    return out


def _result(rec: Any, frames: Sequence[SfmFrame], sensors: list[_Sensor],
            rig: StereoRig | None, n_img: int, n_models: int, metric: bool,
            timings: dict[str, float],
            ba_report: Any) -> SfmResult:
    ref = sensors[0]
    T_vref_ref = invert_T(ref.T_cam_virtual)
    names, t_s, poses = [], [], []
    for k, fr in enumerate(frames):
        fid = k + 1
        if fid not in rec.frames or not rec.frames[fid].has_pose():
            continue
        T_world_vref = invert_T(_T_of(rec.frames[fid].rig_from_world))
        T_world_ref = T_world_vref @ T_vref_ref
        if ref.name == "right" and rig is not None:
            T_world_ref = T_world_ref @ rig.T_right_left
        names.append(fr.name)
        t_s.append(fr.t_s)
        poses.append(T_world_ref)
    pts, cols, errs = [], [], []
    for p in rec.points3D.values():
        pts.append(np.asarray(p.xyz, dtype=np.float64))
        errs.append(float(p.error))
        cols.append(np.asarray(p.color, dtype=np.uint8))
    n_reg_img = sum(1 for im in rec.images.values() if im.has_pose)
    n_reg = len(names)
    status = "ok" if n_reg == len(frames) else "partial"
    message = (f"{n_reg}/{len(frames)} frames registered, {len(pts)} points, mean reprojection "
               f"error {rec.compute_mean_reprojection_error():.3f} px")
    implausible = implausible_camera(_camera_info(sensors, rec))
    if implausible is not None:
        status, message = "failed", f"{implausible}; {message}"
    if n_models > 1:
        message += f" ({n_models} separate models; the largest is kept)"
    return SfmResult(
        status=status, message=message, frames=len(frames), images=n_img, names=names,
        t_s=np.asarray(t_s, dtype=np.float64),
        T_world_left=np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4),
        registered_images=n_reg_img,
        points_world=np.asarray(pts, dtype=np.float64).reshape(-1, 3),
        colors_rgb=np.asarray(cols, dtype=np.uint8).reshape(-1, 3),
        point_error_px=np.asarray(errs, dtype=np.float64),
        mean_reprojection_error_px=float(rec.compute_mean_reprojection_error()),
        metric=bool(metric), models=n_models, cameras=_camera_info(sensors, rec),
        virtual={s.name: s.maps.report for s in sensors if s.maps is not None},
        refractive_ba=ba_report, timings_s=timings, reconstruction=rec,
    )
