"""Recorder: every frame accounted for, clean stops (user, disk, source failure), and the
session it writes reads back exactly."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from sea3d.capture import recorder as recorder_mod
from sea3d.capture.recorder import Recorder, RecorderConfig
from sea3d.capture.sources import ArraySource, CallableSource, ImageFrame, Source
from sea3d.errors import CaptureError, ConfigError
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import ImuSample, SonarSample, open_session
from sea3d.refraction.presets import paper_rig

RIG_YAML = rig_to_yaml(paper_rig("dome"))

FRAME_NS = 33_333_333
NO_RESERVE = 0  # tests do not need a disk reserve


def _imgs(rng, n, shape=(24, 32, 3)):
    return [rng.integers(0, 256, size=shape, dtype=np.uint8) for _ in range(n)]


def _imu_source(n):
    it = iter(range(n))

    def produce():
        k = next(it, None)
        return (
            None
            if k is None
            else ImuSample(k * 5_000_000, np.array([k, 0.0, 9.81]), np.array([0.0, 0.0, k / 10]))
        )

    return CallableSource(produce, kind="imu")


def _sonar_source(n):
    it = iter(range(n))

    def produce():
        k = next(it, None)
        return None if k is None else SonarSample(k * 100_000_000 + 3, 2.0 + k, 0.5)

    return CallableSource(produce, kind="sonar")


@pytest.mark.parametrize("fmt", ["mcap", "folder"])
def test_blocking_replay_records_every_frame_and_reads_back_exactly(tmp_path, fmt):
    rng = np.random.default_rng(0)
    left, right = _imgs(rng, 5), _imgs(rng, 5)
    out = tmp_path / ("r.mcap" if fmt == "mcap" else "r_dir")
    config = RecorderConfig(
        out_path=out,
        block_when_full=True,
        queue_frames=2,
        min_free_bytes=NO_RESERVE,
        rig_yaml=RIG_YAML,
    )
    sources: dict[str, Source] = {
        "left": ArraySource(left, count=20, speed=0),
        "right": ArraySource(right, count=20, speed=0),
        "imu": _imu_source(50),
        "sonar": _sonar_source(4),
    }
    summary = Recorder(config, sources).run()
    assert summary.frames == {"left": 20, "right": 20, "imu": 50, "sonar": 4}
    assert summary.dropped == {"left": 0, "right": 0, "imu": 0, "sonar": 0}
    assert summary.stop_reason == "the camera sources ended"
    assert summary.errors == []
    with open_session(out) as s:
        assert s.rig_yaml == RIG_YAML
        assert s.stamps("left").tolist() == [k * FRAME_NS for k in range(20)]
        for k in range(20):
            np.testing.assert_array_equal(s.image("left", k), left[k % 5])
            np.testing.assert_array_equal(s.image("right", k), right[k % 5])
        assert len(list(s.pairs())) == 20
        assert s.imu().accel_mps2[:, 0].tolist() == list(range(50))
        assert s.sonar().range_m.tolist() == [2.0, 3.0, 4.0, 5.0]
        assert summary.bytes_on_disk == s.size_bytes()


def test_frames_dropped_when_the_queue_is_full_are_counted_never_silent(tmp_path):
    rng = np.random.default_rng(0)
    big = _imgs(rng, 2, shape=(480, 640, 3))
    config = RecorderConfig(
        out_path=tmp_path / "d.mcap",
        queue_frames=1,
        encoder_threads=1,
        min_free_bytes=NO_RESERVE,
        png_compression=9,
    )
    summary = Recorder(
        config,
        {"left": ArraySource(big, count=60, speed=0), "right": ArraySource(big, count=60, speed=0)},
    ).run()
    with open_session(tmp_path / "d.mcap") as s:
        for side in ("left", "right"):
            assert summary.captured[side] == 60
            assert summary.frames[side] + summary.dropped[side] == 60
            assert s.stamps(side).size == summary.frames[side]
    assert summary.dropped["left"] + summary.dropped["right"] > 0  # PNG level 9 is slow


def test_request_stop_from_another_thread_closes_a_readable_session(tmp_path):
    rng = np.random.default_rng(0)
    imgs = _imgs(rng, 3)
    config = RecorderConfig(out_path=tmp_path / "s.mcap", min_free_bytes=NO_RESERVE)
    rec = Recorder(
        config,
        {
            "left": ArraySource(imgs, rate_hz=200.0, speed=1.0),
            "right": ArraySource(imgs, rate_hz=200.0, speed=1.0),
        },
    )
    timer = threading.Timer(0.5, rec.request_stop, args=("stopped by test",))
    timer.start()
    summary = rec.run()
    timer.join()
    assert summary.stop_reason == "stopped by test"
    with open_session(tmp_path / "s.mcap") as s:
        assert s.complete
        assert s.stamps("left").size == summary.frames["left"] > 0


def test_disk_space_is_checked_before_and_during_recording(tmp_path, monkeypatch):
    img = np.zeros((8, 8), np.uint8)
    config = RecorderConfig(out_path=tmp_path / "a.mcap", min_free_bytes=10**18)
    with pytest.raises(CaptureError, match=r"GB free for .*a\.mcap"):
        Recorder(config, {"left": ArraySource([img]), "right": ArraySource([img])}).run()
    assert not (tmp_path / "a.mcap").exists()

    free = iter([5 * 10**9, 5 * 10**9, 5 * 10**9] + [10**8] * 1000)
    monkeypatch.setattr(recorder_mod, "disk_free_bytes", lambda _p: next(free))
    config = RecorderConfig(
        out_path=tmp_path / "b", min_free_bytes=10**9, disk_check_interval_s=0.05
    )
    summary = Recorder(
        config,
        {"left": ArraySource([img], rate_hz=100.0), "right": ArraySource([img], rate_hz=100.0)},
    ).run()
    assert summary.stop_reason.startswith("disk nearly full: 0.10 GB free")
    with open_session(tmp_path / "b") as s:
        assert s.stamps("left").size == summary.frames["left"]


class _FailingSource(Source):
    kind = "image"

    def __init__(self, fail_after: int) -> None:
        super().__init__("flaky-cam")
        self.n, self.fail_after = 0, fail_after

    def read(self):
        from sea3d.capture.sources import ImageFrame

        if self.n >= self.fail_after:
            raise CaptureError("camera flaky-cam: 30 grabs failed in a row; camera lost")
        self.n += 1
        return ImageFrame(self.n * FRAME_NS, np.full((8, 8), self.n, np.uint8))


def test_a_lost_camera_stops_the_recording_with_its_reason_and_keeps_the_data(tmp_path):
    config = RecorderConfig(
        out_path=tmp_path / "c.mcap", block_when_full=True, min_free_bytes=NO_RESERVE
    )
    img = np.zeros((8, 8), np.uint8)
    summary = Recorder(
        config, {"left": _FailingSource(7), "right": ArraySource([img], rate_hz=100.0)}
    ).run()
    assert "left source flaky-cam" in summary.stop_reason and "camera lost" in summary.stop_reason
    assert summary.errors and summary.frames["left"] == 7
    with open_session(tmp_path / "c.mcap") as s:
        assert s.image("left", 6)[0, 0] == 7


def test_bad_configurations_are_rejected(tmp_path):
    with pytest.raises(ConfigError, match="duration_s must be > 0"):
        RecorderConfig(out_path=tmp_path / "x.mcap", duration_s=0)
    img = np.zeros((2, 2), np.uint8)
    with pytest.raises(ConfigError, match="stream imu needs imu records"):
        Recorder(RecorderConfig(out_path=tmp_path / "x.mcap"), {"imu": ArraySource([img])})


@pytest.mark.parametrize("fmt", ["mcap", "folder"])
def test_a_full_disk_mid_recording_stops_with_a_summary_and_a_readable_session(
    tmp_path, monkeypatch, fmt
):
    import errno

    from sea3d.io.session import mcap_chunks, storage_folder

    budget = {"bytes": 0}

    def failing(real):
        def wrapper(self_or_path, data, *args, **kwargs):
            size = sum(len(p) for p in data) if isinstance(data, list) else len(data)
            budget["bytes"] += size
            if budget["bytes"] > 6_000_000:  # the disk is full after about 6 MB
                raise OSError(errno.ENOSPC, "No space left on device")
            return real(self_or_path, data, *args, **kwargs)

        return wrapper

    if fmt == "mcap":
        monkeypatch.setattr(
            mcap_chunks.FdWriter, "write_all", failing(mcap_chunks.FdWriter.write_all)
        )
    else:
        monkeypatch.setattr(storage_folder, "atomic_write", failing(storage_folder.atomic_write))
    rng = np.random.default_rng(0)
    imgs = _imgs(rng, 3, shape=(120, 160, 3))  # about 58 kB per PNG
    out = tmp_path / ("f.mcap" if fmt == "mcap" else "f_dir")
    config = RecorderConfig(out_path=out, block_when_full=True, min_free_bytes=NO_RESERVE)
    summary = Recorder(
        config,
        {
            "left": ArraySource(imgs, count=200, speed=0),
            "right": ArraySource(imgs, count=200, speed=0),
        },
    ).run()
    assert "No space left on device" in summary.stop_reason
    assert any("No space left" in e for e in summary.errors)
    monkeypatch.undo()
    with open_session(out) as s:
        n = s.stamps("left").size
        assert 0 < n == summary.frames["left"]  # the summary counts what is readable
        for k in range(n):
            np.testing.assert_array_equal(s.image("left", k), imgs[k % 3])


def test_samples_within_the_camera_span_are_kept_when_the_cameras_end_first(tmp_path):
    # A loaded machine: the cameras end while the IMU thread still holds the samples stamped
    # up to the last frame (this lost the last IMU sample of a Foxglove recording test once:
    # 190 of 191). The recorder waits (bounded) for them before it stops.
    rng = np.random.default_rng(0)
    n_frames = 4
    last_frame_ns = (n_frames - 1) * FRAME_NS
    n_imu = last_frame_ns // 5_000_000 + 1  # the last sample at or before the last frame
    cameras_done = threading.Event()
    it = iter(range(n_imu))

    def produce():
        k = next(it, None)
        if k is None:
            return None
        if k == n_imu - 2:  # held back until the cameras have ended and the recorder has
            cameras_done.wait(5.0)  # looked at its sources again (it polls every 0.1 s)
            time.sleep(0.3)
        return ImuSample(k * 5_000_000, np.array([k, 0.0, 9.81]), np.zeros(3))

    class _Camera(ArraySource):
        def read(self):
            rec = super().read()
            if rec is None:
                cameras_done.set()
            return rec

    imgs = _imgs(rng, n_frames)
    config = RecorderConfig(out_path=tmp_path / "r.mcap", block_when_full=True,
                            min_free_bytes=NO_RESERVE, rig_yaml=RIG_YAML)
    summary = Recorder(config, {
        "left": _Camera(imgs, count=n_frames, speed=0),
        "right": ArraySource(imgs, count=n_frames, speed=0),
        "imu": CallableSource(produce, kind="imu"),
    }).run()
    assert summary.stop_reason == "the camera sources ended"
    assert summary.frames["left"] == n_frames and summary.frames["imu"] == n_imu
    with open_session(tmp_path / "r.mcap") as s:
        assert s.imu().accel_mps2[:, 0].tolist() == list(range(n_imu))


class _Resizing(Source):
    """A camera that delivers ``n`` frames of 8x6 pixels, then frames of 4x3 (its mode was
    changed under it)."""

    kind = "image"

    def __init__(self, n, *, limit=20):
        super().__init__("resizing-cam")
        self.n, self.i, self.limit = n, 0, limit

    def read(self):
        self.i += 1
        if self.i > self.limit:
            return None
        shape = (6, 8) if self.i <= self.n else (3, 4)
        return ImageFrame(self.i * FRAME_NS, np.full(shape, self.i, np.uint8))


@pytest.mark.parametrize("fmt", ["mcap", "folder"])
def test_a_camera_that_changes_resolution_ends_the_recording_cleanly_with_one_warning(
    tmp_path, caplog, fmt
):
    """The frames before the change are kept, the stop reason names the frame and both sizes,
    one warning says the same, and it is not an error (nothing failed)."""
    out = tmp_path / ("c.mcap" if fmt == "mcap" else "c")
    config = RecorderConfig(out_path=out, block_when_full=True, min_free_bytes=NO_RESERVE)
    right = ArraySource([np.zeros((6, 8), np.uint8)], rate_hz=30.0, speed=0.0, count=40)
    with caplog.at_level("WARNING", logger="sea3d.capture.recorder"):
        summary = Recorder(config, {"left": _Resizing(5), "right": right}).run()
    reason = ("left camera resizing-cam changed resolution at frame 6 (t_ns=199999998): 4x3, "
              "its earlier frames 8x6; the recording stops there")
    assert summary.stop_reason == reason
    assert not summary.errors
    assert summary.frames["left"] == 5 and summary.captured["left"] == 5
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warnings == [reason]
    with open_session(out) as s:
        assert len(s.stamps("left")) == 5 and s.image("left", 4).shape == (6, 8)


def test_a_change_of_channels_alone_names_the_layouts(tmp_path):
    frames = iter([np.zeros((6, 8), np.uint8), np.zeros((6, 8, 3), np.uint8)])
    stamps = iter(range(1, 3))

    def produce():
        img = next(frames, None)
        return None if img is None else ImageFrame(next(stamps) * FRAME_NS, img)

    config = RecorderConfig(out_path=tmp_path / "c.mcap", block_when_full=True,
                            min_free_bytes=NO_RESERVE)
    summary = Recorder(config, {"left": CallableSource(produce, name="cam"),
                                "right": ArraySource([np.zeros((6, 8), np.uint8)], count=2,
                                                     speed=0.0)}).run()
    assert "changed resolution at frame 2 (t_ns=66666666): 8x6x3 uint8, its earlier frames " \
        "8x6 uint8" in summary.stop_reason


class _Stalling(Source):
    """A camera that delivers ``n`` frames, blocks in its next read for ``stall_s``, then
    delivers three more."""

    kind = "image"

    def __init__(self, n, stall_s):
        super().__init__("stalling-cam")
        self.n, self.i, self.stall_s = n, 0, stall_s
        self.released = threading.Event()

    def read(self):
        self.i += 1
        if self.i == self.n + 1:
            self.released.wait(self.stall_s)
        if self.i > self.n + 3:
            return None
        return ImageFrame(self.i * FRAME_NS, np.full((6, 8), self.i, np.uint8))


def test_a_stalled_camera_is_warned_about_once_and_the_recording_goes_on(tmp_path, caplog):
    """Blocked 1.2 s with the warning at 0.3 s: one warning naming the camera and how long,
    then the frames after the stall are recorded as usual."""
    config = RecorderConfig(out_path=tmp_path / "c.mcap", block_when_full=True,
                            min_free_bytes=NO_RESERVE, stall_warn_s=0.3, stall_stop_s=5.0)
    left = _Stalling(3, stall_s=1.2)
    right = ArraySource([np.zeros((6, 8), np.uint8)], rate_hz=30.0, speed=0.0, count=6)
    with caplog.at_level("WARNING", logger="sea3d.capture.recorder"):
        summary = Recorder(config, {"left": left, "right": right}).run()
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith("left camera stalling-cam has delivered nothing for 0.")
    assert warnings[0].endswith(" s (stalled?)")
    assert summary.stop_reason == "the camera sources ended" and not summary.errors
    assert summary.frames["left"] == 6  # the stall delayed the frames, lost none


def test_a_camera_stalled_past_the_limit_stops_the_recording_with_its_reason(tmp_path, caplog):
    config = RecorderConfig(out_path=tmp_path / "c.mcap", block_when_full=True,
                            min_free_bytes=NO_RESERVE, stall_warn_s=0.2, stall_stop_s=0.6)
    left = _Stalling(3, stall_s=30.0)
    right = ArraySource([np.zeros((6, 8), np.uint8)], rate_hz=30.0, speed=0.0, count=3)
    t0 = time.monotonic()
    try:
        with caplog.at_level("WARNING", logger="sea3d.capture.recorder"):
            summary = Recorder(config, {"left": left, "right": right}).run()
    finally:
        left.released.set()
    assert time.monotonic() - t0 < 5.0  # not the 5 s wait for a thread that is blocked
    assert summary.stop_reason.startswith("left camera stalling-cam stalled: nothing "
                                          "delivered for 0.")
    assert summary.stop_reason.endswith(" s (the limit is 0.6 s)")
    assert not summary.errors and summary.frames["left"] == 3
    assert sum("has delivered nothing" in r.getMessage() for r in caplog.records) == 1
    with open_session(tmp_path / "c.mcap") as s:
        assert len(s.stamps("left")) == 3


def test_stall_limits_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="stall_warn_s must be > 0"):
        RecorderConfig(out_path=tmp_path / "x.mcap", stall_warn_s=0)
    with pytest.raises(ConfigError, match="stall_stop_s must be >= stall_warn_s"):
        RecorderConfig(out_path=tmp_path / "x.mcap", stall_warn_s=2.0, stall_stop_s=1.0)
    RecorderConfig(out_path=tmp_path / "x.mcap", stall_stop_s=None)
