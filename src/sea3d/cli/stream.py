"""``sea3d stream``: H.264 over UDP to the top side, and ``sea3d stream receive`` there.

::

    sea3d stream dive.mcap --to udp://10.0.0.2:5600 --bitrate-kbps 3000 --size 960x540
    sea3d stream --left /dev/video0 --right /dev/video1 --to udp://10.0.0.2:5600
    sea3d stream receive udp://0.0.0.0:5600 --show
    sea3d stream receive udp://0.0.0.0:5600 -o topside.ts      # what came, not re-encoded
    sea3d stream receive udp://0.0.0.0:5600 -o topside.mcap    # decoded frames, sensor stamps
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import config_option, image_size, param_option
from sea3d.cli._signals import StopOnSignals

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]

_SOURCE_HELP = (
    "what to send: a session (.mcap or folder) to replay, or one camera as in 'sea3d record' "
    "(/dev/videoN, gst:PIPELINE, video:FILE, sim:MODULE:FACTORY ...); or use --left/--right"
)


def register(sub: Subcommands) -> None:
    """Add ``stream`` (send) and ``stream receive``."""
    p = sub.add_parser(
        "stream",
        help="send the cameras as H.264 over UDP (or 'stream receive' the top side)",
        description="Send: sea3d stream SOURCE --to udp://HOST:PORT [--bitrate-kbps N] "
        "[--size WxH]. Receive: sea3d stream receive udp://HOST:PORT [--show | -o OUT]. "
        "One H.264 stream, left and right side by side, in MPEG-TS over UDP (ffplay, VLC and "
        "GStreamer play it too); each frame keeps its sensor stamp and send time.",
    )
    p.add_argument("source", nargs="?", metavar="SOURCE|receive", help=_SOURCE_HELP)
    p.add_argument("url", nargs="?", metavar="URL", help="with 'receive': udp://HOST:PORT")
    snd = p.add_argument_group("sending")
    snd.add_argument("--to", metavar="udp://HOST:PORT", help="receiver address")
    snd.add_argument("--left", help="left camera (forms of 'sea3d record --left')")
    snd.add_argument("--right", help="right camera")
    from sea3d.capture.stream import StreamConfig, session_pairs

    config_option(snd, StreamConfig, "bitrate_kbps", type=float, metavar="N",
                  help="total kbit/s")
    snd.add_argument("--size", type=image_size, metavar="WxH", help="each camera's size sent")
    snd.add_argument("--fps", type=float, help="nominal frame rate (default: from the source)")
    config_option(snd, StreamConfig, "cameras", choices=("both", "left", "right"),
                  help="what to send")
    config_option(
        snd, StreamConfig, "encoder",
        choices=("auto", "libx264", "h264_nvenc", "gst", "h264_v4l2m2m", "h264_qsv"),
        help="auto: a hardware encoder when one opens here, else libx264",
    )
    config_option(snd, StreamConfig, "preset", help="libx264 preset")
    config_option(snd, StreamConfig, "keyframe_s", type=float,
                  help="seconds between keyframes")
    param_option(snd, session_pairs, "speed", type=float, help="session replay speed")
    snd.add_argument("--loop", action="store_true", help="replay the session in a loop")
    rcv = p.add_argument_group("receiving")
    rcv.add_argument(
        "--show",
        action="store_true",
        help="show the frames (an OpenCV window, or the monitor page where OpenCV has no GUI)",
    )
    rcv.add_argument(
        "--address",
        default="127.0.0.1:8080",
        help="with --show and no GUI: HOST:PORT of the monitor page (127.0.0.1:8080)",
    )
    rcv.add_argument(
        "-o",
        "--output",
        metavar="OUT",
        help=".ts or .mkv: the H.264 as received; .mcap or a folder: the decoded frames as a "
        "session with their sensor stamps",
    )
    rcv.add_argument("--rig", help="with a session output: rig.yaml stored (scaled to the size)")
    rcv.add_argument(
        "--idle-timeout",
        type=float,
        metavar="S",
        help="end after S seconds without data once the stream ran (default: keep waiting)",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_stream)


def _stream(args: argparse.Namespace) -> int:
    from sea3d.errors import ConfigError

    if args.source == "receive":
        if not args.url:
            raise ConfigError("sea3d stream receive needs the address: udp://HOST:PORT")
        return _receive(args)
    if args.url:
        raise ConfigError(f"unexpected argument {args.url!r} (did you mean --to {args.url}?)")
    return _send(args)


def _is_session(text: str) -> bool:
    p = Path(text)
    return text.lower().endswith(".mcap") or (p / "session.json").is_file()


def _send(args: argparse.Namespace) -> int:
    from sea3d.capture.spec import open_source
    from sea3d.capture.stream import StreamConfig, StreamSender, live_pairs, session_pairs
    from sea3d.errors import ConfigError

    if not args.to:
        raise ConfigError("sea3d stream needs --to udp://HOST:PORT")
    config = StreamConfig(
        url=args.to,
        bitrate_kbps=args.bitrate_kbps,
        size_px=args.size,
        fps=args.fps,
        keyframe_s=args.keyframe_s,
        encoder=args.encoder,
        preset=args.preset,
        cameras=args.cameras,
    )
    stop = threading.Event()
    if args.source and _is_session(args.source):
        if args.left or args.right:
            raise ConfigError("give a session or --left/--right, not both")
        pairs: Any = session_pairs(args.source, speed=args.speed, loop=args.loop)
        what = f"session {args.source}"
    else:
        left_spec = args.left or args.source
        if not (left_spec or args.right):
            raise ConfigError("sea3d stream needs SOURCE (a session or a camera) or --left/--right")
        left = open_source(left_spec, "left") if left_spec else None
        right = open_source(args.right, "right") if args.right else None
        if config.cameras == "both" and (left is None or right is None):
            config = StreamConfig(**{**config.__dict__, "cameras": "left" if left else "right"})
        pairs = live_pairs(left, right, stop=stop)
        what = " and ".join(str(s) for s in (left, right) if s is not None)
    sender = StreamSender(config)
    with StopOnSignals(sender.request_stop):
        print(f"streaming {what} to {config.url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        try:
            summary = sender.run(pairs, duration_s=args.duration)
        except KeyboardInterrupt:
            sender.request_stop("interrupted")
            raise
        finally:
            stop.set()
    if args.json:
        json.dump(summary.as_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        hw = " (hardware)" if summary.hardware else ""
        print(
            f"sent {summary.frames} frames of {summary.width}x{summary.height} ({summary.layout}) "
            f"with {summary.encoder}{hw} to {summary.url} in {summary.duration_s:.1f} s: "
            f"{summary.kbps:.0f} kbit/s, encode {summary.encode_ms_median:.1f} ms/frame; "
            f"{summary.stop_reason}"
        )
        for name, why in summary.encoders_tried.items():
            print(f"  encoder {name} not used: {why}")
    return 0


class _SessionOut:
    """Decoded frames into a session: stamps from the sender, rig scaled to the stream."""

    def __init__(self, path: str, rig_path: str | None) -> None:
        self.path = path
        self.rig_path = rig_path
        self.writer: Any = None
        self.written = 0
        self.skipped = 0

    def _open(self, width: int, height: int) -> None:
        from sea3d.io.session import SessionWriter

        rig_yaml = None
        if self.rig_path:
            from sea3d.io.rig_file import load_rig, rig_to_yaml
            from sea3d.stereo.planning import override_rig

            rig = load_rig(self.rig_path)
            if (rig.width, rig.height) != (width, height):
                rig = override_rig(rig, size_px=(width, height))
            rig_yaml = rig_to_yaml(rig)
        self.writer = SessionWriter(self.path, rig_yaml=rig_yaml, handle_signals=False)

    def write(self, frame: Any) -> None:
        from sea3d.errors import SessionError

        img = frame.left if frame.left is not None else frame.right
        if self.writer is None:
            self._open(img.shape[1], img.shape[0])
        try:
            if frame.left is not None:
                self.writer.write_image("left", frame.t_ns, frame.left)
            if frame.right is not None:
                self.writer.write_image("right", frame.t_ns, frame.right)
            self.written += 1
        except SessionError:
            self.skipped += 1  # e.g. stamps going back after a sender restart

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _receive(args: argparse.Namespace) -> int:
    import time

    from sea3d.capture.stream import StreamReceiver

    out = args.output
    remux = out if out and Path(out).suffix.lower() in (".ts", ".mkv") else None
    session_out = _SessionOut(out, args.rig) if out and remux is None else None

    def event(msg: str) -> None:
        print(f"sea3d: {msg}", file=sys.stderr, flush=True)

    receiver = StreamReceiver(
        args.url, idle_timeout_s=args.idle_timeout, remux_path=remux, on_event=event
    )
    show = _Viewer(receiver, args.address) if args.show else None
    t_end = None if args.duration is None else time.monotonic() + args.duration
    timer = None
    try:
        with StopOnSignals(receiver.request_stop):
            # Said only once the signals are ours: a SIGTERM sent on seeing this line stops the
            # receiver cleanly instead of killing it (it raced under load before).
            print(f"receiving on {args.url} (Ctrl-C to stop)", file=sys.stderr, flush=True)
            if t_end is not None:
                timer = threading.Timer(args.duration, receiver.request_stop,
                                        args=("duration reached",))
                timer.daemon = True
                timer.start()
            for frame in receiver.frames():
                if session_out is not None:
                    session_out.write(frame)
                if show is not None:
                    show.update(frame)
    except KeyboardInterrupt:
        receiver.request_stop("interrupted")
    finally:
        if timer is not None:
            timer.cancel()
        if session_out is not None:
            session_out.close()
        if show is not None:
            show.close()
        receiver.close()
    summary = receiver.summary()
    if session_out is not None:
        summary["session_frames_written"] = session_out.written
        summary["session_frames_skipped"] = session_out.skipped
    wrote = bool(out) and Path(out).exists()
    summary["output"] = out if wrote else None
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        lat = summary["latency_ms_median"]
        print(
            f"received {summary['frames']} frames ({summary['lost']} lost) at "
            f"{summary['kbps']:.0f} kbit/s"
            + (f", latency {lat:.0f} ms median" if lat is not None else "")
            + (f"; wrote {out}" if wrote else "; nothing written (no frames)" if out else "")
            + f"; {summary['stopped_reason']}"
        )
    return 0


class _Viewer:
    """An OpenCV window where OpenCV has a GUI, otherwise the monitor page."""

    def __init__(self, receiver: Any, address: str) -> None:
        import cv2

        self.cv2 = cv2
        self.window = False
        self.server: Any = None
        try:
            cv2.namedWindow("sea3d stream", cv2.WINDOW_NORMAL)
            self.window = True
        except cv2.error:
            from sea3d.capture.monitor import MonitorServer, parse_address

            host, port = parse_address(address)
            self.server = MonitorServer(receiver, host, port).start()
            print(
                f"this OpenCV has no GUI: frames on the monitor page {self.server.url}",
                file=sys.stderr,
                flush=True,
            )
        self.receiver = receiver

    def update(self, frame: Any) -> None:
        if not self.window:
            return
        import numpy as np

        views = [v for v in (frame.left, frame.right) if v is not None]
        img = np.hstack(views) if len(views) == 2 else views[0]
        self.cv2.imshow("sea3d stream", self.cv2.cvtColor(img, self.cv2.COLOR_RGB2BGR))
        if self.cv2.waitKey(1) & 0xFF in (ord("q"), 27):
            self.receiver.request_stop("closed the window")

    def close(self) -> None:
        if self.window:
            self.cv2.destroyAllWindows()
        if self.server is not None:
            self.server.stop()
