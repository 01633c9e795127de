"""Rig files: sea3d's ``rig.yaml``, OpenCV FileStorage imports, refractive COLMAP export.

``rig.yaml`` (format ``sea3d-rig``, version 1) holds both camera models with their ports,
``T_left_right`` and the image size, with units in the key names::

    format: sea3d-rig
    version: 1
    image_width_px: 1920
    image_height_px: 1080
    left:
      fx_px: 1082.4
      fy_px: 1074.4
      cx_px: 949.5
      cy_px: 535.7
      distortion: []          # OpenCV order: k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]
      port:
        type: dome            # none | dome | flat
        center_m: [-0.00054, 0.00058, 0.0021]
        inner_radius_m: 0.03125
        thickness_m: 0.0031
        n_air: 1.000292
        n_glass: 1.492
        n_water: 1.333
    right: {...}
    T_left_right: [[1, 0, 0, 0.107], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]   # metres

A flat port has ``normal``, ``distance_m``, ``thickness_m`` and the indices instead.

Optional blocks for the rig's other sensors (a file without them loads as before)::

    imu:
      T_left_imu: [[...], [...], [...], [0, 0, 0, 1]]   # IMU (body) -> left camera, metres
      rate_hz: 200.0
      gyro_noise_density_radps_sqrthz: 1.7e-4
      gyro_random_walk_radps_sqrts: 1.9e-5
      accel_noise_density_mps2_sqrthz: 2.0e-3
      accel_random_walk_mps2_sqrts: 3.0e-3
      gravity_mps2: 9.81          # optional, default 9.81
      time_offset_s: 0.0          # optional: t_imu = t_cam + time_offset_s
    sonar:
      T_left_sonar: [[...], ...]  # echosounder -> left camera; its beam points along its -z
      beam_deg: 30.0              # full cone angle

Importers read OpenCV FileStorage stereo YAML as MATLAB's stereoCameraCalibrator exports it
(``cameraMatrixLeft``, ``distCoeffsLeft``, ..., ``R``, ``T`` in millimetres; OpenCV's convention
``p_right = R p_left + T``) and OpenCV's ``stereo_calib`` sample files (``M1 D1 M2 D2`` in
``intrinsics.yml`` plus ``R T`` in ``extrinsics.yml``, in the units of the board's square size).
Loading is all-or-nothing: any problem raises :class:`~sea3d.errors.RigFileError` naming the
file, the key and the value, and no partial rig is returned.
"""

from __future__ import annotations

import logging
import math
import os
import reprlib
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import yaml

from sea3d.errors import RigFileError, Sea3dError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import DISTORTION_LENGTHS, PinholeCamera
from sea3d.geometry.rig import ImuSpec, SonarSpec, StereoRig
from sea3d.geometry.se3 import invert_T, make_T
from sea3d.refraction.ports import DomePort, DomePortCamera, FlatPort, FlatPortCamera

__all__ = [
    "RigFormat",
    "check_rig_physics",
    "decode_rig_bytes",
    "imu_to_dict",
    "load_rig",
    "read_rig_text",
    "resolve_rig",
    "rig_from_dict",
    "rig_from_yaml",
    "rig_to_colmap",
    "rig_to_dict",
    "rig_to_opencv_yaml",
    "rig_to_yaml",
    "safe_yaml",
    "save_rig",
    "sonar_to_dict",
]

log = logging.getLogger(__name__)

RigFormat = Literal["sea3d", "opencv", "colmap", "json"]

FORMAT_NAME = "sea3d-rig"
FORMAT_VERSION = 1

# Common sensor sizes used to guess a missing image size from the principal point.
_COMMON_SIZES = (
    (640, 480),
    (752, 480),
    (800, 600),
    (1024, 768),
    (1280, 720),
    (1280, 960),
    (1280, 1024),
    (1440, 1080),
    (1920, 1080),
    (1920, 1200),
    (2048, 1536),
    (2560, 1440),
    (3840, 2160),
    (3856, 2180),
    (4096, 2160),
)


# --------------------------------------------------------------------------- to dict / YAML
def _port_to_dict(cam: CameraModel) -> dict[str, Any]:
    if isinstance(cam, DomePortCamera):
        p = cam.port
        return {
            "type": "dome",
            "center_m": [float(v) for v in p.center_m],
            "inner_radius_m": p.inner_radius_m,
            "thickness_m": p.thickness_m,
            "n_air": p.n_air,
            "n_glass": p.n_glass,
            "n_water": p.n_water,
        }
    if isinstance(cam, FlatPortCamera):
        f = cam.port
        return {
            "type": "flat",
            "normal": [float(v) for v in f.normal],
            "distance_m": f.distance_m,
            "thickness_m": f.thickness_m,
            "n_air": f.n_air,
            "n_glass": f.n_glass,
            "n_water": f.n_water,
        }
    return {"type": "none"}


def _camera_to_dict(cam: CameraModel) -> dict[str, Any]:
    pin = cam.lens
    return {
        "fx_px": pin.fx,
        "fy_px": pin.fy,
        "cx_px": pin.cx,
        "cy_px": pin.cy,
        "distortion": [float(v) for v in pin.dist],
        "port": _port_to_dict(cam),
    }


def rig_to_dict(rig: StereoRig) -> dict[str, Any]:
    """The rig as plain Python values (the ``rig.yaml`` schema)."""
    out: dict[str, Any] = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "image_width_px": rig.width,
        "image_height_px": rig.height,
        "left": _camera_to_dict(rig.left),
        "right": _camera_to_dict(rig.right),
        "T_left_right": [[float(v) for v in row] for row in rig.T_left_right],
    }
    out.update(_sensors_to_dict(rig))
    return out


# --------------------------------------------------------------------------- IMU / echosounder
_IMU_NOISE_KEYS = (
    "gyro_noise_density_radps_sqrthz",
    "gyro_random_walk_radps_sqrts",
    "accel_noise_density_mps2_sqrthz",
    "accel_random_walk_mps2_sqrts",
)


def imu_to_dict(imu: ImuSpec) -> dict[str, Any]:
    """The ``imu:`` block of ``rig.yaml``."""
    out: dict[str, Any] = {
        "T_left_imu": [[float(v) for v in row] for row in imu.T_left_imu],
        "rate_hz": imu.rate_hz,
    }
    for key in _IMU_NOISE_KEYS:
        out[key] = float(getattr(imu, key))
    out["gravity_mps2"] = imu.gravity_mps2
    out["time_offset_s"] = imu.time_offset_s
    return out


def sonar_to_dict(sonar: SonarSpec) -> dict[str, Any]:
    """The ``sonar:`` block of ``rig.yaml``."""
    return {
        "T_left_sonar": [[float(v) for v in row] for row in sonar.T_left_sonar],
        "beam_deg": sonar.beam_deg,
    }


def _sensors_to_dict(rig: StereoRig) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if rig.imu is not None:
        out["imu"] = imu_to_dict(rig.imu)
    if rig.sonar is not None:
        out["sonar"] = sonar_to_dict(rig.sonar)
    return out


def rig_to_yaml(rig: StereoRig) -> str:
    """The rig as ``rig.yaml`` text."""
    header = "# sea3d stereo rig; units in key names; conventions: docs/conventions.md\n"
    return header + yaml.safe_dump(rig_to_dict(rig), sort_keys=False, default_flow_style=None)


# --------------------------------------------------------------------------- from dict / YAML
def _short(value: Any, limit: int = 120) -> str:
    """``repr(value)`` cut to ``limit`` characters: error messages stay one readable line even
    for a hostile file (a 1 KB YAML alias bomb expands to hundreds of MB of repr)."""
    try:
        short = reprlib.Repr()
        short.maxlevel, short.maxlist, short.maxdict = 3, 8, 8
        short.maxstring, short.maxother = 60, 60
        text = short.repr(value)
    except RecursionError:
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Reader:
    """Typed access to a nested mapping that names file and key in every error."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, message: str) -> RigFileError:
        return RigFileError(f"{self.source}: key '{key}': {message}")

    def get(self, data: Mapping[str, Any], key: str, prefix: str) -> Any:
        full = f"{prefix}{key}"
        if not isinstance(data, Mapping):
            raise self.fail(prefix.rstrip("."), f"expected a mapping, got {type(data).__name__}")
        if key not in data:
            raise self.fail(full, "missing")
        return data[key]

    def number(self, data: Mapping[str, Any], key: str, prefix: str = "") -> float:
        value = self.get(data, key, prefix)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(f"{prefix}{key}", f"expected a number, got {_short(value)}")
        try:
            number = float(value)  # an int beyond float range raises OverflowError
        except OverflowError:
            number = float("inf")
        if not math.isfinite(number):
            raise self.fail(f"{prefix}{key}", f"expected a finite number, got {_short(value)}")
        return number

    def array(
        self, data: Mapping[str, Any], key: str, shape: tuple[int, ...] | None, prefix: str = ""
    ) -> np.ndarray:
        value = self.get(data, key, prefix)
        if not isinstance(value, list | tuple) or len(value) > 64:
            raise self.fail(
                f"{prefix}{key}", f"expected a short list of numbers, got {_short(value)}"
            )
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, RecursionError) as err:
            raise self.fail(f"{prefix}{key}", f"expected numbers, got {_short(value)}") from err
        if shape is not None and arr.shape != shape:
            raise self.fail(
                f"{prefix}{key}", f"expected shape {shape}, got {arr.shape}: {_short(value)}"
            )
        if not np.all(np.isfinite(arr)):
            raise self.fail(f"{prefix}{key}", f"non-finite values: {_short(value)}")
        return arr


def _camera_from_dict(r: _Reader, data: Any, name: str, width: int, height: int) -> CameraModel:
    prefix = f"{name}."
    if not isinstance(data, Mapping):
        raise r.fail(name, f"expected a mapping, got {_short(data)}")
    dist = r.array(data, "distortion", None, prefix) if "distortion" in data else np.zeros(0)
    if dist.ndim != 1 or dist.size not in DISTORTION_LENGTHS:
        raise r.fail(
            f"{prefix}distortion",
            f"expected one of {DISTORTION_LENGTHS} coefficients, got {dist.size}: {dist.tolist()}",
        )
    try:
        pin = PinholeCamera(
            fx=r.number(data, "fx_px", prefix),
            fy=r.number(data, "fy_px", prefix),
            cx=r.number(data, "cx_px", prefix),
            cy=r.number(data, "cy_px", prefix),
            width=width,
            height=height,
            dist=dist,
        )
    except RigFileError:
        raise
    except Sea3dError as err:
        raise r.fail(name, str(err)) from err
    port = data.get("port", {"type": "none"})
    if port is None:
        port = {"type": "none"}
    pp = f"{prefix}port."
    kind = r.get(port, "type", pp)
    try:
        if kind == "none":
            return pin
        indices = {
            "n_air": r.number(port, "n_air", pp),
            "n_glass": r.number(port, "n_glass", pp),
            "n_water": r.number(port, "n_water", pp),
        }
        if kind == "dome":
            radius = r.number(port, "inner_radius_m", pp)
            if radius <= 0:
                raise r.fail(f"{pp}inner_radius_m", f"must be > 0, got {radius}")
            return DomePortCamera(
                pin,
                DomePort(
                    center_m=r.array(port, "center_m", (3,), pp),
                    inner_radius_m=radius,
                    thickness_m=r.number(port, "thickness_m", pp),
                    **indices,
                ),
            )
        if kind == "flat":
            return FlatPortCamera(
                pin,
                FlatPort(
                    normal=r.array(port, "normal", (3,), pp),
                    distance_m=r.number(port, "distance_m", pp),
                    thickness_m=r.number(port, "thickness_m", pp),
                    **indices,
                ),
            )
    except RigFileError:
        raise
    except Sea3dError as err:
        raise r.fail(f"{pp}", str(err)) from err
    raise r.fail(f"{pp}type", f"expected none, dome or flat, got {_short(kind)}")


def _imu_from_dict(r: _Reader, data: Any) -> ImuSpec:
    p = "imu."
    if not isinstance(data, Mapping):
        raise r.fail("imu", f"expected a mapping, got {_short(data)}")
    known = {"T_left_imu", "rate_hz", "gravity_mps2", "time_offset_s", *_IMU_NOISE_KEYS}
    unknown = sorted(set(data) - known)
    if unknown:
        raise r.fail(f"{p}{unknown[0]}", f"unknown key (expected {', '.join(sorted(known))})")
    values: dict[str, Any] = {
        "T_left_imu": r.array(data, "T_left_imu", (4, 4), p),
        "rate_hz": r.number(data, "rate_hz", p),
    }
    for key in _IMU_NOISE_KEYS:
        values[key] = r.number(data, key, p)
    for key in ("gravity_mps2", "time_offset_s"):
        if key in data:
            values[key] = r.number(data, key, p)
    try:
        return ImuSpec(**values)
    except Sea3dError as err:
        raise r.fail("imu", str(err)) from err


def _sonar_from_dict(r: _Reader, data: Any) -> SonarSpec:
    p = "sonar."
    if not isinstance(data, Mapping):
        raise r.fail("sonar", f"expected a mapping, got {_short(data)}")
    unknown = sorted(set(data) - {"T_left_sonar", "beam_deg"})
    if unknown:
        raise r.fail(f"{p}{unknown[0]}", "unknown key (expected T_left_sonar, beam_deg)")
    try:
        return SonarSpec(
            T_left_sonar=r.array(data, "T_left_sonar", (4, 4), p),
            beam_deg=r.number(data, "beam_deg", p),
        )
    except RigFileError:
        raise
    except Sea3dError as err:
        raise r.fail("sonar", str(err)) from err


def _sensors_from_dict(r: _Reader, data: Mapping[str, Any]) -> dict[str, Any]:
    """The optional ``imu`` and ``sonar`` blocks as ``StereoRig`` keyword arguments."""
    out: dict[str, Any] = {}
    if data.get("imu") is not None:
        out["imu"] = _imu_from_dict(r, data["imu"])
    if data.get("sonar") is not None:
        out["sonar"] = _sonar_from_dict(r, data["sonar"])
    return out


def rig_from_dict(data: Any, source: str = "<dict>") -> StereoRig:
    """Build a rig from the ``rig.yaml`` schema.

    Raises:
        RigFileError: a missing key, a wrong shape or type, or an invalid value, naming
            ``source``, the key and the value.
    """
    r = _Reader(source)
    if not isinstance(data, Mapping):
        raise RigFileError(
            f"{source}: expected a mapping at the top level, got {type(data).__name__}"
        )
    fmt = data.get("format")
    if fmt != FORMAT_NAME:
        raise r.fail("format", f"expected {FORMAT_NAME!r}, got {_short(fmt)}")
    version = data.get("version")
    if isinstance(version, bool) or version != FORMAT_VERSION:  # YAML's true is not 1
        raise r.fail(
            "version",
            f"unsupported version {_short(version)} (this sea3d reads {FORMAT_VERSION})",
        )
    width = r.number(data, "image_width_px")
    height = r.number(data, "image_height_px")
    if width <= 0 or height <= 0 or width != int(width) or height != int(height):
        raise r.fail("image_width_px", f"expected positive whole pixels, got {width}x{height}")
    check_image_size(int(width), int(height), source)
    left = _camera_from_dict(r, r.get(data, "left", ""), "left", int(width), int(height))
    right = _camera_from_dict(r, r.get(data, "right", ""), "right", int(width), int(height))
    T = r.array(data, "T_left_right", (4, 4))
    sensors = _sensors_from_dict(r, data)
    try:
        rig = StereoRig(left=left, right=right, T_left_right=T, **sensors)
    except Sea3dError as err:
        raise r.fail("T_left_right", str(err)) from err
    check_rig_physics(rig, source)
    return rig


def rig_from_yaml(text: str, source: str = "<string>") -> StereoRig:
    """Parse ``rig.yaml`` text (size-limited, alias expansion bounded; see :func:`safe_yaml`).

    Raises:
        RigFileError: invalid YAML or an invalid rig, naming ``source``.
    """
    return rig_from_dict(safe_yaml(text, source), source)


# --------------------------------------------------------------------------- safe loading
# A rig file is a few kB; these limits leave room for comments and generous formatting.
MAX_RIG_FILE_BYTES = 1 << 20
MAX_YAML_NODES = 20_000  # after alias expansion; a rig has about 100
# Image sizes a stereo camera can have (the paper's sensor is 3856x2180).
MAX_IMAGE_SIDE_PX = 32_768
MAX_IMAGE_PIXELS = 1 << 28
# Refractive indices of anything a port or its medium can be made of (air 1.0003, water 1.33,
# acrylic 1.49, sapphire 1.77; the highest optical glasses stay under 2.1).
N_RANGE = (1.0, 2.5)
MAX_DOME_RADIUS_M = 2.0
MAX_PORT_DISTANCE_M = 1.0
MAX_PORT_THICKNESS_M = 0.2
MAX_BASELINE_M = 10.0


def decode_rig_bytes(data: bytes, source: str) -> str:
    """Rig file bytes as text: UTF-8 (with or without a byte-order mark), or UTF-16/32 when
    a byte-order mark says so.

    Raises:
        RigFileError: too large, or not decodable, naming ``source`` and the offending byte.
    """
    if len(data) > MAX_RIG_FILE_BYTES:
        raise RigFileError(
            f"{source}: {len(data)} bytes is too large for a rig file (limit "
            f"{MAX_RIG_FILE_BYTES} bytes)"
        )
    for bom, codec in (
        (b"\xef\xbb\xbf", "utf-8-sig"),
        (b"\xff\xfe\x00\x00", "utf-32"),
        (b"\x00\x00\xfe\xff", "utf-32"),
        (b"\xff\xfe", "utf-16"),
        (b"\xfe\xff", "utf-16"),
    ):
        if data.startswith(bom):
            try:
                return data.decode(codec)
            except UnicodeDecodeError as err:
                raise RigFileError(
                    f"{source}: starts with a {codec} byte-order mark but byte {err.start} "
                    f"cannot be decoded; save the rig as UTF-8"
                ) from err
    if b"\x00" in data:
        raise RigFileError(
            f"{source}: not UTF-8 text: NUL bytes (it looks like UTF-16 without a byte-order "
            "mark); save the rig as UTF-8"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        hint = " (it looks like UTF-16 without a byte-order mark)" if b"\x00" in data else ""
        raise RigFileError(
            f"{source}: not UTF-8 text: byte 0x{data[err.start]:02x} at offset {err.start} "
            f"cannot be decoded{hint}; save the rig as UTF-8"
        ) from err


def read_rig_text(path: str | os.PathLike[str]) -> str:
    """Read a rig file's text with :func:`decode_rig_bytes`' size limit and decoding.

    Raises:
        RigFileError: missing, unreadable, too large or undecodable (naming the file).
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > MAX_RIG_FILE_BYTES:
            raise RigFileError(
                f"{p}: {size} bytes is too large for a rig file (limit {MAX_RIG_FILE_BYTES} bytes)"
            )
        data = p.read_bytes()
    except FileNotFoundError as err:
        raise RigFileError(f"{p}: rig file not found") from err
    except OSError as err:
        raise RigFileError(f"{p}: cannot read: {err.strerror or err}") from err
    return decode_rig_bytes(data, str(p))


def safe_yaml(text: str, source: str) -> Any:
    """``yaml.safe_load`` with limits: at most :data:`MAX_RIG_FILE_BYTES` of text and
    :data:`MAX_YAML_NODES` nodes once aliases are expanded (anchors and aliases are allowed,
    e.g. one ``port`` block shared by both cameras; recursive aliases are refused).

    Raises:
        RigFileError: invalid YAML, too large, too deeply nested, or too many nodes.
    """
    if not isinstance(text, str):
        raise RigFileError(f"{source}: expected YAML text, got {type(text).__name__}")
    if len(text) > MAX_RIG_FILE_BYTES:
        raise RigFileError(
            f"{source}: {len(text)} characters is too large for a rig file (limit "
            f"{MAX_RIG_FILE_BYTES})"
        )
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        if root is not None:
            _count_yaml_nodes(root, source)
            _refuse_duplicate_keys(root, source)
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        message = " ".join(str(err).split())  # one line
        if len(message) > 400:
            message = message[:400] + "..."
        raise RigFileError(f"{source}: not valid YAML: {message}") from err
    except RecursionError as err:
        raise RigFileError(f"{source}: YAML nested too deeply for a rig file") from err


def _refuse_duplicate_keys(root: yaml.Node, source: str) -> None:
    """Raise on a key given twice in one mapping (YAML loaders keep the last one silently, so
    a pasted block would override a calibrated value without a word)."""
    seen_nodes: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen_nodes:
            continue
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            first: dict[str, int] = {}
            for key, value in node.value:
                if isinstance(key, yaml.ScalarNode) and key.value != "<<":
                    line = key.start_mark.line + 1
                    if key.value in first:
                        raise RigFileError(
                            f"{source}: key '{key.value}' is given twice (lines "
                            f"{first[key.value]} and {line}); remove one"
                        )
                    first[key.value] = line
                stack.append(value)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)


def _count_yaml_nodes(root: yaml.Node, source: str) -> None:
    """Raise if the node graph, with aliases expanded, exceeds :data:`MAX_YAML_NODES`."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise RigFileError(f"{source}: YAML holds a recursive alias; refusing it")
        active.add(key)
        total = 1
        if isinstance(node, yaml.SequenceNode):
            total += sum(size(child) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            total += sum(size(k) + size(v) for k, v in node.value)
        active.discard(key)
        if total > MAX_YAML_NODES:
            raise RigFileError(
                f"{source}: YAML expands to more than {MAX_YAML_NODES} values (an alias bomb?); "
                "refusing it"
            )
        sizes[key] = total
        return total

    size(root)


# --------------------------------------------------------------------------- physics
def check_image_size(width: int, height: int, source: str) -> None:
    """Raise unless the image size is one a camera can have (at most 32768 px a side and
    2^28 pixels)."""
    if not (0 < width <= MAX_IMAGE_SIDE_PX and 0 < height <= MAX_IMAGE_SIDE_PX) or (
        width * height > MAX_IMAGE_PIXELS
    ):
        raise RigFileError(
            f"{source}: key 'image_width_px': image size {width}x{height} px is outside the "
            f"range of cameras (at most {MAX_IMAGE_SIDE_PX} px a side, {MAX_IMAGE_PIXELS} "
            "pixels)"
        )


def _check_intrinsics(pin: PinholeCamera, name: str, source: str) -> None:
    """Principal point inside the image, focal lengths within 1/100..100 image widths, and a
    distortion that stays invertible out to the image corners."""
    w, h = pin.width, pin.height
    if not (0.0 <= pin.cx <= w and 0.0 <= pin.cy <= h):
        raise RigFileError(
            f"{source}: key '{name}.cx_px': principal point ({pin.cx:g}, {pin.cy:g}) px lies "
            f"outside the {w}x{h} image"
        )
    for key, f in (("fx_px", pin.fx), ("fy_px", pin.fy)):
        if not 0.01 * w <= f <= 100.0 * w:
            raise RigFileError(
                f"{source}: key '{name}.{key}': focal length {f:g} px is not between 1/100 and "
                f"100 image widths ({0.01 * w:g}..{100.0 * w:g} px)"
            )
    if pin.has_distortion:
        kept = distortion_coverage(pin)
        if kept < MIN_COVERAGE_FRACTION:
            raise RigFileError(
                f"{source}: key '{name}.distortion': undistorted at its own focal length, the "
                f"image keeps only {kept:.1%} of its pixels (the coefficients "
                f"{[float(f'{v:.4g}') for v in pin.dist]} squeeze or spread the picture "
                "beyond any lens); check the coefficients"
            )
        bad = distortion_fold(pin)
        if bad is None:
            return
        message = (
            f"{source}: key '{name}.distortion': the lens model folds over at pixel "
            f"({bad[0]:.0f}, {bad[1]:.0f}), {bad[2]:.0%} of the way from the principal point to "
            "the image border: pixels beyond cannot be undistorted"
        )
        if bad[2] < FOLD_ERROR_FRACTION:
            raise RigFileError(message + "; check the coefficients")
        log.warning("%s (usual when the board never reached the image corners)", message)


def distortion_fold(pin: PinholeCamera, n_rays: int = 72) -> tuple[float, float, float] | None:
    """Where the distortion model stops being invertible inside the image, or None.

    Along rays from the principal point in ``n_rays`` directions, undistorted radii from 0 to
    20 (87 degrees off axis) are distorted with :meth:`PinholeCamera.distort`; the distorted
    radius must keep growing until the point leaves the image.

    Returns:
        ``(u, v, fraction)`` for the worst ray: the last pixel before the fold and how far
        out it lies as a fraction of the way from the principal point to the image border
        along that ray (0..1); None if the model is invertible everywhere in the image.
    """
    angles = np.linspace(0.0, 2.0 * np.pi, n_rays, endpoint=False)
    radii = np.concatenate([np.linspace(0.0, 2.0, 1500), np.linspace(2.0, 20.0, 1500)[1:]])
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    xy = (radii[None, :, None] * dirs[:, None, :]).reshape(-1, 2)
    with np.errstate(all="ignore"):
        xy_d = pin.distort(xy).reshape(n_rays, radii.size, 2)
    u = pin.fx * xy_d[..., 0] + pin.cx
    v = pin.fy * xy_d[..., 1] + pin.cy
    inside = (u >= 0) & (u <= pin.width) & (v >= 0) & (v <= pin.height)
    r_d = np.einsum("ijk,ik->ij", xy_d, dirs)  # distorted radius along the ray
    worst: tuple[float, float, float] | None = None
    for i in range(n_rays):
        leaves = np.flatnonzero(~inside[i])
        stop = int(leaves[0]) if leaves.size else radii.size
        seg = r_d[i, : min(stop + 1, radii.size)]
        growing = np.isfinite(seg[1:]) & (np.diff(seg) > 0)
        if np.all(growing) and leaves.size:
            continue
        k = int(np.argmin(growing)) if not np.all(growing) else stop - 1
        # How far to the border this ray is, in pixels, along its (undistorted) direction.
        du, dv = pin.fx * dirs[i, 0], pin.fy * dirs[i, 1]
        tx = ((pin.width - pin.cx) / du if du > 0 else -pin.cx / du) if du else np.inf
        ty = ((pin.height - pin.cy) / dv if dv > 0 else -pin.cy / dv) if dv else np.inf
        border = min(tx, ty) * float(np.hypot(du, dv))
        reached = float(np.hypot(u[i, k] - pin.cx, v[i, k] - pin.cy))
        fraction = min(reached / border, 1.0) if border > 0 else 0.0
        if worst is None or fraction < worst[2]:
            worst = (float(u[i, k]), float(v[i, k]), fraction)
    return worst


def distortion_coverage(pin: PinholeCamera, n: int = 64) -> float:
    """Fraction of the image's own pixel grid that, undistorted at the camera's focal length
    and principal point (the rectified view of this camera), still comes from inside the
    image: ``(u - cx) / fx`` of an ``n x n`` grid is distorted back to pixels and counted.

    A lens keeps most of its picture (barrel distortion all of it, mild pincushion 80-100 %);
    coefficients such as ``k1 = 1e10`` are monotonic, so they never fold, yet squeeze the
    whole image into a few pixels around the principal point: nearly nothing is kept.
    """
    u = (np.arange(n) + 0.5) * pin.width / n
    v = (np.arange(n) + 0.5) * pin.height / n
    uu, vv = np.meshgrid(u, v)
    xy = np.stack([(uu.ravel() - pin.cx) / pin.fx, (vv.ravel() - pin.cy) / pin.fy], axis=1)
    with np.errstate(all="ignore"):
        xy_d = pin.distort(xy)
    ud = pin.fx * xy_d[:, 0] + pin.cx
    vd = pin.fy * xy_d[:, 1] + pin.cy
    inside = np.isfinite(ud) & np.isfinite(vd)
    inside &= (ud >= 0) & (ud <= pin.width) & (vd >= 0) & (vd <= pin.height)
    return float(np.count_nonzero(inside)) / inside.size


# Undistorted at its own focal length, a camera must keep at least this fraction of its
# image: under it, most of the rectified view is empty and depth has nothing to match.
MIN_COVERAGE_FRACTION = 0.5

# A fold closer to the principal point than this fraction of the way to the border is a
# broken model; beyond it (real calibrations whose board never reached the corners, such as
# OpenCV's own stereo_calib sample, fold at about 80 %) it is a warning.
FOLD_ERROR_FRACTION = 0.5


def _check_port(cam: CameraModel, name: str, source: str) -> None:
    port = cam.port
    if port is None:
        return
    key = f"{name}.port"
    for n_name in ("n_air", "n_glass", "n_water"):
        n = float(getattr(port, n_name))
        if not N_RANGE[0] <= n <= N_RANGE[1]:
            raise RigFileError(
                f"{source}: key '{key}.{n_name}': refractive index {n:g} is outside the range "
                f"of real media ({N_RANGE[0]}..{N_RANGE[1]})"
            )
    if isinstance(port, DomePort):
        r, t = port.inner_radius_m, port.thickness_m
        if r > MAX_DOME_RADIUS_M:
            raise RigFileError(
                f"{source}: key '{key}.inner_radius_m': {r:g} m is larger than any dome port "
                f"(at most {MAX_DOME_RADIUS_M} m)"
            )
        if t >= r:
            raise RigFileError(
                f"{source}: key '{key}.thickness_m': {t:g} m is not below the inner radius "
                f"{r:g} m; a dome shell is thinner than its radius"
            )
    elif isinstance(port, FlatPort):
        if port.distance_m > MAX_PORT_DISTANCE_M:
            raise RigFileError(
                f"{source}: key '{key}.distance_m': {port.distance_m:g} m is farther than a flat "
                f"port sits from its lens (at most {MAX_PORT_DISTANCE_M} m)"
            )
        if port.thickness_m > MAX_PORT_THICKNESS_M:
            raise RigFileError(
                f"{source}: key '{key}.thickness_m': {port.thickness_m:g} m is thicker than any "
                f"flat port (at most {MAX_PORT_THICKNESS_M} m)"
            )


def check_rig_physics(rig: StereoRig, source: str) -> None:
    """Check a rig against physics, not just types: image size, intrinsics inside the image,
    a distortion invertible out to the image corners, port geometry (dome thickness below
    its radius, centre inside the dome, sizes of real ports), refractive indices of real media
    and a baseline under 10 m.

    Raises:
        RigFileError: naming ``source``, the key and the value.
    """
    check_image_size(rig.width, rig.height, source)
    for name in ("left", "right"):
        cam = getattr(rig, name)
        _check_intrinsics(cam.lens, name, source)
        _check_port(cam, name, source)
    baseline = rig.baseline_m
    if not 0.0 < baseline <= MAX_BASELINE_M:
        raise RigFileError(
            f"{source}: key 'T_left_right': baseline {baseline:g} m is outside (0, "
            f"{MAX_BASELINE_M}] m"
        )


# --------------------------------------------------------------------------- OpenCV files
def _read_opencv_nodes(path: Path) -> dict[str, Any]:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as err:
        raise RigFileError(f"{path}: not a readable OpenCV FileStorage file: {err}") from err
    if not fs.isOpened():
        raise RigFileError(f"{path}: not a readable OpenCV FileStorage file")
    out: dict[str, Any] = {}
    try:
        root = fs.root()
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap() and not node.empty():
                mat = node.mat()
                out[key] = mat if mat is not None else None
            elif node.isSeq():
                out[key] = np.array([node.at(i).real() for i in range(node.size())])
            elif node.isReal() or node.isInt():
                out[key] = node.real()
            elif node.isString():
                out[key] = node.string()
    finally:
        fs.release()
    return out


def _guess_size(cx: float, cy: float) -> tuple[int, int]:
    w_est, h_est = 2 * cx + 1, 2 * cy + 1
    best = min(_COMMON_SIZES, key=lambda s: abs(s[0] - w_est) / s[0] + abs(s[1] - h_est) / s[1])
    if abs(best[0] - w_est) / best[0] < 0.1 and abs(best[1] - h_est) / best[1] < 0.1:
        return best
    return round(w_est), round(h_est)


def _mat(nodes: Mapping[str, Any], key: str, shape: tuple[int, ...], path: Path) -> np.ndarray:
    if key not in nodes or nodes[key] is None:
        raise RigFileError(f"{path}: key '{key}': missing")
    arr = np.asarray(nodes[key], dtype=np.float64)
    if arr.size != int(np.prod(shape)):
        raise RigFileError(f"{path}: key '{key}': expected {shape}, got shape {arr.shape}")
    arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise RigFileError(f"{path}: key '{key}': non-finite values")
    return arr


def _dist(nodes: Mapping[str, Any], key: str, path: Path) -> np.ndarray:
    if key not in nodes or nodes[key] is None:
        return np.zeros(0)
    arr = np.asarray(nodes[key], dtype=np.float64).reshape(-1)
    if arr.size not in DISTORTION_LENGTHS:
        raise RigFileError(
            f"{path}: key '{key}': expected one of {DISTORTION_LENGTHS} coefficients, got "
            f"{arr.size}: {arr.tolist()}"
        )
    return arr


def _load_opencv(
    path: Path,
    nodes: Mapping[str, Any],
    extrinsics: Path | None,
    image_size: tuple[int, int] | None,
    translation_scale: float | None,
) -> StereoRig:
    if "cameraMatrixLeft" in nodes:  # MATLAB stereoCameraCalibrator export, T in millimetres
        names = ("cameraMatrixLeft", "distCoeffsLeft", "cameraMatrixRight", "distCoeffsRight")
        scale = 1e-3 if translation_scale is None else translation_scale
        ext_nodes, ext_path = nodes, path
    else:  # OpenCV stereo_calib sample: M1 D1 M2 D2 (+ R T in extrinsics.yml)
        names = ("M1", "D1", "M2", "D2")
        scale = 1.0 if translation_scale is None else translation_scale
        if "R" in nodes and "T" in nodes:
            ext_nodes, ext_path = nodes, path
        elif extrinsics is not None:
            ext_path = Path(extrinsics)
            if not ext_path.is_file():
                raise RigFileError(f"{ext_path}: extrinsics file not found")
            ext_nodes = _read_opencv_nodes(ext_path)
        else:
            raise RigFileError(
                f"{path}: has intrinsics (M1, D1, M2, D2) but no extrinsics (R, T); pass the "
                "matching extrinsics.yml"
            )
    K1 = _mat(nodes, names[0], (3, 3), path)
    K2 = _mat(nodes, names[2], (3, 3), path)
    D1 = _dist(nodes, names[1], path)
    D2 = _dist(nodes, names[3], path)
    R = _mat(ext_nodes, "R", (3, 3), ext_path)
    T = _mat(ext_nodes, "T", (3,), ext_path) * scale
    if image_size is None:
        if "image_width" in nodes and "image_height" in nodes:
            image_size = (int(nodes["image_width"]), int(nodes["image_height"]))
        elif "imageSize" in nodes and nodes["imageSize"] is not None:
            size = np.asarray(nodes["imageSize"]).reshape(-1)
            image_size = (int(size[0]), int(size[1]))
        else:
            image_size = _guess_size(K1[0, 2], K1[1, 2])
            log.warning(
                "%s holds no image size; assuming %dx%d from the principal point (pass "
                "image_size to set it)",
                path,
                *image_size,
            )
    # Orthonormalise R: exported files round to 6 digits, which breaks a strict rigidity check.
    u, _, vt = np.linalg.svd(R)
    R_ortho = u @ vt
    if np.abs(R_ortho - R).max() > 1e-3:
        raise RigFileError(f"{ext_path}: key 'R': not a rotation matrix: {R.tolist()}")
    try:
        left = PinholeCamera.from_K(K1, *image_size, dist=D1)
        right = PinholeCamera.from_K(K2, *image_size, dist=D2)
        T_right_left = make_T(R_ortho, T)
        rig = StereoRig(left=left, right=right, T_left_right=invert_T(T_right_left))
    except Sea3dError as err:
        raise RigFileError(f"{path}: {err}") from err
    check_rig_physics(rig, str(path))
    return rig


def rig_to_opencv_yaml(rig: StereoRig) -> str:
    """OpenCV FileStorage YAML in the MATLAB-export layout (``T`` in millimetres).

    Port parameters cannot be expressed there and are dropped (a warning is logged).
    """
    import cv2

    if rig.left.port is not None or rig.right.port is not None:
        log.warning("OpenCV stereo YAML has no place for port parameters; they are dropped")
    left, right = rig.left.lens, rig.right.lens
    T_rl = rig.T_right_left
    fd, tmp = tempfile.mkstemp(suffix=".yml")
    os.close(fd)
    try:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE)
        fs.write("imageSize", np.array([[rig.width, rig.height]], dtype=np.float64))
        fs.write("cameraMatrixLeft", left.K)
        fs.write("distCoeffsLeft", np.asarray(left.dist, dtype=np.float64).reshape(1, -1))
        fs.write("cameraMatrixRight", right.K)
        fs.write("distCoeffsRight", np.asarray(right.dist, dtype=np.float64).reshape(1, -1))
        fs.write("R", T_rl[:3, :3])
        fs.write("T", (T_rl[:3, 3] * 1e3).reshape(3, 1))
        fs.release()
        return Path(tmp).read_text()
    finally:
        os.unlink(tmp)


def rig_to_colmap(rig: StereoRig) -> str:
    """Refractive COLMAP camera parameters, one camera per line.

    Each camera gets a ``cameras.txt``-style line ``CAMERA_ID OPENCV|FULL_OPENCV W H params`` and,
    if it has a port, a line ``CAMERA_ID DOMEPORT Cx Cy Cz int_radius int_thick na ng nw`` or
    ``CAMERA_ID FLATPORT Nx Ny Nz int_dist int_thick na ng nw`` (lengths in metres).
    """
    lines = [
        "# sea3d rig exported for refractive COLMAP; lengths in metres",
        "# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]",
        "# CAMERA_ID DOMEPORT Cx Cy Cz int_radius int_thick na ng nw",
        "# CAMERA_ID FLATPORT Nx Ny Nz int_dist int_thick na ng nw",
    ]
    for cam_id, cam in ((1, rig.left), (2, rig.right)):
        pin = cam.lens
        coeffs = np.zeros(8)
        n = min(pin.dist.size, 8)
        coeffs[:n] = pin.dist[:n]
        if pin.dist.size > 8 and np.any(pin.dist[8:] != 0):
            raise RigFileError(
                "COLMAP's camera models hold at most 8 OpenCV distortion coefficients; this rig "
                f"has {pin.dist.size} with thin-prism or tilt terms"
            )
        if np.any(coeffs[4:] != 0):
            model, params = "FULL_OPENCV", [pin.fx, pin.fy, pin.cx, pin.cy, *coeffs]
        else:
            model, params = "OPENCV", [pin.fx, pin.fy, pin.cx, pin.cy, *coeffs[:4]]
        lines.append(
            f"{cam_id} {model} {rig.width} {rig.height} " + " ".join(f"{v:.12g}" for v in params)
        )
        if isinstance(cam, DomePortCamera):
            p = cam.port
            vals = [*p.center_m, p.inner_radius_m, p.thickness_m, p.n_air, p.n_glass, p.n_water]
            lines.append(f"{cam_id} DOMEPORT " + " ".join(f"{v:.12g}" for v in vals))
        elif isinstance(cam, FlatPortCamera):
            f = cam.port
            vals = [*f.normal, f.distance_m, f.thickness_m, f.n_air, f.n_glass, f.n_water]
            lines.append(f"{cam_id} FLATPORT " + " ".join(f"{v:.12g}" for v in vals))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- files
def load_rig(
    path: str | os.PathLike[str],
    *,
    extrinsics: str | os.PathLike[str] | None = None,
    image_size: tuple[int, int] | None = None,
    translation_scale: float | None = None,
) -> StereoRig:
    """Load a rig from ``rig.yaml``, a sea3d JSON rig, or an OpenCV FileStorage stereo file.

    Args:
        path: the file. OpenCV files are recognised by their ``%YAML`` header or XML.
        extrinsics: for OpenCV ``stereo_calib`` intrinsics files, the matching extrinsics file.
        image_size: ``(width, height)`` for OpenCV files that do not store it.
        translation_scale: metres per unit of ``T`` in OpenCV files (default: 1e-3 for MATLAB
            exports, which are in millimetres; 1 for stereo_calib files).

    Raises:
        RigFileError: the file is missing, unreadable or invalid (naming file, key and value).
    """
    p = Path(path)
    if not p.is_file():
        raise RigFileError(f"{p}: rig file not found")
    text = read_rig_text(p)
    head = text.lstrip()[:200]
    if head.startswith("%YAML") or head.startswith("<?xml") or head.startswith("<opencv_storage"):
        nodes = _read_opencv_nodes(p)
        return _load_opencv(
            p, nodes, Path(extrinsics) if extrinsics else None, image_size, translation_scale
        )
    if head.startswith("{"):
        # JSON: read as JSON, since YAML 1.1 takes numbers such as 3e-05 for strings
        import json

        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise RigFileError(f"{p}: not valid JSON: {err}") from err
        return rig_from_dict(data, str(p))
    return rig_from_yaml(text, str(p))


def _atomic_write(path: Path, text: str) -> None:
    from sea3d.io._atomic import atomic_write

    atomic_write(path, text)


_EXTENSION_FORMATS = {".yaml": "sea3d", ".yml": "sea3d", ".json": "json", ".txt": "colmap"}


def save_rig(
    rig: StereoRig, path: str | os.PathLike[str], *, format: RigFormat | None = None
) -> Path:
    """Write a rig; the format follows the extension unless given.

    ``.yaml``/``.yml`` -> sea3d ``rig.yaml``; ``.json`` -> the same schema as JSON; ``.txt`` ->
    refractive COLMAP parameters; ``format="opencv"`` -> OpenCV FileStorage (MATLAB layout).
    The file is written to a temporary name first and renamed, so a failure never leaves a
    half-written rig; it gets the usual permissions (0666 less the umask).

    Raises:
        RigFileError: an extension that names no format (and no ``format``), or an unknown
            ``format``.
    """
    import json

    p = Path(path)
    if format is None:
        ext = p.suffix.lower()
        if ext not in _EXTENSION_FORMATS:
            raise RigFileError(
                f"{p}: cannot tell the rig format from the extension {ext or '(none)'!r}; use "
                f".yaml or .yml (sea3d), .json or .txt (refractive COLMAP), or name the format"
            )
        format = _EXTENSION_FORMATS[ext]  # type: ignore[assignment]
    if format == "sea3d":
        text = rig_to_yaml(rig)
    elif format == "json":
        text = json.dumps(rig_to_dict(rig), indent=2) + "\n"
    elif format == "colmap":
        text = rig_to_colmap(rig)
    elif format == "opencv":
        text = rig_to_opencv_yaml(rig)
    else:
        raise RigFileError(f"{p}: unknown rig format {format!r}")
    _atomic_write(p, text)
    return p


class _StoresRig(Protocol):
    """What :func:`resolve_rig` needs of a session reader."""

    path: Path

    @property
    def rig_yaml(self) -> str | None: ...


def resolve_rig(path: str | os.PathLike[str] | None, session: _StoresRig) -> StereoRig:
    """The rig to process ``session`` with: the rig file ``path`` if given, else the rig stored
    in the session, else an error.

    Args:
        path: a rig file (any format :func:`load_rig` reads), or None.
        session: an open :class:`~sea3d.io.session.SessionReader`.

    Raises:
        RigFileError: the rig file is missing or invalid, or the stored rig is invalid.
        SessionError: no file was given and the session stores no rig (or a damaged one).
    """
    from sea3d.errors import SessionError

    if path is not None:
        return load_rig(path)
    text = session.rig_yaml
    if not text:
        raise SessionError(f"{session.path} stores no rig; give a rig file")
    return rig_from_yaml(text, f"{session.path} (stored rig.yaml)")
