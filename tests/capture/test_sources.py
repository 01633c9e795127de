"""Capture sources: replay from folders, videos and sessions, OpenCV cameras, simulator hook."""

from __future__ import annotations

import textwrap

import cv2
import numpy as np
import pytest

from sea3d.capture.sources import (
    ArraySource,
    CallableSource,
    ImageFolderSource,
    ImageFrame,
    OpenCVCameraSource,
    SessionReplaySource,
    VideoFileSource,
    gstreamer_available,
)
from sea3d.capture.spec import open_source
from sea3d.errors import CaptureError
from sea3d.io.session import ImuSample, SessionWriter, SonarSample


def _rgb(rng, n, shape=(24, 32, 3)):
    return [rng.integers(0, 256, size=shape, dtype=np.uint8) for _ in range(n)]


def test_image_folder_source_uses_stamped_names_and_loops_with_increasing_stamps(tmp_path):
    rng = np.random.default_rng(0)
    imgs = _rgb(rng, 3)
    stamps = [1000, 34_334_333, 67_667_666]
    for t, img in zip(stamps, imgs, strict=True):
        cv2.imwrite(str(tmp_path / f"{t}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    src = ImageFolderSource(tmp_path, loop=True)
    got = [src.read() for _ in range(6)]
    assert all(isinstance(r, ImageFrame) for r in got)
    t = [r.t_ns for r in got]  # type: ignore[union-attr]
    assert t[:3] == stamps
    assert np.all(np.diff(t) > 0)
    assert t[3] - t[0] == t[4] - t[1] == stamps[2] - stamps[0] + (stamps[2] - stamps[0]) // 2
    for r, img in zip(got, imgs + imgs, strict=True):
        np.testing.assert_array_equal(r.image, img)  # type: ignore[union-attr]


def test_image_folder_source_makes_stamps_for_plain_names(tmp_path):
    rng = np.random.default_rng(0)
    for k, img in enumerate(_rgb(rng, 3)):
        cv2.imwrite(str(tmp_path / f"frame_{k:03d}.jpg"), img)
    src = ImageFolderSource(tmp_path, rate_hz=20.0, t0_ns=5)
    assert [r.t_ns for r in src] == [5, 50_000_005, 100_000_005]


def test_image_folder_source_rejects_missing_or_empty_folders(tmp_path):
    with pytest.raises(CaptureError, match="does not exist"):
        ImageFolderSource(tmp_path / "nope")
    with pytest.raises(CaptureError, match="holds no images"):
        ImageFolderSource(tmp_path)


def test_video_file_source_replays_lossless_video_exactly(tmp_path):
    rng = np.random.default_rng(0)
    imgs = _rgb(rng, 4)
    path = tmp_path / "v.mkv"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"FFV1"), 10, (32, 24))
    assert vw.isOpened()
    for img in imgs:
        vw.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    vw.release()
    with VideoFileSource(path, t0_ns=7) as src:
        frames = list(src)
    assert [f.t_ns for f in frames] == [7 + k * 100_000_000 for k in range(4)]  # type: ignore[union-attr]
    for f, img in zip(frames, imgs, strict=True):
        np.testing.assert_array_equal(f.image, img)  # type: ignore[union-attr]
    # The live-camera class reads the same file through OpenCV's FFmpeg backend.
    with OpenCVCameraSource(str(path), api="ffmpeg", clock=iter(range(100, 200)).__next__) as cam:
        first = cam.read()
    assert first is not None and first.t_ns == 100
    np.testing.assert_array_equal(first.image, imgs[0])


def test_opencv_camera_errors_name_the_device_and_missing_gstreamer():
    with pytest.raises(CaptureError, match="/dev/video99"):
        OpenCVCameraSource("/dev/video99").open()
    if not gstreamer_available():
        with pytest.raises(CaptureError, match="no GStreamer support"):
            OpenCVCameraSource("videotestsrc ! appsink").open()
    with pytest.raises(CaptureError, match="unknown capture api"):
        OpenCVCameraSource(0, api="dshow-ish")


def test_session_replay_source_delivers_every_stream_with_its_stamps(tmp_path):
    rng = np.random.default_rng(0)
    imgs = _rgb(rng, 3)
    path = tmp_path / "s.mcap"
    with SessionWriter(path) as w:
        for k, img in enumerate(imgs):
            w.write_stereo(k * 10, img, img[::-1].copy())
            w.write_imu(k * 5, [k, 0, 9.81], [0, k, 0])
            w.write_sonar(k * 7, 1.5 + k, 0.25)
    right = list(SessionReplaySource(path, "right"))
    assert [r.t_ns for r in right] == [0, 10, 20]
    np.testing.assert_array_equal(right[1].image, imgs[1][::-1])  # type: ignore[union-attr]
    imu = list(SessionReplaySource(path, "imu"))
    assert all(isinstance(r, ImuSample) for r in imu)
    assert imu[2].accel_mps2.tolist() == [2.0, 0.0, 9.81]  # type: ignore[union-attr]
    sonar = list(SessionReplaySource(path, "sonar"))
    assert all(isinstance(r, SonarSample) for r in sonar)
    assert [s.range_m for s in sonar] == [1.5, 2.5, 3.5]  # type: ignore[union-attr]


def test_simulator_hook_is_imported_by_name(tmp_path, monkeypatch):
    (tmp_path / "fake_sim.py").write_text(
        textwrap.dedent(
            """
        import numpy as np
        def make():
            frames = iter(range(3))
            def produce():
                k = next(frames, None)
                return None if k is None else (k * 100, np.full((4, 4), k, np.uint8))
            return produce
        """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    src = open_source("sim:fake_sim:make", "left", replay_speed=0)
    assert isinstance(src, CallableSource)
    got = list(src)
    assert [f.t_ns for f in got] == [0, 100, 200]  # type: ignore[union-attr]
    assert got[2].image[0, 0] == 2  # type: ignore[union-attr]
    with pytest.raises(CaptureError, match="cannot import simulator hook"):
        open_source("sim:no_such_module_xyz:make", "left")


def test_open_source_picks_the_right_kind_and_rejects_nonsense(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "s.mcap"
    with SessionWriter(path) as w:
        w.write_stereo(0, *_rgb(rng, 2))
    assert isinstance(open_source(str(path), "left"), SessionReplaySource)
    assert open_source(f"session:{path}#right", "left").stream == "right"  # type: ignore[attr-defined]
    assert isinstance(open_source(f"session:{path}", "imu"), SessionReplaySource)
    assert isinstance(open_source("/dev/video3", "left"), OpenCVCameraSource)
    assert open_source("mti:loop://", "imu").kind == "imu"
    with pytest.raises(CaptureError, match="the left source needs image records"):
        open_source("mti:loop://", "left")
    with pytest.raises(CaptureError, match="cannot tell what source"):
        open_source("bogus-thing", "left")


def test_array_source_counts_frames_from_duration():
    img = np.zeros((2, 2), np.uint8)
    src = ArraySource([img], rate_hz=30.0, duration_s=1.0, speed=0)
    stamps = [f.t_ns for f in src]  # type: ignore[union-attr]
    assert len(stamps) == 30 and stamps[1] == 33_333_333
