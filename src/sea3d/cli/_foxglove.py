"""``--foxglove HOST:PORT`` for ``sea3d record`` and ``sea3d monitor``: start the Foxglove
WebSocket server and the bridge that feeds it (see :mod:`sea3d.capture.foxglove_live`)."""

from __future__ import annotations

import logging
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sea3d.capture.foxglove_live import FoxgloveBridge, FoxglovePublisher
    from sea3d.capture.monitor import SessionPlayer
    from sea3d.capture.recorder import Recorder
    from sea3d.geometry.rig import StereoRig
    from sea3d.pipeline.live_publish import LiveFeed

__all__ = ["FOXGLOVE_HELP", "start_foxglove"]

_log = logging.getLogger(__name__)

FOXGLOVE_HELP = (
    "also serve the Foxglove WebSocket protocol on HOST:PORT (e.g. 127.0.0.1:8765): both "
    "cameras, IMU, echosounder, a depth image; open it in Foxglove or Lichtblick"
)


def _rig(rig_yaml: str | None) -> StereoRig | None:
    if not rig_yaml:
        return None
    from sea3d.errors import Sea3dError
    from sea3d.io.rig_file import rig_from_yaml

    try:
        return rig_from_yaml(rig_yaml, "the session's rig.yaml")
    except Sea3dError as err:
        _log.warning("Foxglove: no camera calibration or depth: %s", err)
        return None


def start_foxglove(
    address: str,
    provider: Recorder | SessionPlayer | LiveFeed,
    *,
    rig_yaml: str | None = None,
    replay: SessionPlayer | None = None,
    required: bool = True,
) -> tuple[FoxglovePublisher, FoxgloveBridge] | None:
    """Start a publisher on ``address`` and a bridge from ``provider``.

    Args:
        address: ``HOST:PORT`` (host defaults to 127.0.0.1, port to 8765).
        provider: a Recorder (its listener hook is registered) or a SessionPlayer.
        rig_yaml: the rig's text, for camera calibrations and depth.
        replay: the SessionPlayer when replaying (its IMU and echosounder series are
            published with the frames and stamps are shifted to now).
        required: raise when the server cannot start; otherwise warn and return None (the
            recording goes on without it).

    Returns:
        ``(publisher, bridge)`` (call ``bridge.stop()`` then ``publisher.stop()``), or None.

    Raises:
        CaptureError: the address cannot be bound and ``required``.
    """
    from sea3d.capture.foxglove_live import FoxgloveBridge, FoxgloveConfig, FoxglovePublisher
    from sea3d.capture.monitor import parse_address
    from sea3d.capture.recorder import Recorder
    from sea3d.errors import CaptureError
    from sea3d.pipeline.live_preview import DepthPreview

    host, port = parse_address(address, default_port=8765)
    try:
        publisher = FoxglovePublisher(FoxgloveConfig(host=host, port=port), rig=_rig(rig_yaml))
    except CaptureError as err:
        if required:
            raise
        print(f"sea3d: warning: {err}; recording goes on without Foxglove", file=sys.stderr)
        return None
    bridge = FoxgloveBridge(
        publisher,
        provider,
        imu=None if replay is None else replay.imu,
        sonar=None if replay is None else replay.sonar,
        restamp=replay is not None,
        depth=DepthPreview(publisher.rig, publisher.config.depth_width_px),
    )
    if replay is None and isinstance(provider, Recorder):  # a live feed hands no records on
        provider.add_listener(bridge.on_record)
    bridge.start()
    print(f"Foxglove at {publisher.url}", file=sys.stderr, flush=True)
    return publisher, bridge
