"""``sea3d live`` from cameras: the recorder's listener hook feeds the live loop while the
recording holds exactly the records the recorder writes alone; the growing mesh, the
trajectory and the status reach a real Foxglove WebSocket client and the monitor page while
it runs; a camera that stops keeps the mesh so far and says why.

The cameras are :class:`~sea3d.capture.sources.SessionReplaySource` streams of the first
``FRAMES`` frames of the simulated lake (320x180, 10 fps, with its IMU); poses are the ground
truth's, so every frame is tracked and the figures do not depend on the odometry."""

from __future__ import annotations

import hashlib
import json
import threading
import time
import urllib.request

import numpy as np
import pytest

from foxglove_client import FoxgloveClient
from sea3d.capture.foxglove_live import LIVE_STATUS_TOPIC, FoxgloveConfig, FoxglovePublisher
from sea3d.capture.monitor import MonitorServer
from sea3d.capture.recorder import Recorder, RecorderConfig
from sea3d.capture.sources import CallableSource, ImageFrame, SessionReplaySource
from sea3d.errors import CaptureError
from sea3d.io.session import ImuSample, SessionWriter, open_session
from sea3d.pipeline.live import LiveConfig, RecorderFrames, run_live_cameras
from sea3d.pipeline.live_publish import FeedConfig, LiveFeed
from sea3d.pipeline.process import MapConfig, PoseConfig, ProcessConfig

FRAMES = 12
SPEED = 1.0  # the cameras at their recorded 10 fps


@pytest.fixture(scope="module")
def cameras(sim_session, tmp_path_factory):
    """The first FRAMES frames (and their IMU) of the simulated session, as a session."""
    out = tmp_path_factory.mktemp("cams") / "first.mcap"
    with open_session(sim_session) as s:
        t = s.stamps("left")[:FRAMES]
        imu = s.imu()
        with SessionWriter(out, rig_yaml=s.rig_yaml, image_encoding="png") as w:
            for k in np.nonzero(imu.t_ns <= t[-1])[0]:
                w.write_imu(int(imu.t_ns[k]), imu.accel_mps2[k], imu.gyro_radps[k])
            for i in range(FRAMES):
                w.write_stereo(int(t[i]), s.image("left", i, by="index"),
                               s.image("right", i, by="index"))
    return out


def _gt(sim_session):
    return sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"


def _recorder(cameras, path, rig_yaml, *, left=None, **config):
    sources = {"left": left or SessionReplaySource(cameras, "left", speed=SPEED),
               "right": SessionReplaySource(cameras, "right", speed=SPEED),
               "imu": SessionReplaySource(cameras, "imu", speed=SPEED)}
    cfg = RecorderConfig(out_path=path, image_encoding="png", block_when_full=True,
                         min_free_bytes=0, rig_yaml=rig_yaml, **config)
    return Recorder(cfg, sources)


def _config(sim_session, out):
    return ProcessConfig(out_dir=out, poses=PoseConfig(poses_path=_gt(sim_session)),
                         map=MapConfig(keyframes_per_submap=2), report=False)


def _records(path):
    """Every record of a session: (stream, t_ns, sha256 of the image or the sample)."""
    with open_session(path) as s:
        out = [(st, int(t), hashlib.sha256(s.image(st, i, by="index").tobytes()).hexdigest())
               for st in ("left", "right") for i, t in enumerate(s.stamps(st))]
        imu = s.imu()
        out += [("imu", int(t), hashlib.sha256(np.r_[a, g].tobytes()).hexdigest())
                for t, a, g in zip(imu.t_ns, imu.accel_mps2, imu.gyro_radps, strict=True)]
    return out


def test_live_from_cameras_records_the_same_bytes_and_publishes_while_it_runs(
        sim_session, cameras, tmp_path):
    with open_session(cameras) as s:
        rig_yaml = s.rig_yaml
    alone = tmp_path / "alone.mcap"
    _recorder(cameras, alone, rig_yaml).run()

    pub = FoxglovePublisher(FoxgloveConfig(port=0))
    feed = LiveFeed(pub, FeedConfig(mesh_interval_s=0.2, status_interval_s=0.05))
    client = FoxgloveClient(pub.url)
    client.subscribe(["/mesh", "/odometry/trajectory", LIVE_STATUS_TOPIC])
    polls: list[dict] = []
    done = threading.Event()
    with_live = tmp_path / "live.mcap"
    recorder = _recorder(cameras, with_live, rig_yaml)
    try:
        with MonitorServer(recorder, port=0, live=feed) as mon:
            def poll():
                while not done.is_set():
                    with urllib.request.urlopen(mon.url + "live.json", timeout=5) as r:
                        polls.append(json.loads(r.read()))
                    time.sleep(0.1)

            poller = threading.Thread(target=poll, daemon=True)
            poller.start()
            summary, stats, rec = run_live_cameras(recorder, _config(sim_session,
                                                                     tmp_path / "out"),
                                                   LiveConfig(), feed=feed)
            done.set()
            poller.join(timeout=10)
            with urllib.request.urlopen(mon.url + "live/mesh.ply", timeout=5) as r:
                ply = r.read()
            with urllib.request.urlopen(mon.url + "live.json", timeout=5) as r:
                after = json.loads(r.read())
            status = client.wait_for(LIVE_STATUS_TOPIC)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and status[-1][1]["stop_reason"] is None:
                time.sleep(0.05)
                status = client.wait_for(LIVE_STATUS_TOPIC)
            meshes = client.wait_for("/mesh")
            trajs = client.wait_for("/odometry/trajectory")
    finally:
        client.close()
        pub.stop()

    # the recording: every record (stream, stamp, checksum of its decoded content) what the
    # recorder writes alone. (Not the file's bytes: two recordings without live already
    # differ there, as the IMU thread's and the image writer's messages interleave by timing.)
    n_imu = rec.frames["imu"]
    assert rec.frames == {"left": FRAMES, "right": FRAMES, "imu": n_imu} and n_imu > 0
    assert rec.dropped == {"left": 0, "right": 0, "imu": 0}
    assert _records(with_live) == _records(alone)

    # the live run: every recorded pair went through the odometry, none lost
    assert stats.frames == FRAMES and summary["frames"] == FRAMES
    assert stats.tracked == FRAMES and stats.fused >= 1
    assert summary["live"]["unpaired_frames"] == 0
    assert stats.stop_reason == "recording ended: the camera sources ended"
    assert (tmp_path / "out" / "mesh.ply").is_file()

    # Foxglove: the mesh grows while it runs, then the merged mesh replaces the submaps
    # (The active submap's mesh is extracted again after each fused frame, and a refined TSDF
    # can lose a few vertices there, -16 of 20,513 once under load; so the growth asserted is
    # of the submaps published and of the total from first to last, not of every update.)
    total, live_totals, merged, ids = {}, [], [], []
    for _t, msg in meshes:
        merged += [e for e in msg.entities if e.id == "mesh"]
        if merged:
            continue
        for e in msg.entities:
            assert e.id.startswith("submap-")
            total[e.id] = len(e.triangles[0].points)
        live_totals.append(sum(total.values()))
        ids.append(len(total))
    assert len(live_totals) >= 2 and live_totals[-1] > live_totals[0] > 0
    assert ids == sorted(ids)
    final = merged[-1]
    assert final.id == "mesh" and len(final.triangles[0].points) == summary["mesh"]["vertices"]
    assert len(final.triangles[0].indices) == 3 * summary["mesh"]["triangles"]
    # the trajectory: one pose per tracked frame so far, all of them at the end
    lengths = [len(m.poses) for _t, m in trajs]
    assert lengths == sorted(lengths) and lengths[-1] == stats.tracked
    last = status[-1][1]
    assert last["frames"] == FRAMES and last["tracked"] == FRAMES
    assert last["stop_reason"] == stats.stop_reason and last["running"] is False
    assert last["mesh_vertices"] == summary["mesh"]["vertices"]
    # latency from a frame to the published mesh update holding it, per fused frame
    assert len(stats.mesh_latency_s) == stats.fused
    assert min(stats.mesh_latency_s) > 0
    assert all(m >= f for m, f in zip(stats.mesh_latency_s, stats.latency_s, strict=True))

    # the monitor page: status, trajectory and the mesh as PLY
    seen = [p["trajectory_poses"] for p in polls]
    assert seen and seen == sorted(seen) and any(p["running"] for p in polls)
    assert all(p["trajectory_poses"] == len(p["trajectory_xyz"]) for p in polls)
    assert after["trajectory_poses"] == len(after["trajectory_xyz"]) == FRAMES
    assert after["stop_reason"] == stats.stop_reason and after["running"] is False
    head = ply[:ply.index(b"end_header")].decode()
    assert f"element vertex {summary['mesh']['vertices']}" in head


class _StopsAfter:
    """A camera that delivers ``n`` frames, then fails as a lost camera does."""

    def __init__(self, cameras, n):
        self.src = SessionReplaySource(cameras, "left", speed=SPEED)
        self.n = n

    def __call__(self):
        if self.n == 0:
            raise CaptureError("camera 'left': 30 grabs failed in a row; camera lost")
        self.n -= 1
        return self.src.read()


def test_a_camera_that_stops_keeps_the_mesh_so_far_and_says_why(sim_session, cameras,
                                                                tmp_path):
    with open_session(cameras) as s:
        rig_yaml = s.rig_yaml
    left = CallableSource(_StopsAfter(cameras, 5), name="left-cam")
    recorder = _recorder(cameras, tmp_path / "rec.mcap", rig_yaml, left=left)
    summary, stats, rec = run_live_cameras(recorder, _config(sim_session, tmp_path / "out"))
    assert rec.frames["left"] == 5
    assert stats.frames == 5 and summary["frames"] == 5
    assert stats.stop_reason == ("camera stopped: left source left-cam: camera 'left': 30 "
                                 "grabs failed in a row; camera lost")
    assert summary["live"]["stop_reason"] == stats.stop_reason
    assert summary["mesh"]["triangles"] > 0 and (tmp_path / "out" / "mesh.ply").is_file()
    with open_session(tmp_path / "rec.mcap") as s:  # the recording so far stays readable
        assert len(s.stamps("left")) == 5


class _FakeRecorder:
    def __init__(self):
        self.sources = {"left": None, "right": None}

    def add_listener(self, fn):
        self.fn = fn


def test_pairs_by_mutual_nearest_stamp_and_counts_frames_without_a_partner():
    """Left every 100 ms; right 3 ms later, one missing, one extra 50 ms off: pairs as
    SessionReader.match_pairs would, the partnerless frames counted, none of them held."""
    rec = _FakeRecorder()
    frames = RecorderFrames(rec)
    img = np.zeros((4, 4), np.uint8)
    ms = 1_000_000
    for k in range(10):
        rec.fn("left", ImageFrame(k * 100 * ms, img))
        if k != 4:
            rec.fn("right", ImageFrame(k * 100 * ms + 3 * ms, img))
        if k == 6:
            rec.fn("right", ImageFrame(k * 100 * ms + 53 * ms, img))
        rec.fn("imu", ImuSample(k * 100 * ms, np.zeros(3), np.zeros(3)))
    frames.end("recording ended: test")
    got = list(frames)
    assert [f.t_ns // ms for f in got] == [0, 100, 200, 300, 500, 600, 700, 800, 900]
    assert frames.unpaired == 2  # left 400 (no right), right 653 (no left)
    assert frames.stop_reason == "recording ended: test"
    assert all(f.imu is not None and f.imu.t_ns[-1] == f.t_ns for f in got)
    with pytest.raises(ValueError):  # the recorder's arrays are not writable through live
        got[0].left[0, 0] = 1


@pytest.mark.parametrize("imu_offset_s, warned", [(0.0, False), (100.0, True), (-100.0, True)])
def test_an_imu_clock_far_from_the_cameras_is_named_once(caplog, imu_offset_s, warned):
    """IMU stamps 100 s from the cameras' (an unsynchronised IMU): one warning naming the
    stream, from the clock check of ``sea3d process``; then pairs no longer wait for IMU
    samples up to their stamps. 1 s is the tolerance (OdometryConfig's default)."""
    rec = _FakeRecorder()
    rec.sources["imu"] = None
    frames = RecorderFrames(rec, imu_wait_s=0.05, imu_tolerance_s=1.0)
    img = np.zeros((4, 4), np.uint8)
    ms = 1_000_000
    for k in range(10):
        t = k * 100 * ms
        for j in range(20):  # 200 Hz
            rec.fn("imu", ImuSample(t + j * 5 * ms + int(imu_offset_s * 1e9), np.zeros(3),
                                    np.zeros(3)))
        rec.fn("left", ImageFrame(t, img))
        rec.fn("right", ImageFrame(t, img))
    it = iter(frames)
    with caplog.at_level("WARNING", logger="sea3d.pipeline.live"):
        got = [next(it) for _ in range(9)]
    notes = [r.getMessage() for r in caplog.records if "clock" in r.getMessage()]
    assert len(got) == 9
    if warned:
        assert len(notes) == 1 and notes[0].startswith("live: stream imu: the IMU stamps")
        assert frames.imu_clock_note is not None and not frames.has_imu
    else:
        assert notes == [] and frames.imu_clock_note is None and frames.has_imu


def test_the_feed_keeps_finished_submap_meshes_on_disk_and_serves_them(monkeypatch, tmp_path):
    """A finished submap's mesh goes to the feed's folder (float32: 1e-6 m at metres) and
    comes back, at its anchor's pose, in /live/mesh.ply; in memory only its pose and sizes."""
    from types import SimpleNamespace

    from sea3d.geometry.mesh import Mesh
    from sea3d.pipeline import live_publish
    from sea3d.recon import tsdf as tsdf_mod

    rng = np.random.default_rng(0)
    mesh = Mesh(vertices=rng.uniform(-1, 1, (50, 3)), triangles=rng.integers(0, 50, (80, 3)),
                colors_rgb=rng.integers(0, 256, (50, 3), dtype=np.uint8))

    class _Volume:
        @staticmethod
        def from_blocks(blocks, cfg):
            return SimpleNamespace(extract_mesh=lambda: mesh)

    monkeypatch.setattr(tsdf_mod, "TsdfVolume", _Volume)
    feed = LiveFeed(mesh_dir=tmp_path / "meshes")
    try:
        T = np.eye(4)
        T[:3, 3] = (1.0, 2.0, 3.0)
        store = feed.wrap_store(SimpleNamespace(put=lambda s: None), None)
        store.put(SimpleNamespace(submap_id=3, anchor_keyframe_id=7, T_anchor_grid=np.eye(4),
                                  blocks=None))
        fin = feed._finished[3]
        assert isinstance(fin, live_publish._Finished) and fin.path.is_file()
        assert fin.vertices == 50  # no mesh arrays held, only where it is and its size
        no_active = SimpleNamespace(active_mesh=lambda kf: None)
        out = feed._mesh_changes(SimpleNamespace(kf_rect={7: T}, fusion=no_active))
        np.testing.assert_allclose(out["submap-3"].vertices, mesh.vertices + T[:3, 3], atol=1e-6)
        np.testing.assert_array_equal(out["submap-3"].triangles, mesh.triangles)
        np.testing.assert_array_equal(out["submap-3"].colors_rgb, mesh.colors_rgb)
        ply = feed.mesh_ply()
        assert ply is not None and b"element vertex 50" in ply and b"element face 80" in ply
        # 10 s later: with the monitor alone it is not read back (the page reads it from
        # disk); with a Foxglove server it is sent again, for clients that missed it
        loads = []
        load = live_publish._Finished.load
        monkeypatch.setattr(live_publish._Finished, "load",
                            lambda self: loads.append(1) or load(self))
        stages = SimpleNamespace(kf_rect={7: T}, fusion=no_active)
        feed._last_full -= 11.0
        assert "submap-3" not in feed._mesh_changes(stages) and not loads
        feed.publisher = SimpleNamespace(clients_seen=lambda: 0)
        feed._last_full -= 11.0
        assert "submap-3" in feed._mesh_changes(stages) and loads == [1]
        feed.publisher = None
    finally:
        feed.close()


def test_cli_a_camera_that_fails_exits_non_zero_after_writing_the_frames_so_far(
        sim_session, cameras, tmp_path, monkeypatch, capsys):
    """``sea3d live --record``: a camera that raises (unplugged) ends the recording; the
    frames before it are reconstructed and written, and the exit status is 1 with the fault on
    stderr, as ``sea3d record`` does (it was 0)."""
    import sea3d.cli.live as cli_live
    from sea3d.cli import main

    with open_session(cameras) as s:
        rig_yaml = s.rig_yaml
    left = CallableSource(_StopsAfter(cameras, 4), name="left-cam")
    monkeypatch.setattr(cli_live, "_recorder",
                        lambda args: _recorder(cameras, args.record, rig_yaml, left=left))
    out = tmp_path / "out"
    code = main(["live", "--record", str(tmp_path / "rec.mcap"), "--left", "0", "--right", "1",
                 "-o", str(out), "--poses", str(_gt(sim_session))])
    captured = capsys.readouterr()
    assert code == 1
    assert "camera stopped: left source left-cam" in captured.out
    assert "sea3d live: left source left-cam: camera 'left': 30 grabs failed" in captured.err
    assert (out / "mesh.ply").is_file() and (out / "trajectory.tum").is_file()
    assert json.loads((out / "summary.json").read_text())["frames"] == 4


class _HalvesAfter:
    """A camera that delivers ``n`` frames at the recorded size, then frames of half the
    width and height (its mode changed under the recording)."""

    def __init__(self, cameras, n):
        self.src = SessionReplaySource(cameras, "left", speed=SPEED)
        self.n = n

    def __call__(self):
        rec = self.src.read()
        if rec is None or self.n > 0:
            self.n -= 1
            return rec
        return ImageFrame(rec.t_ns, np.ascontiguousarray(rec.image[::2, ::2]))


def test_cli_a_camera_that_changes_resolution_ends_cleanly_keeping_the_frames_before(
        sim_session, cameras, tmp_path, monkeypatch, capsys, caplog):
    """``sea3d live --record``: a camera whose frames turn to half size after 4 frames ends
    the recording there; the 4 frames before are reconstructed and written, the stop reason
    names the frame and both sizes, one warning says so, and the exit status is 0 (the
    cameras stopped, nothing failed)."""
    import sea3d.cli.live as cli_live
    from sea3d.cli import main

    with open_session(cameras) as s:
        rig_yaml = s.rig_yaml
        t5 = int(s.stamps("left")[4])
    left = CallableSource(_HalvesAfter(cameras, 4), name="left-cam")
    monkeypatch.setattr(cli_live, "_recorder",
                        lambda args: _recorder(cameras, args.record, rig_yaml, left=left))
    out = tmp_path / "out"
    with caplog.at_level("WARNING"):
        code = main(["live", "--record", str(tmp_path / "rec.mcap"), "--left", "0",
                     "--right", "1", "-o", str(out), "--poses", str(_gt(sim_session))])
    captured = capsys.readouterr()
    reason = (f"left camera left-cam changed resolution at frame 5 (t_ns={t5}): 160x90, its "
              "earlier frames 320x180; the recording stops there")
    assert code == 0, captured.err
    assert f"recording ended: {reason}" in captured.out
    assert [r.getMessage() for r in caplog.records if "resolution" in r.getMessage()] == [reason]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 4 and summary["live"]["stop_reason"] == f"recording ended: {reason}"
    assert summary["mesh"]["triangles"] > 0
    assert (out / "mesh.ply").is_file() and (out / "trajectory.tum").is_file()
    with open_session(tmp_path / "rec.mcap") as s:  # the recording holds one size
        assert len(s.stamps("left")) == 4


def test_a_camera_frame_of_another_size_than_the_rig_stops_the_recording():
    """Frames that do not have the rig's size are not reconstructed (they would be resized
    into a wrong geometry): the recording is stopped with a reason naming the frame and both
    sizes, once."""
    rec = _FakeRecorder()
    stops = []
    rec.request_stop = stops.append
    frames = RecorderFrames(rec, image_size=(8, 6), pair_tolerance_ns=0)
    good, small = np.zeros((6, 8), np.uint8), np.zeros((3, 4), np.uint8)
    for k in range(3):
        rec.fn("left", ImageFrame(k, good))
        rec.fn("right", ImageFrame(k, good))
    rec.fn("left", ImageFrame(3, small))
    rec.fn("right", ImageFrame(3, small))
    frames.end("recording ended: " + stops[0])
    assert [f.t_ns for f in frames] == [0, 1, 2]
    assert stops == ["left frame t_ns=3 is 4x3, not the rig's 8x6; the recording stops there"]


class _StallsAfter:
    """A camera that delivers ``n`` frames, then blocks in its read until released."""

    def __init__(self, cameras, n):
        self.src = SessionReplaySource(cameras, "left", speed=SPEED)
        self.n = n
        self.released = threading.Event()

    def __call__(self):
        if self.n == 0:
            self.released.wait(30.0)
            return None
        self.n -= 1
        return self.src.read()


def test_a_camera_stalled_past_the_limit_ends_the_run_keeping_the_frames_before(
        sim_session, cameras, tmp_path, caplog):
    """Limits of 0.3 s (warning) and 1 s (stop): one warning naming the camera, then the
    recording stops with a reason that says it stalled; the 4 frames before are written."""
    with open_session(cameras) as s:
        rig_yaml = s.rig_yaml
    stalls = _StallsAfter(cameras, 4)
    recorder = _recorder(cameras, tmp_path / "rec.mcap", rig_yaml,
                         left=CallableSource(stalls, name="left-cam"),
                         stall_warn_s=0.3, stall_stop_s=1.0)
    try:
        with caplog.at_level("WARNING"):
            summary, stats, rec = run_live_cameras(recorder,
                                                   _config(sim_session, tmp_path / "out"))
    finally:
        stalls.released.set()
    assert stats.stop_reason.startswith("recording ended: left camera left-cam stalled: "
                                        "nothing delivered for 1.")
    assert summary["frames"] == 4 and not rec.errors
    assert summary["mesh"]["triangles"] > 0 and (tmp_path / "out" / "mesh.ply").is_file()
    stalled = [r.getMessage() for r in caplog.records if "delivered nothing" in r.getMessage()]
    assert len(stalled) == 1 and stalled[0].startswith("left camera left-cam has delivered "
                                                       "nothing for 0.")
