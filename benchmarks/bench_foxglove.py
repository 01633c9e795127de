"""Foxglove live publishing: messages per second sustained for both 1080p cameras.

A client of the Foxglove WebSocket protocol runs in a second process (websocket-client,
subscribed to ``/cam/left/image`` and ``/cam/right/image``) and counts what arrives; this
process publishes the left and right frames of a stereo pair in turn, as fast as it can, for
``--seconds``. Printed, median of ``--repeats`` runs:

- ours: the live path, :class:`FoxgloveBridge` polling a provider that always has a new pair
  and :class:`FoxglovePublisher` encoding JPEG (quality 80, left and right in two threads)
  from the 1920x1080 RGB frames, at full size and at the live view's default 960 px width;
- reference, same frames and server: the foxglove-sdk channel fed with JPEG bytes encoded
  beforehand (the transport alone: what the server and the link carry without encoding);

as messages per second received by the client (and per camera), MB/s, and this process's CPU
seconds per second (2 cores means at most 2.0).

Frames: the real Sea3D lake frames of ``$SEA3D_TEST_DATA/underwater/sea3d_field_left``, else
synthetic.

``--mesh V``: the ``/mesh`` message of a live mesh update instead: a marching-cubes mesh of
about V vertices with colours (a sphere from Open3D, subdivided), encoded as
``foxglove.SceneUpdate`` bytes by ours (:func:`sea3d.io.foxglove_msgs.mesh_scene`, from the
arrays) and by the reference, the foxglove-sdk's own message built from one ``Point3`` and
one ``Color`` per vertex, then encoded by the SDK (what ``mesh_scene`` did before); CPU
seconds per message, median of ``--repeats``, and whether the two decode to the same
message. Usage::

    python benchmarks/bench_foxglove.py               # 5 s per run, 3 repeats
    python benchmarks/bench_foxglove.py --mesh 100000 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sea3d.capture.foxglove_live import FoxgloveConfig, FoxglovePublisher
from sea3d.io import foxglove_msgs as fm

CLIENT = r"""
import json, struct, sys, time, websocket
url, seconds = sys.argv[1], float(sys.argv[2])
ws = websocket.create_connection(url, subprotocols=["foxglove.sdk.v1"], timeout=10)
chans = {}
while len(chans) < 2:
    m = ws.recv()
    if isinstance(m, str):
        msg = json.loads(m)
        if msg["op"] == "advertise":
            for c in msg["channels"]:
                if c["topic"] in ("/cam/left/image", "/cam/right/image"):
                    chans[c["topic"]] = c["id"]
subs = [{"id": k + 1, "channelId": cid} for k, cid in enumerate(chans.values())]
ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
print("subscribed", flush=True)
n, nbytes, t0 = 0, 0, None
ws.settimeout(1.0)
while True:
    try:
        m = ws.recv()
    except Exception:
        break
    if isinstance(m, bytes) and m[0] == 1:
        if t0 is None:
            t0 = time.monotonic()
        n += 1
        nbytes += len(m)
        if time.monotonic() - t0 >= seconds:
            break
dt = time.monotonic() - t0 if t0 else 0.0
print(json.dumps({"messages": n, "bytes": nbytes, "seconds": dt}), flush=True)
"""


def load_pair() -> tuple[np.ndarray, np.ndarray]:
    root = Path(
        os.environ.get(
            "SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
        )
    )
    files = sorted((root / "underwater" / "sea3d_field_left").glob("*.jpg"))[:2]
    if len(files) == 2:
        a, b = (cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files)
        return cv2.resize(a, (1920, 1080)), cv2.resize(b, (1920, 1080))
    rng = np.random.default_rng(0)
    imgs = [
        np.clip(cv2.resize(rng.normal(128, 60, (135, 240, 3)), (1920, 1080)), 0, 255).astype(
            np.uint8
        )
        for _ in range(2)
    ]
    return imgs[0], imgs[1]


class _Always:
    """A provider whose cameras always have a new frame: the bridge publishes flat out."""

    def __init__(self, pair: tuple[np.ndarray, np.ndarray]) -> None:
        from sea3d.capture.sources import ImageFrame

        self.frames = {"left": ImageFrame(0, pair[0]), "right": ImageFrame(0, pair[1])}
        self.n = 0
        self.published = 0

    def latest(self, stream: str) -> tuple[int, object]:
        self.n += 1
        if stream == "left":
            self.published += 2
        return self.n, self.frames[stream]


def run(mode: str, pair: tuple[np.ndarray, np.ndarray], seconds: float) -> dict[str, float]:
    from sea3d.capture.foxglove_live import FoxgloveBridge

    width = None if mode in ("full", "transport") else 960
    cfg = FoxgloveConfig(port=0, max_width_px=width, image_rate_hz=None, depth_rate_hz=0.0)
    with FoxglovePublisher(cfg) as pub:
        client = subprocess.Popen(
            [sys.executable, "-c", CLIENT, pub.url, str(seconds)],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert client.stdout is not None
        assert client.stdout.readline().strip() == "subscribed"
        while not (pub.subscribed(pub.image["left"]) and pub.subscribed(pub.image["right"])):
            time.sleep(0.01)
        jpegs = [fm.encode_preview_jpeg(img, quality=80)[0] for img in pair]
        sent = 0
        cpu0, t0 = time.process_time(), time.monotonic()
        if mode == "transport":
            while client.poll() is None and time.monotonic() - t0 < seconds + 5:
                for k, stream in enumerate(("left", "right")):
                    t_ns = time.time_ns()
                    msg = fm.compressed_image(t_ns, jpegs[k], "jpeg", stream)
                    pub.image[stream].log(msg, log_time=t_ns)
                    sent += 1
        else:  # the live path: the bridge polling a provider, encoding left and right in parallel
            provider = _Always(pair)
            with FoxgloveBridge(pub, provider, poll_interval_s=0.0):
                while client.poll() is None and time.monotonic() - t0 < seconds + 5:
                    time.sleep(0.05)
            sent = provider.published
        cpu, wall = time.process_time() - cpu0, time.monotonic() - t0
        out = json.loads(client.communicate(timeout=30)[0].strip().splitlines()[-1])
    secs = out["seconds"] or 1.0
    return {
        "received_per_s": out["messages"] / secs,
        "mb_per_s": out["bytes"] / secs / 1e6,
        "published_per_s": sent / wall,
        "cpu_per_s": cpu / wall,
    }


def _sdk_mesh_scene(t_ns, v, tri, col):
    """The reference: the SDK's objects, one per vertex, encoded by the SDK."""
    from foxglove.messages import (
        Color,
        Point3,
        SceneEntity,
        SceneUpdate,
        TriangleListPrimitive,
    )

    prim = TriangleListPrimitive(
        pose=fm.pose(np.eye(4)),
        points=[Point3(x=a, y=b, z=c) for a, b, c in v.tolist()],
        color=Color(r=0.7, g=0.7, b=0.7, a=1.0),
        colors=[Color(r=r, g=g, b=b, a=1.0) for r, g, b in (col / 255.0).tolist()],
        indices=[int(i) for i in tri.reshape(-1).tolist()],
    )
    ent = SceneEntity(timestamp=fm.timestamp(t_ns), frame_id="world", id="mesh",
                      triangles=[prim])
    return bytes(SceneUpdate(entities=[ent]).encode())


def mesh_bench(n_vertices: int, repeats: int) -> None:
    import open3d as o3d
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=20)
    while len(mesh.vertices) < n_vertices:
        mesh = mesh.subdivide_midpoint(1)
    v = np.asarray(mesh.vertices)[:n_vertices]
    tri = np.asarray(mesh.triangles)
    tri = tri[(tri < len(v)).all(axis=1)]
    col = np.random.default_rng(0).integers(0, 256, (len(v), 3), dtype=np.uint8)
    t_ns = 1_700_000_000_000_000_000

    def cpu(fn):
        times, out = [], b""
        for _ in range(repeats):
            c0 = time.process_time()
            out = fn()
            times.append(time.process_time() - c0)
        return statistics.median(times), out

    ours_s, ours = cpu(lambda: fm.mesh_scene(t_ns, "world", v, tri, col))
    ref_s, ref = cpu(lambda: _sdk_mesh_scene(t_ns, v, tri, col))
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(fm.SCENE_UPDATE_SCHEMA.data).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.SceneUpdate"))
    same = cls.FromString(ours) == cls.FromString(ref)
    print(f"mesh of {len(v)} vertices, {len(tri)} triangles, colours; {os.cpu_count()} CPUs "
          f"(load average {os.getloadavg()[0]:.1f}); CPU s per message, median of {repeats}")
    print(f"ours (from the arrays)          {ours_s:8.4f} s  {len(ours) / 1e6:6.1f} MB")
    print(f"reference (SDK object per vertex) {ref_s:6.4f} s  {len(ref) / 1e6:6.1f} MB")
    print(f"ratio {ref_s / max(ours_s, 1e-9):.0f}x; decoded messages equal: {same}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mesh", type=int, default=0, metavar="V",
                    help="benchmark the /mesh message of about V vertices instead")
    args = ap.parse_args()
    if args.mesh:
        mesh_bench(args.mesh, args.repeats)
        return
    pair = load_pair()
    print(
        f"two 1920x1080 RGB cameras, {os.cpu_count()} CPUs (load average "
        f"{os.getloadavg()[0]:.1f}), client in a second process"
    )
    print(f"{'what':<46}{'msg/s':>8}{'per cam':>9}{'MB/s':>8}{'CPU/s':>7}")
    rows = [
        ("full", "ours: JPEG q80 at 1920x1080, then publish"),
        ("live", "ours: JPEG q80 at 960 px (live default)"),
        ("transport", "reference: SDK channel, JPEG encoded before"),
    ]
    for mode, label in rows:
        runs = [run(mode, pair, args.seconds) for _ in range(args.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(
            f"{label:<46}{med['received_per_s']:>8.1f}{med['received_per_s'] / 2:>9.1f}"
            f"{med['mb_per_s']:>8.1f}{med['cpu_per_s']:>7.2f}"
        )


if __name__ == "__main__":
    main()
