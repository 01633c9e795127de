"""``sea3d record`` (cameras, IMU and echosounder into a session) and ``sea3d monitor``
(replay a session on the live monitor page)."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import (
    add_output,
    add_stall_options,
    check_session_output,
    config_default,
    config_option,
    param_option,
    stall_limits,
)
from sea3d.cli._foxglove import FOXGLOVE_HELP as _FOXGLOVE_HELP
from sea3d.cli._signals import StopOnSignals

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]

_SOURCE_HELP = (
    "source: /dev/videoN, N (camera index), gst:PIPELINE, folder:DIR, video:FILE, "
    "session:PATH[#STREAM], sim:MODULE:FACTORY"
)


def register(sub: Subcommands) -> None:
    """Add ``record`` and ``monitor`` to the top-level subparsers."""
    rec = sub.add_parser(
        "record",
        help="record stereo cameras (+ IMU, echosounder) into a session",
        description="Record two cameras and optional IMU and echosounder into an MCAP file or "
        "a folder session. Ctrl-C or SIGTERM stops cleanly; a summary is printed at the end.",
    )
    rec.add_argument("--left", required=True, help=f"left camera {_SOURCE_HELP}")
    rec.add_argument("--right", required=True, help="right camera, same forms as --left")
    rec.add_argument("--imu", help="IMU: mti:PORT[@BAUD], session:PATH or sim:MODULE:FACTORY")
    rec.add_argument("--sonar", help="echosounder: ping:PORT[@BAUD], session:PATH or sim:...")
    add_output(rec, required=True, help="output session: *.mcap or a new folder")
    rec.add_argument("--format", choices=("mcap", "folder"), help="default: from --output")
    rec.add_argument("--duration", type=float, help="seconds to record (default: until stopped)")
    rec.add_argument("--rig", help="rig.yaml stored with the session (and its capture settings)")
    from sea3d.capture.monitor import SessionPlayer
    from sea3d.capture.recorder import RecorderConfig
    from sea3d.capture.spec import open_source

    config_option(
        rec, RecorderConfig, "image_encoding",
        choices=("jxl", "png", "jpeg", "raw"),
        help="jxl: JPEG XL lossless (2 x 30 fps at 1080p on 2 cores, about 120 GB/h); "
        "png: lossless, about 5x the CPU; jpeg: lossy; raw: sensor_msgs/Image in LZ4 chunks "
        "(MCAP only)",
    )
    rec.add_argument(
        "--chunk-compression",
        choices=("lz4", "zstd", "none"),
        help="MCAP chunk compression (default: lz4 for raw images, none for encoded ones)",
    )
    config_option(rec, RecorderConfig, "png_compression", type=int, help="zlib level 0..9")
    config_option(rec, RecorderConfig, "jpeg_quality", type=int, help="0..100")
    config_option(rec, RecorderConfig, "queue_frames", "--queue", dest="queue", type=int,
                  help="frames buffered before dropping")
    config_option(rec, RecorderConfig, "encoder_threads", "--encoders", dest="encoders",
                  type=int, help="encoder threads")
    free_gb = config_default(RecorderConfig, "min_free_bytes") / 1e9  # the reserve, in GB
    rec.add_argument(
        "--min-free-gb",
        type=float,
        default=free_gb,
        help=f"stop when free disk space falls below this (default {free_gb:.2f} GB)",
    )
    param_option(rec, open_source, "replay_speed", type=float,
                 help="pacing of replay sources: 1 real time, 0 as fast as possible")
    add_stall_options(rec)
    rec.add_argument(
        "--block",
        action="store_true",
        help="replay sources wait for the writer instead of dropping frames",
    )
    rec.add_argument(
        "--sync",
        action="store_true",
        help="configure camera hardware sync with v4l2-ctl first (settings from "
        "the rig's capture section, else the paper's)",
    )
    rec.add_argument(
        "--monitor", metavar="HOST:PORT", help="serve the live monitor page (e.g. 127.0.0.1:8080)"
    )
    rec.add_argument("--foxglove", metavar="HOST:PORT", help=_FOXGLOVE_HELP)
    rec.add_argument("--json", action="store_true", help="print the summary as JSON")
    rec.set_defaults(handler=_record)

    mon = sub.add_parser(
        "monitor",
        help="replay a session on the monitor web page",
        description="Serve the monitor page (left/right images, disparity preview, figures) "
        "for a recorded session, replayed in a loop.",
    )
    mon.add_argument("session", help="session: .mcap file or folder")
    mon.add_argument(
        "--address",
        default="127.0.0.1:8080",
        help="HOST:PORT to listen on (default 127.0.0.1:8080, loopback only)",
    )
    param_option(mon, SessionPlayer, "speed", type=float, help="replay speed (1 = real time)")
    mon.add_argument("--once", action="store_true", help="play once instead of looping")
    mon.add_argument("--duration", type=float, help="stop serving after this many seconds")
    mon.add_argument("--foxglove", metavar="HOST:PORT", help=_FOXGLOVE_HELP)
    mon.add_argument(
        "--no-browser",
        action="store_true",
        help="with --foxglove: only the Foxglove WebSocket server, no monitor page",
    )
    mon.set_defaults(handler=_monitor)


def _print_summary(summary: Any, as_json: bool) -> None:
    if as_json:
        json.dump(summary.as_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return
    hours = summary.duration_s / 3600.0
    rate = summary.bytes_on_disk / hours / 1e9 if hours > 0 else 0.0
    print(
        f"recorded {summary.path} ({summary.format}) for {summary.duration_s:.1f} s: "
        f"{summary.stop_reason}"
    )
    for stream, n in summary.frames.items():
        fps = summary.fps.get(stream)
        extra = f", {fps:.1f} fps" if fps is not None else ""
        print(
            f"  {stream:<6} {n:>7} written, {summary.dropped[stream]:>5} dropped "
            f"(of {summary.captured[stream]} captured){extra}"
        )
    print(f"  {summary.bytes_on_disk / 1e6:.1f} MB on disk ({rate:.1f} GB/h)")
    for err in summary.errors:
        print(f"  error: {err}")


def _record(args: argparse.Namespace) -> int:
    import dataclasses
    import math

    from sea3d.capture.recorder import Recorder, RecorderConfig
    from sea3d.capture.sources import SessionReplaySource
    from sea3d.capture.spec import open_source
    from sea3d.errors import ConfigError

    # Everything that can be checked without the cameras is checked first: opening them, or
    # configuring their sync, takes seconds and changes the devices' state.
    check_session_output(args.out, "-o/--output", args.format)
    if not (math.isfinite(args.min_free_gb) and args.min_free_gb >= 0):
        raise ConfigError(f"--min-free-gb must be >= 0 and finite, got {args.min_free_gb:g}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(f"--duration must be > 0 seconds, got {args.duration:g}")
    config = RecorderConfig(
        out_path=Path(args.out),
        format=args.format,
        duration_s=args.duration,
        image_encoding=args.image_encoding,
        png_compression=args.png_compression,
        jpeg_quality=args.jpeg_quality,
        queue_frames=args.queue,
        encoder_threads=args.encoders,
        block_when_full=args.block,
        min_free_bytes=int(args.min_free_gb * 1e9),
        chunk_compression=args.chunk_compression,
        **stall_limits(args),
    )
    rig_yaml = None
    if args.rig:
        from sea3d.io.rig_file import read_rig_text, rig_from_yaml

        rig_yaml = read_rig_text(args.rig)  # size-limited, decoded, clear errors
        rig_from_yaml(rig_yaml, args.rig)  # a rig that cannot be used is refused before recording
    if args.sync:
        from sea3d.capture.v4l2_sync import PAPER_SYNC, configure_sync, sync_settings_from_rig_yaml

        settings = sync_settings_from_rig_yaml(rig_yaml, where=args.rig) if rig_yaml else None
        readback = configure_sync(settings or PAPER_SYNC)
        print(f"camera sync configured: {readback}", file=sys.stderr)
    sources = {
        "left": open_source(args.left, "left", replay_speed=args.replay_speed),
        "right": open_source(args.right, "right", replay_speed=args.replay_speed),
    }
    left = sources["left"]
    if rig_yaml is None and isinstance(left, SessionReplaySource):  # session replay: keep its rig
        from sea3d.io.session import open_session

        with open_session(left.path) as replayed:
            rig_yaml = replayed.rig_yaml
    if args.imu:
        sources["imu"] = open_source(args.imu, "imu", replay_speed=args.replay_speed)
    if args.sonar:
        sources["sonar"] = open_source(args.sonar, "sonar", replay_speed=args.replay_speed)
    config = dataclasses.replace(config, rig_yaml=rig_yaml)
    recorder = Recorder(config, sources)
    server = None
    if args.monitor:
        from sea3d.capture.monitor import MonitorServer, parse_address

        host, port = parse_address(args.monitor)
        server = MonitorServer(recorder, host, port).start()
        print(f"monitor at {server.url}", file=sys.stderr, flush=True)
    foxglove = None
    if args.foxglove:
        from sea3d.cli._foxglove import start_foxglove

        foxglove = start_foxglove(args.foxglove, recorder, rig_yaml=rig_yaml, required=False)
    try:
        with StopOnSignals(recorder.request_stop):
            summary = recorder.run()
    finally:
        if server is not None:
            server.stop()
        if foxglove is not None:
            foxglove[1].stop()
            foxglove[0].stop()
    _print_summary(summary, args.json)
    return 1 if summary.errors else 0


def _monitor(args: argparse.Namespace) -> int:
    from sea3d.capture.monitor import MonitorServer, SessionPlayer, parse_address
    from sea3d.errors import ConfigError

    if args.no_browser and not args.foxglove:
        raise ConfigError("--no-browser needs --foxglove HOST:PORT (otherwise nothing is served)")
    host, port = parse_address(args.address)
    player = SessionPlayer(args.session, speed=args.speed, loop=not args.once).start()
    done = threading.Event()
    foxglove = None
    try:
        if args.foxglove:
            from sea3d.cli._foxglove import start_foxglove

            foxglove = start_foxglove(
                args.foxglove, player, rig_yaml=player.session.rig_yaml, replay=player
            )
        with StopOnSignals(lambda _r: done.set()):
            if args.no_browser:
                print("serving Foxglove only (Ctrl-C to stop)", file=sys.stderr, flush=True)
                done.wait(args.duration)
            else:
                with MonitorServer(player, host, port) as server:
                    print(f"monitor at {server.url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
                    done.wait(args.duration)
    finally:
        if foxglove is not None:
            foxglove[1].stop()
            foxglove[0].stop()
        player.stop()
    return 0
