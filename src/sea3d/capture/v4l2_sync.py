"""Hardware sync of the two cameras through V4L2 controls, set with ``v4l2-ctl`` and checked.

The paper's IMX585 cameras are put in master/slave sync with::

    v4l2-ctl -d /dev/video0 -c operation_mode=0 -c synchronizing_function=1
    v4l2-ctl -d /dev/video1 -c operation_mode=0 -c synchronizing_function=2

:func:`configure_sync` runs these for the user, then reads every control back with
``v4l2-ctl -d DEV -C name,...`` and raises if a value did not stick. The settings come from
the rig file's optional ``capture`` section::

    capture:
      left:  {device: /dev/video0, controls: {operation_mode: 0, synchronizing_function: 1}}
      right: {device: /dev/video1, controls: {operation_mode: 0, synchronizing_function: 2}}
"""

from __future__ import annotations

import logging
import shutil
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from sea3d.errors import CaptureError

__all__ = [
    "PAPER_SYNC",
    "DeviceControls",
    "SyncSettings",
    "configure_sync",
    "sync_settings_from_rig_yaml",
]

_log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class DeviceControls:
    """V4L2 controls to set on one device.

    Attributes:
        device: the V4L2 device node, e.g. ``/dev/video0``.
        controls: control name to integer value, set in this order.
    """

    device: str
    controls: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.device:
            raise CaptureError("a V4L2 device path is needed")
        for name, value in self.controls.items():
            if (
                not name.replace("_", "").isalnum()
                or isinstance(value, bool)
                or not isinstance(value, int)
            ):
                raise CaptureError(
                    f"{self.device}: control {name!r}={value!r} must be a name and an integer"
                )


@dataclass(frozen=True, kw_only=True)
class SyncSettings:
    """Sync controls for both cameras."""

    left: DeviceControls
    right: DeviceControls


PAPER_SYNC = SyncSettings(
    left=DeviceControls(
        device="/dev/video0", controls={"operation_mode": 0, "synchronizing_function": 1}
    ),
    right=DeviceControls(
        device="/dev/video1", controls={"operation_mode": 0, "synchronizing_function": 2}
    ),
)


def sync_settings_from_rig_yaml(text: str, *, where: str = "rig.yaml") -> SyncSettings | None:
    """Read the ``capture`` section of a rig file; None when it has none.

    Raises:
        CaptureError: when the section is malformed (the key and value are named).
    """
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise CaptureError(f"{where}: not valid YAML ({err})") from err
    cap = doc.get("capture") if isinstance(doc, dict) else None
    if cap is None:
        return None
    if not isinstance(cap, dict):
        raise CaptureError(f"{where}: 'capture' must be a mapping, got {type(cap).__name__}")

    def side(key: str) -> DeviceControls:
        entry: Any = cap.get(key)
        if not isinstance(entry, dict) or "device" not in entry:
            raise CaptureError(
                f"{where}: capture.{key} must be a mapping with 'device', got {entry!r}"
            )
        controls = entry.get("controls") or {}
        if not isinstance(controls, dict):
            raise CaptureError(
                f"{where}: capture.{key}.controls must be a mapping, got {controls!r}"
            )
        return DeviceControls(device=str(entry["device"]), controls=dict(controls))

    return SyncSettings(left=side("left"), right=side("right"))


def _run(cmd: list[str], timeout_s: float) -> str:
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired as err:
        raise CaptureError(f"{' '.join(cmd)} did not finish within {timeout_s} s") from err
    except OSError as err:
        raise CaptureError(f"cannot run {cmd[0]}: {err}") from err
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        last = lines[-1] if lines else "no output"
        raise CaptureError(f"{' '.join(cmd)} failed with status {proc.returncode}: {last}")
    return proc.stdout


def configure_sync(
    settings: SyncSettings = PAPER_SYNC, *, v4l2_ctl: str = "v4l2-ctl", timeout_s: float = 5.0
) -> dict[str, dict[str, int]]:
    """Set each camera's sync controls with ``v4l2-ctl`` and read them back.

    Returns:
        device -> control -> value read back.

    Raises:
        CaptureError: ``v4l2-ctl`` missing or failing, or a control that reads back a
            different value (device, control, wanted and read values named).
    """
    exe = shutil.which(v4l2_ctl)
    if exe is None:
        raise CaptureError(
            f"{v4l2_ctl} not found on PATH; install v4l-utils (apt-get install v4l-utils) "
            "or record without hardware sync (and configure the cameras yourself)"
        )
    readback: dict[str, dict[str, int]] = {}
    for dev in (settings.left, settings.right):
        if not dev.controls:
            continue
        cmd = [exe, "-d", dev.device]
        for name, value in dev.controls.items():
            cmd += ["-c", f"{name}={value}"]
        _log.info("sync: %s", " ".join(cmd))
        _run(cmd, timeout_s)
        out = _run([exe, "-d", dev.device, "-C", ",".join(dev.controls)], timeout_s)
        got: dict[str, int] = {}
        for line in out.splitlines():
            key, sep, val = line.partition(":")
            if sep:
                try:
                    got[key.strip()] = int(val.strip().split()[0], 0)
                except (ValueError, IndexError):
                    continue
        for name, want in dev.controls.items():
            if name not in got:
                raise CaptureError(
                    f"{dev.device}: control {name} could not be read back "
                    f"(v4l2-ctl printed {out.strip()!r})"
                )
            if got[name] != want:
                raise CaptureError(
                    f"{dev.device}: control {name} reads {got[name]} after "
                    f"setting {want}; camera sync is not configured"
                )
        readback[dev.device] = got
    return readback
