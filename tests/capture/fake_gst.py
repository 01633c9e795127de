"""A stand-in for ``gst-launch-1.0 ... nvv4l2h264enc ...`` (the Jetson's hardware encoder) in
tests: reads raw RGB frames from stdin and writes an AUD-delimited H.264 Annex B stream to
stdout, encoded with libx264 through PyAV, as the real pipeline's ``fdsink`` would.
``gst-inspect-1.0 ELEMENT`` succeeds for nvv4l2h264enc only."""

from __future__ import annotations

import sys
from fractions import Fraction


def inspect(argv: list[str]) -> int:
    return 0 if argv[-1] == "nvv4l2h264enc" else 1


def launch(argv: list[str]) -> int:
    import av
    import numpy as np

    opts = dict(a.split("=", 1) for a in argv if "=" in a and not a.startswith("video/"))
    w, h = int(opts["width"]), int(opts["height"])
    num, den = (int(v) for v in opts["framerate"].split("/"))
    ctx = av.CodecContext.create("libx264", "w")
    ctx.width, ctx.height, ctx.pix_fmt = w, h, "yuv420p"
    ctx.time_base = Fraction(den, num)
    ctx.options = {"preset": "ultrafast", "tune": "zerolatency", "x264-params": "aud=1"}
    ctx.open()
    out = sys.stdout.buffer
    n = w * h * 3
    k = 0
    while True:
        raw = sys.stdin.buffer.read(n)
        if len(raw) < n:
            break
        frame = av.VideoFrame.from_ndarray(np.frombuffer(raw, np.uint8).reshape(h, w, 3), "rgb24")
        frame = frame.reformat(format="yuv420p")
        frame.pts = k
        k += 1
        for p in ctx.encode(frame):
            out.write(bytes(p))
        out.flush()
    for p in ctx.encode(None):
        out.write(bytes(p))
    out.flush()
    return 0


if __name__ == "__main__":
    tool = sys.argv[1]
    sys.exit(inspect(sys.argv[2:]) if tool == "inspect" else launch(sys.argv[2:]))
