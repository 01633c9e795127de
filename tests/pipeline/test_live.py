"""``sea3d live --replay``: odometry on every frame, depth and fusion on those it keeps up
with, drops counted, latency measured, and a camera that stops keeps the mesh so far."""

from __future__ import annotations

import csv
import json
import logging
from concurrent.futures import Future

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import SessionError
from sea3d.pipeline.frame_source import SessionFrames
from sea3d.pipeline.live import LiveConfig, ReplayFrames, run_live_replay
from sea3d.pipeline.process import MapConfig, PoseConfig, ProcessConfig

FRAMES = 12


def _gt(session):
    return session.with_name(session.stem + "_gt") / "poses_left.tum"


def _rows(out):
    with open(out / "status.csv") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("rate", [1.0, 1000.0])
def test_replay_tracks_every_frame_and_fuses_what_it_keeps_up_with(sim_session, tmp_path,
                                                                   rate, caplog):
    """At the recorded rate (10 fps, 320x180) and 50 times faster: every frame reaches the
    odometry; frames whose depth was dropped are not fused, and say so; the count adds up;
    the latency's parts (depth on the worker, then to fusion) lie within it."""
    cfg = ProcessConfig(out_dir=tmp_path / "live", poses=PoseConfig(poses_path=_gt(sim_session)),
                        max_frames=FRAMES, map=MapConfig(keyframes_per_submap=2))
    # 1000x (all 12 frames due within 1.2 ms): also newest first (frames with newer ones
    # waiting behind them get no depth), with room for every frame's depth at once, so that
    # a frame is dropped for being stale, never because the worker happens to be busy (at 50x
    # and one frame in flight, the first depth frame outlasted the loop over the others on a
    # loaded machine: 10 dropped, none stale)
    live_cfg = (LiveConfig(depth_max_backlog=1, depth_in_flight=FRAMES) if rate > 10
                else LiveConfig())
    with caplog.at_level(logging.WARNING, logger="sea3d.pipeline.live"):
        summary, stats = run_live_replay(sim_session, cfg, live_cfg, rate=rate)
    live = summary["live"]
    assert stats.frames == FRAMES and summary["frames"] == FRAMES
    # a stage that fell behind is named in the summary, and said once
    assert ("depth" in live["behind"]) == (stats.depth_dropped > 0)
    assert ("odometry" in live["behind"]) == (max(stats.wait_s) > live_cfg.behind_after_s)
    said = [r.getMessage() for r in caplog.records if "behind the camera" in r.getMessage()]
    assert len(said) == len(live["behind"])
    assert all(m.startswith(f"live: {st} is behind") for m, st in zip(said, live["behind"],
                                                                      strict=True))
    assert live["fraction_tracked"] == 1.0
    rows = _rows(tmp_path / "live")
    assert len(rows) == FRAMES
    no_depth = sum(r["fusion"] == "no-depth" for r in rows)
    assert no_depth == stats.depth_dropped
    assert stats.fused + stats.depth_dropped <= FRAMES and stats.fused >= 1
    assert len(stats.latency_s) == stats.fused and min(stats.latency_s) > 0
    # where the latency goes: depth on the worker, then to fusion, within arrival to fusion
    assert len(stats.depth_s) == len(stats.hold_s) == stats.fused
    assert len(stats.wait_s) == FRAMES
    for lat, d, h in zip(stats.latency_s, stats.depth_s, stats.hold_s, strict=True):
        assert d > 0 and h >= 0 and d + h <= lat + 1e-6
    assert 0 <= stats.depth_stale <= stats.depth_dropped == live["depth_dropped"]
    assert live["stop_reason"] == "replay ended"
    # every frame's pose latency; the worker's CPU for each depth frame, once; the loop's
    # CPU split into its thread and the read-ahead's
    assert len(stats.pose_latency_s) == FRAMES and min(stats.pose_latency_s) > 0
    assert stats.depth_frames + stats.depth_dropped == FRAMES
    assert len(stats.depth_cpu_s) == stats.depth_frames and min(stats.depth_cpu_s) > 0
    assert live["depth_cpu_s_per_depth_frame"] == pytest.approx(np.mean(stats.depth_cpu_s))
    assert 0 < stats.loop_thread_cpu_s and 0 < stats.read_cpu_s
    assert stats.loop_thread_cpu_s + stats.read_cpu_s <= stats.cpu_s + 0.05
    # a frame without depth says so, and its seeds are the last depth map moved to its
    # predicted pose (from the second tracked frame on: constant velocity needs two)
    assert sum(r["depth"] == "seeded" for r in rows) == stats.depth_dropped
    if rate > 10:  # 10,000 fps: every frame but the first (nothing to seed from before it)
        # and the last has newer ones behind it
        assert rows[0]["depth"] != "seeded"
        assert stats.depth_dropped > 0 and stats.depth_stale > 0
        assert stats.depth_dropped - 2 <= stats.seeds_moved <= stats.depth_dropped
    assert summary["mesh"]["triangles"] > 1000
    traj = np.loadtxt(tmp_path / "live" / "trajectory.tum")
    assert len(traj) == FRAMES
    # the finish step of process: its timings and its fusion block, as process writes them
    assert {"merge_s", "cloud_s", "write_s"} <= summary["timings_s"].keys()
    assert summary["fusion"]["min_piece_triangles"] == cfg.map.min_piece_triangles
    written = json.loads((tmp_path / "live" / "summary.json").read_text())
    assert written["fusion"] == summary["fusion"]


class _Pairs:
    """A session's pairs as :class:`ReplayFrames` reads them (10 fps, no IMU)."""

    def __init__(self, n):
        from sea3d.pipeline.frame_source import FramePair

        self.pairs = [FramePair(index=i, t_ns=i * 100_000_000, left_index=i, right_index=i)
                      for i in range(n)]
        self.imu = None

    def read(self, pair):
        return np.zeros((2, 2), np.uint8), np.zeros((2, 2), np.uint8)


def test_replay_counts_the_frames_due_behind_each_one_and_skips_none():
    """A consumer taking 250 ms a frame of a 10 fps replay: the frames already due pile up
    (the backlog, this frame included) and none is skipped; a consumer that keeps up sees 1."""
    clock = [0.0]
    frames = ReplayFrames(_Pairs(8), clock=lambda: clock[0],
                          sleep=lambda s: clock.__setitem__(0, clock[0] + s))
    seen = []
    for f in frames:
        seen.append((f.t_ns // 100_000_000, frames.backlog, round(f.arrival_s, 3)))
        clock[0] += 0.25
    assert [k for k, _, _ in seen] == list(range(8))
    # at frame k the clock reads 0.25 k s: frames up to floor(2.5 k) are due
    assert [b for _, b, _ in seen] == [min(8, int(2.5 * k) + 1) - k for k in range(8)]
    assert [a for _, _, a in seen] == [round(0.1 * k, 3) for k in range(8)]  # due times
    clock[0] = 0.0
    fast = ReplayFrames(_Pairs(5), clock=lambda: clock[0],
                        sleep=lambda s: clock.__setitem__(0, clock[0] + s))
    assert [fast.backlog for _ in fast] == [1] * 5


def test_frames_that_cannot_be_read_are_skipped_and_the_mesh_kept(sim_session, tmp_path,
                                                                  monkeypatch):
    real_read = SessionFrames.read

    def read(self, pair):
        if pair.index >= 6:
            raise SessionError("chunk at byte 1234 is damaged (CRC mismatch)")
        return real_read(self, pair)

    monkeypatch.setattr(SessionFrames, "read", read)
    cfg = ProcessConfig(out_dir=tmp_path / "stop", poses=PoseConfig(poses_path=_gt(sim_session)),
                        max_frames=FRAMES, map=MapConfig(keyframes_per_submap=2))
    summary, stats = run_live_replay(sim_session, cfg, rate=50.0)
    assert stats.frames == 6 and summary["frames"] == 6
    assert summary["live"]["frames_unreadable"] == FRAMES - 6
    assert summary["live"]["stop_reason"] == (f"replay ended ({FRAMES - 6} unreadable frames "
                                              "skipped)")
    assert (tmp_path / "stop" / "mesh.ply").is_file() and summary["mesh"]["triangles"] > 0


@pytest.fixture(scope="module")
def chunked_session(sim_session, tmp_path_factory):
    """``sim_session`` written again in chunks of about 1 MB (two or three frames each), so
    that the chunks do not depend on how fast the simulator ran; its poses are
    ``sim_session``'s."""
    from sea3d.io.session import SessionWriter, open_session

    out = tmp_path_factory.mktemp("chunked") / "lake.mcap"
    with open_session(sim_session) as src:
        match = src.match_pairs()
        left_t, right_t = src.stamps("left"), src.stamps("right")
        imu = src.imu()
        with SessionWriter(out, rig_yaml=src.rig_yaml, chunk_size=1 << 20,
                           chunk_interval_s=1e6) as w:
            k = 0
            for li, ri in zip(match.left_index, match.right_index, strict=True):
                t = int(left_t[li])
                assert int(right_t[ri]) == t
                while k < len(imu) and int(imu.t_ns[k]) <= t:
                    w.write_imu(int(imu.t_ns[k]), imu.accel_mps2[k], imu.gyro_radps[k])
                    k += 1
                w.write_stereo(t, src.image("left", int(li), by="index"),
                               src.image("right", int(ri), by="index"))
    return out


def _damaged_copy(session, dst, which):
    """A copy of ``session`` with one chunk's bytes flipped midway (its CRC then fails); the
    chunk's ``(offset, start_ns, end_ns)``. ``which``: "first" or "middle"."""
    from mcap.reader import make_reader

    with open(session, "rb") as fh:
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 3
    c = chunks[0] if which == "first" else chunks[len(chunks) // 2]
    data = bytearray(session.read_bytes())
    at = c.chunk_start_offset + c.chunk_length // 2
    data[at:at + 64] = bytes(b ^ 0xFF for b in data[at:at + 64])
    dst.write_bytes(bytes(data))
    return c.chunk_start_offset, c.message_start_time, c.message_end_time


def _left_stamps(session):
    from sea3d.io.session import open_session

    with open_session(session) as s:
        return [int(t) for t in s.stamps("left")]


def test_replay_skips_a_damaged_middle_chunk_and_goes_on_after_it(sim_session, chunked_session,
                                                                   tmp_path, caplog):
    gt = _gt(sim_session)
    sim_session = chunked_session
    damaged = tmp_path / "mid.mcap"
    offset, start_ns, end_ns = _damaged_copy(sim_session, damaged, "middle")
    stamps = _left_stamps(sim_session)
    lost = [t for t in stamps if start_ns <= t <= end_ns]
    assert lost and stamps[-1] > end_ns  # good frames after the chunk
    cfg = ProcessConfig(out_dir=tmp_path / "live", poses=PoseConfig(poses_path=gt),
                        map=MapConfig(keyframes_per_submap=2), report=False)
    summary, _ = run_live_replay(damaged, cfg, rate=50.0)
    assert summary["live"]["frames_unreadable"] == len(lost)
    assert summary["frames"] == len(stamps) - len(lost)
    assert summary["live"]["stop_reason"] == f"replay ended ({len(lost)} unreadable frames skipped)"
    rows = _rows(tmp_path / "live")
    assert max(int(r["t_ns"]) for r in rows) == stamps[-1]
    assert not {int(r["t_ns"]) for r in rows} & set(lost)
    assert any(f"chunk at byte {offset}" in r.getMessage() and r.levelname == "WARNING"
               for r in caplog.records)


@pytest.mark.parametrize("command", ["process", "live"])
def test_a_damaged_first_chunk_skips_its_frames_as_its_message_says(sim_session, chunked_session,
                                                                   tmp_path, command):
    gt = _gt(sim_session)
    sim_session = chunked_session
    from sea3d.pipeline.process import ExecutorConfig, run_process

    damaged = tmp_path / "first.mcap"
    _, start_ns, end_ns = _damaged_copy(sim_session, damaged, "first")
    stamps = _left_stamps(sim_session)
    lost = [t for t in stamps if start_ns <= t <= end_ns]
    assert 0 < len(lost) < len(stamps)
    cfg = ProcessConfig(out_dir=tmp_path / command, poses=PoseConfig(poses_path=gt),
                        map=MapConfig(keyframes_per_submap=2), report=False,
                        evaluate=False, executor=ExecutorConfig(workers=0))
    if command == "process":
        summary = run_process(damaged, cfg).summary
        assert summary["frames_unreadable"] == len(lost)
    else:
        summary, _ = run_live_replay(damaged, cfg, rate=50.0)
        assert summary["live"]["frames_unreadable"] == len(lost)
    assert summary["frames"] == len(stamps) - len(lost)
    assert summary["mesh"]["triangles"] > 0


def test_cli_live_replay(sim_session, tmp_path, capsys):
    assert main(["live", "--replay", str(sim_session), "-o", str(tmp_path / "cli"), "--poses",
                 str(_gt(sim_session)), "--max-frames", "6", "--rate", "5", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["frames"] == 6 and s["live"]["frames"] == 6
    # the odometry's own poses, without loop closure: the switch reaches the odometry
    assert main(["live", "--replay", str(sim_session), "-o", str(tmp_path / "nl"),
                 "--max-frames", "6", "--rate", "5", "--no-loop-closure", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["loop_checks"]["enabled"] is False and s["loop_closures"] == 0
    assert main(["live", "-o", str(tmp_path / "x")]) == 2  # no source
    assert "give --replay SESSION" in capsys.readouterr().err
    assert main(["live", "-o", str(tmp_path / "x"), "--record", str(tmp_path / "r.mcap"),
                 "--left", "0"]) == 2
    assert "--record needs --left and --right" in capsys.readouterr().err


class _Lazy(Future):
    """A depth future of :class:`_Worker`: done after two more odometry steps, or when the
    loop waits for it (then its depth is ready at once)."""

    def __init__(self, worker, res):
        super().__init__()
        self.worker, self.res, self.steps_left = worker, res, 2

    def result(self, timeout=None):
        if not self.done():
            self.worker.pending.remove(self)
            self.set_result(self.res)
        return super().result(timeout)


class _Worker:
    """The depth worker: the first frame's depth at once (nothing to seed from before it),
    later ones after the odometry of the two frames that follow."""

    def __init__(self):
        self.pending, self.submitted = [], 0

    def share(self, obj):
        return obj

    def submit(self, fn, config, t_ns, left, right, shared):
        from sea3d.pipeline.frame_stage import FrameResult

        self.submitted += 1
        res = FrameResult(t_ns=t_ns, status="ok", rect_left=left, rect_right=right,
                          depth_m=np.full(left.shape, 2.0, np.float32), valid_fraction=1.0)
        f = _Lazy(self, res)
        if self.submitted == 1:
            f.set_result(res)
        else:
            self.pending.append(f)
        return f

    def tick(self):
        for f in list(self.pending):
            f.steps_left -= 1
            if f.steps_left <= 0:
                self.pending.remove(f)
                f.set_result(f.res)


class _Stages:
    """The ordered stages, recording what the loop asks of them."""

    K = np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]])
    T_left_rect = np.eye(4)

    def __init__(self, worker):
        self.worker, self.kf_rect, self.estimates, self.log = worker, {}, [], []

    def step(self, res, imu, *, fuse=True):
        from types import SimpleNamespace

        from sea3d.odometry.types import TrackingStatus

        assert not fuse  # live fuses a frame once its own depth has come
        self.log.append(("odometry", res.t_ns, bool(res.seeded)))
        est = SimpleNamespace(t_ns=res.t_ns, T_world_left=np.eye(4), keyframe_id=None,
                              anchor_keyframe_id=None, status=TrackingStatus.TRACKING)
        self.estimates.append(est)
        self.worker.tick()
        return est

    def fuse_late(self, index, res, est, T_world_cam=None):
        assert self.estimates[index] is est
        self.log.append(("fusion", res.t_ns, False))
        return "integrated"


@pytest.mark.parametrize("waits", [False, True])
def test_the_odometry_does_not_wait_behind_depth(monkeypatch, waits):
    """A depth frame's odometry runs on the seeds while its depth computes, and the frames
    after it go on; its depth is fused when it comes, in time order. With
    ``odometry_waits_for_depth`` (the loop before) every frame waits behind depth."""
    from types import SimpleNamespace

    from sea3d.pipeline import live
    from sea3d.pipeline.live import LiveFrame, run_live

    monkeypatch.setattr(live, "rectify_pair", lambda stereo, left, right: (left, right))
    image = np.full((8, 8), 100, np.uint8)
    frames = [LiveFrame(t_ns=i * 100_000_000, left=image, right=image) for i in range(8)]
    worker = _Worker()
    stages = _Stages(worker)
    stats = run_live(frames, None, SimpleNamespace(maps=SimpleNamespace(width=8)), stages,
                     worker, LiveConfig(odometry_waits_for_depth=waits, depth_pick="in-order"))
    odo = [e for e in stages.log if e[0] == "odometry"]
    fused = [e[1] for e in stages.log if e[0] == "fusion"]
    assert [e[1] for e in odo] == [f.t_ns for f in frames]  # every frame, in order
    assert fused == sorted(fused) and len(fused) == stats.fused == worker.submitted
    assert stats.fused + stats.depth_dropped == len(frames) and stats.tracked == len(frames)
    t1 = fused[1]  # the second depth frame (the first is fused at once)
    after = stages.log.index(("odometry", t1 + 100_000_000, True))
    if waits:  # its own depth, and the next frame after its fusion
        assert ("odometry", t1, False) in odo and stats.depth_after_odometry == 0
        assert after > stages.log.index(("fusion", t1, False))
    else:  # on the seeds, and the next frame before its fusion
        assert ("odometry", t1, True) in odo and stats.depth_after_odometry == len(fused) - 1
        assert after < stages.log.index(("fusion", t1, False))


class _Manual(Future):
    """A depth future the test finishes."""


class _ManualWorker:
    def __init__(self):
        self.futures, self.t_ns = [], []

    def share(self, obj):
        return obj

    def submit(self, fn, config, t_ns, left, right, shared):
        f = _Manual()
        self.futures.append(f)
        self.t_ns.append(t_ns)
        return f


def _loop(worker, **cfg):
    from types import SimpleNamespace

    from sea3d.pipeline.live import LiveStats, _Loop

    stats = LiveStats()
    stages = SimpleNamespace(K=np.eye(3))
    loop = _Loop(None, SimpleNamespace(maps=SimpleNamespace(width=8)), stages, worker,
                 LiveConfig(**cfg), stats, None)
    return loop, stats


def _wait_for(cond, timeout=10.0):
    import time

    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


def test_newest_first_gives_the_worker_the_newest_frame_read(monkeypatch):
    """Depth starts as frames are read, not when the loop takes them: while the loop has
    taken none of six frames, the worker gets frame 0, is busy through frames 1-3 (dropped,
    not stale), and once it is free gets frame 4, the newest read, though frames 1-3 still
    wait for the loop (in order it would have got frame 1, seconds old on a loop that
    falls behind). The read-ahead passes each frame its waiting count and the oldest's age."""
    import time

    from sea3d.pipeline import live
    from sea3d.pipeline.live import LiveFrame, _Prefetch

    monkeypatch.setattr(live, "rectify_pair", lambda stereo, left, right: (left, right))
    worker = _ManualWorker()
    loop, stats = _loop(worker, depth_pick="newest")
    seen = []

    def start_depth(frame, lag_s, backlog):
        seen.append((frame.t_ns, backlog, lag_s))
        return loop.start_depth(frame, lag_s, backlog)

    image = np.zeros((4, 4), np.uint8)
    t0 = time.monotonic() - 5.0  # frame 0 arrived 5 s ago

    def frames():
        for k in range(6):
            if k == 4:
                worker.futures[0].set_result(None)  # the worker is free again
            yield LiveFrame(t_ns=k, left=image, right=image, arrival_s=t0 + 0.1 * k)

    pre = _Prefetch(frames(), None, max_bytes=1e9, start_depth=start_depth)
    try:
        _wait_for(lambda: len(seen) == 6)
        assert worker.t_ns == [0, 4]
        assert stats.depth_frames == 2 and stats.depth_dropped == 4 and stats.depth_stale == 0
        assert [b for _, b, _ in seen] == [1, 2, 3, 4, 5, 6]  # nothing taken by the loop yet
        assert all(4.9 < lag < 60 for _, _, lag in seen)  # frame 0's age: it still waits
        taken = [(f.t_ns, d is not None) for f, _, d in pre]
    finally:
        pre.close()
    assert taken == [(0, True), (1, False), (2, False), (3, False), (4, True), (5, False)]


def test_depth_max_lag_drops_depth_that_would_be_fused_late():
    """With ``depth_max_lag_s`` a frame gets no depth while the oldest frame waiting for the
    loop is older than that (stale, counted), except before the first depth frame (nothing
    to seed from); a busy worker is a drop that is not stale."""
    worker = _ManualWorker()
    loop, stats = _loop(worker, depth_max_lag_s=2.0)
    frame = __import__("sea3d.pipeline.live", fromlist=["LiveFrame"]).LiveFrame
    image = np.zeros((4, 4), np.uint8)
    assert loop.start_depth(frame(t_ns=0, left=image, right=image), 9.0, 1) is not None
    assert loop.start_depth(frame(t_ns=1, left=image, right=image), 0.1, 1) is None  # busy
    assert (stats.depth_dropped, stats.depth_stale) == (1, 0)
    worker.futures[0].set_result(None)
    assert loop.start_depth(frame(t_ns=2, left=image, right=image), 2.5, 1) is None  # late
    assert (stats.depth_dropped, stats.depth_stale) == (2, 1)
    assert loop.start_depth(frame(t_ns=3, left=image, right=image), 1.5, 1) is not None
    assert worker.t_ns == [0, 3] and stats.depth_frames == 2


def test_the_read_ahead_holds_at_most_its_bytes():
    """With room for one frame, the read-ahead reads the next only once the loop took one."""
    from sea3d.pipeline import live
    from sea3d.pipeline.live import LiveFrame, _Prefetch

    image = np.zeros((10, 10), np.uint8)  # 100 bytes; a frame with its rectified pair: 400
    read = []

    def frames():
        for k in range(4):
            read.append(k)
            yield LiveFrame(t_ns=k, left=image, right=image)

    real = live.rectify_pair
    live.rectify_pair = lambda stereo, left, right: (left, right)
    try:
        pre = _Prefetch(frames(), None, max_bytes=500)
        it = iter(pre)
        _wait_for(lambda: len(read) == 2)  # the second is read, and waits for room
        import time

        time.sleep(0.2)
        assert read == [0, 1] and pre.backlog == 2  # one held, one in the source
        assert [f.t_ns for f, _, _ in it] == [0, 1, 2, 3]
        pre.close()
    finally:
        live.rectify_pair = real


def test_a_replay_stopped_early_writes_the_frames_so_far(sim_session, tmp_path):
    """Ctrl-C or SIGTERM on ``live --replay`` (the CLI's stop callback): the frames replayed
    so far are finished and written, and the summary says why it stopped."""
    polls = []

    def stop():
        polls.append(1)
        return "stopped by SIGINT" if len(polls) > 6 else None

    cfg = ProcessConfig(out_dir=tmp_path / "stopped", poses=PoseConfig(poses_path=_gt(sim_session)),
                        max_frames=FRAMES, map=MapConfig(keyframes_per_submap=2))
    summary, stats = run_live_replay(sim_session, cfg, LiveConfig(), rate=100.0, stop=stop)
    assert stats.frames == 6 and summary["frames"] == 6
    assert summary["live"]["stop_reason"] == "stopped by SIGINT"
    assert len(_rows(tmp_path / "stopped")) == 6
    assert (tmp_path / "stopped" / "mesh.ply").is_file()
    assert (tmp_path / "stopped" / "trajectory.tum").is_file()


@pytest.mark.slow
def test_cli_live_replay_on_sigterm_writes_what_it_has(sim_session, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "sig"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sea3d", "live", "--replay", str(sim_session), "-o", str(out),
         "--poses", str(_gt(sim_session)), "--rate", "0.1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / ".lock").exists() and not any(out.glob("*")) and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(8.0)  # past the warm-up, a few frames in (1 s a frame at rate 0.1)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert "stopped by SIGTERM" in stdout
    assert (out / "summary.json").is_file() and (out / "trajectory.tum").is_file()
    assert json.loads((out / "summary.json").read_text())["live"]["stop_reason"] == (
        "stopped by SIGTERM")
