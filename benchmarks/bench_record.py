"""Recording benchmark: which lossless encoding keeps up with 2 x 30 fps at 1080p on 2 cores.

Three parts, each against a reference in the same process on the same frames:

1. ``--codecs``: CPU-seconds per 1920x1080 frame to encode and decode, size, bit-exactness and
   GB per hour at 2 x 30 fps for every lossless option (PNG at several zlib levels, raw images
   in LZ4 or Zstandard chunks, QOI, JPEG XL, JPEG-LS, HTJ2K, WebP, Bayer raw), JPEG q95 as the
   lossy reference, and the capacity this implies on 2 cores. CPU time (``time.process_time``)
   is robust when other jobs share the machine; wall time is not.
2. ``--record``: the real recorder (capture threads, encoder pool, MCAP writer) for
   ``--duration`` seconds paced at the paper's 2 x 30 fps per encoding, with its drops, the
   load average and the recorder's CPU-seconds per frame (from ``getrusage``); and the
   zero-drop maximum rate (replay waits for the writer). Reference: a single-threaded
   ``cv2.imwrite`` PNG loop, and the paper's 2 x 30 fps and 140 GB/h.
3. ``--read``: read-back pairs per second, ours against the official ``mcap`` reader +
   rosbags + ``cv2.imdecode``/imagecodecs.

Frames: the real Sea3D lake frames in ``$SEA3D_TEST_DATA/underwater/sea3d_field_left`` (left =
frame k, right = frame k+1), else synthetic textured frames. Usage::

    nice python benchmarks/bench_record.py --codecs
    nice python benchmarks/bench_record.py --record --duration 60
    nice python benchmarks/bench_record.py                # all three, 10 s runs
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from sea3d.capture.recorder import Recorder, RecorderConfig
from sea3d.capture.sources import ArraySource
from sea3d.io.session import open_session

PAPER_PNG_GB_PER_H = 140.0
PAPER_BAG_GB_PER_H = 15.0
PAPER_FPS = 30.0
CORES = 2


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


def bayer_rggb(rgb: np.ndarray) -> np.ndarray:
    """The RGGB mosaic a Bayer sensor would deliver for this frame (one byte per pixel)."""
    out = np.empty(rgb.shape[:2], np.uint8)
    out[0::2, 0::2] = rgb[0::2, 0::2, 0]
    out[0::2, 1::2] = rgb[0::2, 1::2, 1]
    out[1::2, 0::2] = rgb[1::2, 0::2, 1]
    out[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return out


# --------------------------------------------------------------------------- 1. codecs
Codec = tuple[Callable[[np.ndarray], bytes], Callable[[bytes, np.ndarray], np.ndarray]]


def _codecs() -> dict[str, tuple[str, Codec]]:
    import imagecodecs as ic
    import lz4.frame
    import zstandard

    from sea3d.io.session.common import decode_image, encode_image

    zc, zd = zstandard.ZstdCompressor(level=1), zstandard.ZstdDecompressor()

    def cv_png(level: int) -> Codec:
        return (
            lambda a: encode_image(a, "png", png_compression=level),
            lambda b, a: decode_image(b, "bench"),
        )

    def raw(comp: Callable[[bytes], bytes], dec: Callable[[bytes], bytes]) -> Codec:
        return (
            lambda a: comp(a.tobytes()),
            lambda b, a: np.frombuffer(dec(b), np.uint8).reshape(a.shape),
        )

    return {
        "PNG zlib 1, Up filter (sea3d png)": ("rgb", cv_png(1)),
        "PNG zlib 0 (stored), Up filter": ("rgb", cv_png(0)),
        "PNG zlib 3, Up filter": ("rgb", cv_png(3)),
        "PNG zlib 6, Up filter": ("rgb", cv_png(6)),
        "raw RGB + LZ4 chunk (sea3d raw)": ("rgb", raw(lz4.frame.compress, lz4.frame.decompress)),
        "raw RGB + Zstandard 1 chunk": ("rgb", raw(zc.compress, zd.decompress)),
        "QOI": ("rgb", (lambda a: bytes(ic.qoi_encode(a)), lambda b, a: ic.qoi_decode(b))),
        "JPEG XL lossless effort 1 (sea3d jxl)": (
            "rgb",
            (lambda a: encode_image(a, "jxl"), lambda b, a: decode_image(b, "bench")),
        ),
        "JPEG XL lossless effort 2": (
            "rgb",
            (
                lambda a: encode_image(a, "jxl", jxl_effort=2),
                lambda b, a: decode_image(b, "bench"),
            ),
        ),
        "JPEG-LS (CharLS)": (
            "rgb",
            (lambda a: bytes(ic.jpegls_encode(a)), lambda b, a: ic.jpegls_decode(b)),
        ),
        "HTJ2K reversible": (
            "rgb",
            (lambda a: bytes(ic.htj2k_encode(a)), lambda b, a: ic.htj2k_decode(b)),
        ),
        "WebP lossless, method 0": (
            "rgb",
            (
                lambda a: bytes(ic.webp_encode(a, lossless=True, method=0, level=0)),
                lambda b, a: ic.webp_decode(b),
            ),
        ),
        "Bayer RGGB raw + LZ4 chunk": ("bayer", raw(lz4.frame.compress, lz4.frame.decompress)),
        "Bayer RGGB raw + Zstandard 1 chunk": ("bayer", raw(zc.compress, zd.decompress)),
        "Bayer RGGB as grey PNG zlib 1": ("bayer", cv_png(1)),
        "JPEG q95 (lossy reference)": (
            "rgb",
            (
                lambda a: cv2.imencode(
                    ".jpg", cv2.cvtColor(a, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95]
                )[1].tobytes(),
                lambda b, a: cv2.cvtColor(
                    cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB
                ),
            ),
        ),
    }


def bench_codecs(frames: list[np.ndarray], repeats: int) -> None:
    print(
        "\n1. CPU-seconds per 1920x1080 frame (median of "
        f"{len(frames)} frames x {repeats}), single thread"
    )
    header = (
        f"{'encoding':<40}{'enc ms':>8}{'dec ms':>8}{'MB/frame':>10}{'GB/h 2x30':>11}"
        f"{'exact':>7}{'2-core fps':>12}{'vs PNG 1':>10}"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for name, (kind, (enc, dec)) in _codecs().items():
        src = frames if kind == "rgb" else [bayer_rggb(f) for f in frames]
        enc_t, dec_t, sizes, exact = [], [], [], True
        for _ in range(repeats):
            for a in src:
                t = time.process_time()
                b = enc(a)
                enc_t.append(time.process_time() - t)
                t = time.process_time()
                back = dec(b, a)
                dec_t.append(time.process_time() - t)
                sizes.append(len(b))
                exact &= bool(np.array_equal(np.asarray(back).reshape(a.shape), a))
        e, d, mb = statistics.median(enc_t), statistics.median(dec_t), statistics.median(sizes)
        rows.append((name, e, d, mb, exact))
    png_e = rows[0][1]
    for name, e, d, mb, exact in rows:
        gb_h = mb * 2 * PAPER_FPS * 3600 / 1e9
        # Two cores encode 2 / e frames per second; a stereo pair is two frames.
        cap = CORES / e / 2
        print(
            f"{name:<40}{e * 1e3:>8.1f}{d * 1e3:>8.1f}{mb / 1e6:>10.2f}{gb_h:>11.0f}"
            f"{'yes' if exact else 'NO':>7}{cap:>12.1f}{png_e / e:>10.2f}"
        )
    print(
        f"(paper: PNG {PAPER_PNG_GB_PER_H:.0f} GB/h, ROS 2 bag {PAPER_BAG_GB_PER_H:.0f} GB/h, "
        f"2 x {PAPER_FPS:.0f} fps on a 12-core Orin; '2-core fps' = stereo pairs per second "
        "two cores could encode, before capture and writing costs)"
    )


# --------------------------------------------------------------------------- 2. recorder
def record(
    out: Path,
    left: list[np.ndarray],
    right: list[np.ndarray],
    *,
    duration_s: float,
    encoding: str,
    block: bool,
    speed: float,
) -> tuple[object, float]:
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
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    summary = Recorder(config, sources).run()
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return summary, cpu


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
        for side, imgs in (("left", left), ("right", right)):
            cv2.imwrite(
                str(out / side / f"{t_ns}.png"),
                cv2.cvtColor(imgs[k % len(imgs)], cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_PNG_COMPRESSION, 1],
            )
        k += 1
    return k / (time.perf_counter() - t0)


def bench_record(
    scratch: Path,
    left: list[np.ndarray],
    right: list[np.ndarray],
    duration: float,
    runs: list[tuple[str, str]],
    modes: list[str],
) -> None:
    ref_fps = reference_imwrite_fps(scratch / "ref", left, right, min(duration, 10.0))
    shutil.rmtree(scratch / "ref")
    print(
        f"\n2. the recorder, {duration:g} s per paced run (20 s at most for the maximum rate); "
        "reference: a single-threaded cv2.imwrite "
        f"PNG loop reaches {ref_fps:.1f} stereo fps"
    )
    header = (
        f"{'layout':<8}{'encoding':<9}{'mode':<22}{'fps':>7}{'drops':>7}{'load':>6}"
        f"{'CPU ms/frame':>14}{'2-core fps':>12}{'MB/pair':>9}{'GB/h 2x30':>11}{'paper':>7}"
    )
    print(header)
    print("-" * len(header))
    for layout, enc in runs:
        for mode in modes:
            out = scratch / ("s.mcap" if layout == "mcap" else "s_dir")
            paced = mode.startswith("paced")
            load0 = os.getloadavg()[0]
            summ, cpu = record(
                out,
                left,
                right,
                duration_s=duration if paced else min(duration, 20.0),
                encoding=enc,
                block=not paced,
                speed=1.0 if paced else 0.0,
            )
            load = (load0 + os.getloadavg()[0]) / 2
            frames = summ.frames["left"] + summ.frames["right"]  # type: ignore[attr-defined]
            pairs = min(summ.frames["left"], summ.frames["right"])  # type: ignore[attr-defined]
            drops = sum(summ.dropped.values())  # type: ignore[attr-defined]
            per_pair = summ.bytes_on_disk / max(pairs, 1)  # type: ignore[attr-defined]
            gb_h = per_pair * PAPER_FPS * 3600 / 1e9
            cpu_frame = cpu / max(frames, 1)
            with open_session(out) as s:  # honest counts: what the summary says is readable
                assert s.stamps("left").size == summ.frames["left"]  # type: ignore[attr-defined]
            print(
                f"{layout:<8}{enc:<9}{mode:<22}{pairs / summ.duration_s:>7.1f}{drops:>7}"  # type: ignore[attr-defined]
                f"{load:>6.1f}{cpu_frame * 1e3:>14.1f}{CORES / cpu_frame / 2:>12.1f}"
                f"{per_pair / 1e6:>9.2f}{gb_h:>11.0f}{PAPER_PNG_GB_PER_H:>7.0f}"
            )
            shutil.rmtree(out) if out.is_dir() else out.unlink()
    print(
        "(load: 1-minute load average during the run; '2-core fps' = 2 CPU-seconds per second "
        "divided by the recorder's CPU-seconds per stereo pair, i.e. the rate two idle cores "
        "sustain)"
    )


# --------------------------------------------------------------------------- 3. read back
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
    import imagecodecs
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t0 = time.perf_counter()
    n = 0
    with open(path, "rb") as f:
        for schema, _ch, msg in make_reader(f, validate_crcs=True).iter_messages(
            topics=["/cam/left/image", "/cam/right/image"]
        ):
            m = store.deserialize_cdr(msg.data, schema.name)
            if m.format == "jxl":
                imagecodecs.jpegxl_decode(bytes(m.data), numthreads=1)
            else:
                cv2.imdecode(np.asarray(m.data), cv2.IMREAD_UNCHANGED)
            n += 1
            if n >= 2 * max_pairs:
                break
    return n / 2 / (time.perf_counter() - t0)


def bench_read(
    scratch: Path, left: list[np.ndarray], right: list[np.ndarray], pairs: int, repeats: int
) -> None:
    from sea3d.io.session import SessionWriter

    print(f"\n3. read-back, {pairs} pairs, median of {repeats}")
    for enc in ("jxl", "png"):
        out = scratch / f"read_{enc}.mcap"
        with SessionWriter(out, image_encoding=enc) as w:
            for k in range(pairs):
                w.write_stereo(k * 33_333_333, left[k % len(left)], right[k % len(right)])
        ours = statistics.median(read_back_pairs_per_s(out, pairs) for _ in range(repeats))
        ref = statistics.median(reference_read_mcap(out, pairs) for _ in range(repeats))
        print(
            f"  {enc}: sea3d reader {ours:.1f} pairs/s (2 decoder threads, every CRC checked); "
            f"official mcap reader + rosbags + one-thread decode {ref:.1f} pairs/s; "
            f"ratio {ours / ref:.2f}"
        )
        out.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--codecs", action="store_true", help="part 1: codec CPU and size table")
    ap.add_argument("--record", action="store_true", help="part 2: the recorder")
    ap.add_argument("--read", action="store_true", help="part 3: read-back")
    ap.add_argument(
        "--runs",
        default="mcap:jxl,folder:jxl,mcap:png,mcap:raw",
        help="part 2: layout:encoding pairs (default: %(default)s)",
    )
    ap.add_argument(
        "--paced-only", action="store_true", help="part 2: only the runs paced at 2 x 30 fps"
    )
    ap.add_argument("--duration", type=float, default=10.0, help="seconds per recorder run")
    ap.add_argument("--frames", type=int, default=10, help="distinct frames")
    ap.add_argument("--repeats", type=int, default=3, help="repeats (medians)")
    ap.add_argument("--read-pairs", type=int, default=40, help="pairs per read-back run")
    ap.add_argument(
        "--noise",
        type=float,
        default=0.0,
        help="add Gaussian noise of this sigma (grey levels) to the frames, as sensor noise",
    )
    ap.add_argument("--tmp", default=None, help="scratch folder (default: system temp)")
    args = ap.parse_args()
    if not (args.codecs or args.record or args.read):
        args.codecs = args.record = args.read = True
    logging.basicConfig(level=logging.ERROR)  # the tail of unpaired frames at stop is expected
    imgs, origin = load_frames(args.frames)
    if args.noise > 0:
        rng = np.random.default_rng(0)
        imgs = [
            np.clip(i + rng.normal(0.0, args.noise, i.shape), 0, 255).astype(np.uint8)
            for i in imgs
        ]
        origin += f", with Gaussian noise of sigma {args.noise:g} added"
    left, right = imgs[:-1], imgs[1:]
    print(
        f"frames: {origin}, {left[0].shape[1]}x{left[0].shape[0]}, {len(left)} distinct; "
        f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f} at the start "
        "(the machine is shared: wall-clock rates are lower than on a quiet one)"
    )
    scratch = Path(tempfile.mkdtemp(prefix="sea3d_bench_", dir=args.tmp))
    try:
        if args.codecs:
            bench_codecs(left[:6], args.repeats)
        if args.record:
            runs = [tuple(r.split(":", 1)) for r in args.runs.split(",")]
            modes = ["paced 2 x 30 fps"] + ([] if args.paced_only else ["max, zero drops"])
            bench_record(scratch, left, right, args.duration, runs, modes)  # type: ignore[arg-type]
        if args.read:
            bench_read(scratch, left, right, args.read_pairs, args.repeats)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
