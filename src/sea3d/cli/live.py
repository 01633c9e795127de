"""``sea3d live``: live reconstruction (odometry on every frame, depth and fusion as it keeps
up), from cameras while they are recorded (``--record SESSION --left SRC --right SRC``; the
session is written as ``sea3d record`` writes it) or from a recorded session replayed at its
rate (``--replay``); the growing mesh, trajectory and status go to Foxglove (``--foxglove``)
and the monitor page (``--monitor``) while it runs."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import (
    add_loop_closure_flag,
    add_stall_options,
    check_session_output,
    config_option,
    image_size,
    odometry_config,
    param_option,
    stall_limits,
)

if TYPE_CHECKING:
    from sea3d.capture.recorder import Recorder

__all__ = ["register"]


def _recorder(args: argparse.Namespace) -> Recorder:
    from sea3d.capture.recorder import Recorder, RecorderConfig
    from sea3d.capture.sources import SessionReplaySource
    from sea3d.capture.spec import open_source
    from sea3d.io.rig_file import read_rig_text

    sources = {role: open_source(spec, role, replay_speed=args.replay_speed)
               for role, spec in (("left", args.left), ("right", args.right),
                                  ("imu", args.imu)) if spec}
    rig_yaml = read_rig_text(args.rig) if args.rig else None
    left = sources["left"]
    if rig_yaml is None and isinstance(left, SessionReplaySource):  # a session replay: its rig
        from sea3d.io.session import open_session

        with open_session(left.path) as replayed:
            rig_yaml = replayed.rig_yaml
    return Recorder(RecorderConfig(out_path=args.record, duration_s=args.duration,
                                   rig_yaml=rig_yaml, **stall_limits(args)), sources)


def _cmd_live(args: argparse.Namespace) -> int:
    from sea3d.errors import ConfigError
    from sea3d.pipeline.live import LiveConfig, run_live_cameras, run_live_replay
    from sea3d.pipeline.live_publish import LiveFeed
    from sea3d.pipeline.process import PoseConfig, ProcessConfig

    if (args.replay is None) == (args.record is None):
        raise ConfigError("give --replay SESSION, or --record SESSION with --left and --right "
                          "cameras")
    if args.record is not None and not (args.left and args.right):
        raise ConfigError("--record needs --left and --right camera sources")
    # Checked here, before sessions, cameras or the depth worker start (seconds of work).
    if not args.rate > 0:
        raise ConfigError(f"--rate must be > 0, got {args.rate:g}")
    if args.record is not None:
        check_session_output(args.record, "--record", format_flag=False)
    config = ProcessConfig(out_dir=args.output, rig_path=args.rig, size_px=args.size,
                           poses=PoseConfig(poses_path=args.poses, use_imu=not args.no_imu,
                                            odometry_config=odometry_config(args)),
                           max_frames=args.max_frames, report=False)
    live = LiveConfig(depth_in_flight=args.depth_in_flight,
                      depth_max_backlog=args.depth_max_backlog or None,  # 0: any
                      depth_pick=args.depth_pick, depth_max_lag_s=args.depth_max_lag_s or None)
    recorder = _recorder(args) if args.record is not None else None
    record_errors: list[str] = []
    servers: list[Any] = []
    rig_yaml = recorder.config.rig_yaml if recorder is not None else None
    feed = None
    try:
        if args.foxglove or args.monitor:
            feed = LiveFeed()
            provider = recorder if recorder is not None else feed
            if args.foxglove:
                from sea3d.cli._foxglove import start_foxglove

                fox = start_foxglove(args.foxglove, provider, rig_yaml=rig_yaml)
                assert fox is not None
                feed.publisher = fox[0]
                servers += [fox[1], fox[0]]
            if args.monitor:
                from sea3d.capture.monitor import MonitorServer, parse_address

                host, port = parse_address(args.monitor)
                mon = MonitorServer(provider, host, port, live=feed).start()
                print(f"monitor at {mon.url}", file=sys.stderr, flush=True)
                servers.insert(0, mon)
        if recorder is not None:
            from sea3d.cli._signals import StopOnSignals

            with StopOnSignals(recorder.request_stop):
                summary, stats, rec = run_live_cameras(recorder, config, live, feed=feed)
            record_errors = list(rec.errors)
        else:
            from sea3d.cli._signals import StopOnSignals

            # Ctrl-C or SIGTERM ends the replay at the next frame; what was replayed so far is
            # finished and written, as when a recording is stopped
            stops: list[str] = []
            with StopOnSignals(stops.append):
                summary, stats = run_live_replay(args.replay, config, live, rate=args.rate,
                                                 feed=feed,
                                                 stop=lambda: stops[-1] if stops else None)
    finally:
        if feed is not None:
            feed.close()
        for s in servers:
            s.stop()
    # a camera that failed (unplugged, lost) or a writer error: the frames before it are
    # reconstructed and written, and the exit status says the recording did not end cleanly,
    # as `sea3d record` does
    status = 1 if record_errors else 0
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
        for fault in record_errors:
            print(f"sea3d live: {fault}", file=sys.stderr)
        return status
    info = summary["live"]
    lat, pose = info["latency_s"], info["pose_latency_s"]
    print(f"{stats.frames} frames: {info['fraction_tracked']:.0%} tracked, "
          f"{info['fraction_fused']:.0%} fused ({stats.depth_dropped} depth frames dropped to "
          f"keep up); frame to fusion (fused frames) p50 {lat['p50'] or 0:.2f} s, p99 "
          f"{lat['p99'] or 0:.2f} s; frame to pose (every frame) p50 {pose['p50'] or 0:.2f} s, "
          f"p99 {pose['p99'] or 0:.2f} s; {info['stop_reason']}; outputs in {args.output}")
    for fault in record_errors:
        print(f"sea3d live: {fault}", file=sys.stderr)
    return status


def register(sub: argparse._SubParsersAction) -> None:
    from sea3d.capture.spec import open_source
    from sea3d.pipeline.live import LiveConfig, run_live_replay

    p = sub.add_parser("live", help="live reconstruction (cameras being recorded, or a "
                       "replayed session)", description=__doc__)
    p.add_argument("--replay", type=Path, help="a recorded session, replayed at its rate")
    p.add_argument("--record", type=Path, help="record the cameras into this new session "
                   "and reconstruct them live")
    p.add_argument("--left", help="left camera source (as sea3d record's --left)")
    p.add_argument("--right", help="right camera source")
    p.add_argument("--imu", help="IMU source (as sea3d record's --imu)")
    p.add_argument("--duration", type=float, help="seconds to record (default: until the "
                   "cameras stop or Ctrl-C)")
    param_option(p, open_source, "replay_speed", type=float,
                 help="pace of replay sources given to --left/--right (1: real time)")
    add_stall_options(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    param_option(p, run_live_replay, "rate", type=float, help="replay speed (1: as recorded)")
    p.add_argument("--rig", type=Path, help="rig file (default: the session's); stored with "
                   "a --record session")
    p.add_argument("--size", type=image_size, help="process at WxH")
    p.add_argument("--poses", type=Path, help="known T_world_left poses instead of odometry")
    p.add_argument("--no-imu", action="store_true", help="visual odometry only")
    add_loop_closure_flag(p)
    p.add_argument("--max-frames", type=int, help="only the first N pairs")
    config_option(p, LiveConfig, "depth_in_flight", type=int,
                  help="depth frames computed at once")
    config_option(p, LiveConfig, "depth_max_backlog", type=int, metavar="N",
                  help="a frame gets depth only while at most N frames, itself included, "
                  "wait for the live loop (older ones are stale); 0: any", shown="any")
    config_option(p, LiveConfig, "depth_pick", choices=("newest", "in-order"),
                  help="newest: depth starts as a frame is read, for the newest whenever the "
                  "worker has room; in-order: when the live loop takes the frame")
    config_option(p, LiveConfig, "depth_max_lag_s", "--depth-max-lag", type=float, metavar="S",
                  help="no depth while the oldest frame waiting for the live loop arrived "
                  "more than S seconds ago (its fusion would be that late); 0: any lag",
                  shown="any")
    p.add_argument("--foxglove", metavar="HOST:PORT", help="publish the images, mesh, "
                   "trajectory and status on a Foxglove WebSocket server")
    p.add_argument("--monitor", metavar="HOST:PORT", help="serve the monitor page (with the "
                   "live status, trajectory and mesh)")
    p.add_argument("--json", action="store_true", help="print summary.json")
    p.set_defaults(handler=_cmd_live)
