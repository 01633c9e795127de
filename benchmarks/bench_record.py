"""Recording benchmark: 1920x1080 stereo from a replay source, both layouts, on this machine.

Prints, per layout and encoding:

- the sustained frame rate with zero drops (replay waits for the writer: ``block_when_full``),
- a run paced at the paper's 2 cameras x 30 fps, with its drops counted,
- bytes per hour at 2 x 30 fps, next to the paper's 140 GB/h (PNG) and 15 GB/h (ROS 2 bag),
- read-back throughput in stereo pairs per second,

and, in the same process on the same frames, two references: a plain single-threaded
``cv2.imwrite`` loop (what a simple recording script does) for writing, and the official
``mcap`` reader + rosbags deserialiser + ``cv2.imdecode`` for reading MCAP back.

Frames: the real Sea3D lake frames in ``$SEA3D_TEST_DATA/underwater/sea3d_field_left`` (left =
frame k, right = frame k+1), else synthetic textured frames. Usage::

    python benchmarks/bench_record.py            # 10 s per run
    python benchmarks/bench_record.py --duration 60
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from sea3d.capture.recorder import Recorder, RecorderConfig
from sea3d.capture.sources import ArraySource
from sea3d.io.session import open_session

PAPER_PNG_GB_PER_H = 140.0
PAPER_BAG_GB_PER_H = 15.0
PAPER_FPS = 30.0


def load_frames(n: int) -> tuple[list[np.ndarray], str]:
    root = Path(
        os.environ.get(
            "SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
        )
    )
    folder = root / "underwater" / "sea3d_field_left"
    files = sorted(folder.glob("*.jpg"))[: n + 1] if folder.is_dir() else []
    if len(files) >= 2:
        imgs = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
        imgs = [cv2.resize(i, (1920, 1080)) if i.shape[:2] != (1080, 1920) else i for i in imgs]
        return imgs, f"real Sea3D lake frames ({folder})"
    rng = np.random.default_rng(0)
    imgs = []
    for _ in range(n + 1):
        noise = rng.normal(0, 1, size=(135, 240, 3)).astype(np.float32)
        img = cv2.resize(cv2.GaussianBlur(noise, (0, 0), 3), (1920, 1080))
        img = (img - img.min()) / (np.ptp(img) + 1e-9) * 200 + rng.normal(0, 4, size=img.shape)
        imgs.append(np.clip(img, 0, 255).astype(np.uint8))
    return imgs, "synthetic textured frames"


def record(
    out: Path,
    left: list[np.ndarray],
    right: list[np.ndarray],
    *,
    duration_s: float,
    encoding: str,
    block: bool,
    speed: float,
):
    config = RecorderConfig(
        out_path=out,
        duration_s=duration_s,
        image_encoding=encoding,
        block_when_full=block,
        min_free_bytes=2 * 1024**3,
        encoder_threads=2,
        queue_frames=16,
    )
    sources = {
        "left": ArraySource(left, rate_hz=PAPER_FPS, speed=speed),
        "right": ArraySource(right, rate_hz=PAPER_FPS, speed=speed),
    }
    return Recorder(config, sources).run()


def read_back_pairs_per_s(path: Path, max_pairs: int) -> float:
    with open_session(path) as s:
        t0 = time.perf_counter()
        n = 0
        for _pair in s.pairs():
            n += 1
            if n >= max_pairs:
                break
        return n / (time.perf_counter() - t0)


def reference_read_mcap(path: Path, max_pairs: int) -> float:
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t0 = time.perf_counter()
    n = 0
    with open(path, "rb") as f:
        for schema, _ch, msg in make_reader(f).iter_messages(
            topics=["/cam/left/image", "/cam/right/image"]
        ):
            m = store.deserialize_cdr(msg.data, schema.name)
            cv2.imdecode(np.asarray(m.data), cv2.IMREAD_UNCHANGED)
            n += 1
            if n >= 2 * max_pairs:
                break
    return n / 2 / (time.perf_counter() - t0)


def reference_imwrite_fps(
    out: Path, left: list[np.ndarray], right: list[np.ndarray], duration_s: float
) -> float:
    """Single-threaded cv2.imwrite of left and right PNGs, as fast as it goes."""
    (out / "left").mkdir(parents=True)
    (out / "right").mkdir()
    t0 = time.perf_counter()
    k = 0
    while time.perf_counter() - t0 < duration_s:
        t_ns = k * 33_333_333
        cv2.imwrite(
            str(out / "left" / f"{t_ns}.png"),
            cv2.cvtColor(left[k % len(left)], cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_PNG_COMPRESSION, 1],
        )
        cv2.imwrite(
            str(out / "right" / f"{t_ns}.png"),
            cv2.cvtColor(right[k % len(right)], cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_PNG_COMPRESSION, 1],
        )
        k += 1
    return k / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--duration", type=float, default=10.0, help="seconds per recording run (issue: 60)"
    )
    ap.add_argument("--frames", type=int, default=10, help="distinct replay frames")
    ap.add_argument("--read-pairs", type=int, default=100, help="pairs read back per measurement")
    ap.add_argument("--repeats", type=int, default=3, help="read-back repeats (median)")
    ap.add_argument("--tmp", default=None, help="scratch folder (default: system temp)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the tail of unpaired frames at stop is expected

    imgs, origin = load_frames(args.frames)
    left, right = imgs[:-1], imgs[1:]
    print(
        f"frames: {origin}, {left[0].shape[1]}x{left[0].shape[0]}, {len(left)} distinct; "
        f"{os.cpu_count()} CPU cores (load average {os.getloadavg()[0]:.1f} before start); "
        f"{args.duration:g} s per run"
    )
    scratch = Path(tempfile.mkdtemp(prefix="sea3d_bench_", dir=args.tmp))
    try:
        ref_fps = reference_imwrite_fps(scratch / "ref", left, right, args.duration)
        shutil.rmtree(scratch / "ref")
        print(f"\nreference: single-threaded cv2.imwrite PNG loop: {ref_fps:.1f} stereo fps\n")
        header = (
            f"{'layout':<8}{'enc':<6}{'mode':<22}{'fps':>7}{'drops':>7}{'MB/pair':>9}"
            f"{'GB/h@2x30':>11}{'paper GB/h':>11}{'vs ref':>8}{'read pairs/s':>14}"
        )
        print(header)
        print("-" * len(header))
        for layout, enc in (("folder", "png"), ("mcap", "png"), ("mcap", "jpeg")):
            out = scratch / ("s.mcap" if layout == "mcap" else "s_dir")
            summ = record(
                out, left, right, duration_s=args.duration, encoding=enc, block=True, speed=0
            )
            pairs = min(summ.frames["left"], summ.frames["right"])
            per_pair = summ.bytes_on_disk / max(pairs, 1)
            gb_h = per_pair * PAPER_FPS * 3600 / 1e9
            paper = PAPER_PNG_GB_PER_H if enc == "png" else PAPER_BAG_GB_PER_H
            reads = [read_back_pairs_per_s(out, args.read_pairs) for _ in range(args.repeats)]
            fps = pairs / summ.duration_s  # stereo pairs per second
            vs_ref = f"{fps / ref_fps:.2f}" if enc == "png" else "-"  # the reference is PNG
            drops = summ.dropped["left"] + summ.dropped["right"]
            print(
                f"{layout:<8}{enc:<6}{'max, zero drops':<22}{fps:>7.1f}{drops:>7}"
                f"{per_pair / 1e6:>9.2f}{gb_h:>11.1f}{paper:>11.0f}{vs_ref:>8}"
                f"{statistics.median(reads):>14.1f}"
            )
            if layout == "mcap" and enc == "png":
                refs = [reference_read_mcap(out, args.read_pairs) for _ in range(args.repeats)]
                print(
                    f"{'':<36}read-back reference (mcap reader + rosbags + imdecode): "
                    f"{statistics.median(refs):.1f} pairs/s; ours/ref "
                    f"{statistics.median(reads) / statistics.median(refs):.2f}"
                )
            shutil.rmtree(out) if out.is_dir() else out.unlink()
            summ = record(
                out, left, right, duration_s=args.duration, encoding=enc, block=False, speed=1.0
            )
            drops = summ.dropped["left"] + summ.dropped["right"]
            captured = summ.captured["left"] + summ.captured["right"]
            print(
                f"{layout:<8}{enc:<6}{'paced 2x30 fps live':<22}{summ.fps['left']:>7.1f}{drops:>7}"
                f"{'':>9}{'':>11}{'':>11}{'':>8}   ({drops} of {captured} frames dropped)"
            )
            shutil.rmtree(out) if out.is_dir() else out.unlink()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
