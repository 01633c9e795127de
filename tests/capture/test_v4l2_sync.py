"""Camera sync through v4l2-ctl, with a fake v4l2-ctl on PATH that keeps control state."""

from __future__ import annotations

import os
import stat
import sys
import textwrap

import pytest

from sea3d.capture.v4l2_sync import (
    PAPER_SYNC,
    DeviceControls,
    configure_sync,
    sync_settings_from_rig_yaml,
)
from sea3d.errors import CaptureError

_FAKE = textwrap.dedent(
    """\
    #!{python}
    # Fake v4l2-ctl: -d DEV, -c name=value (set), -C a,b (get). State in $FAKE_V4L2_STATE.
    import json, os, sys
    state_path = os.environ["FAKE_V4L2_STATE"]
    state = json.load(open(state_path)) if os.path.exists(state_path) else {{}}
    args = sys.argv[1:]
    dev = args[args.index("-d") + 1]
    with open(state_path + ".log", "a") as log:
        log.write(" ".join(args) + "\\n")
    if not dev.startswith("/dev/video"):
        print(f"Cannot open device {{dev}}", file=sys.stderr); sys.exit(1)
    ctrls = state.setdefault(dev, {{}})
    ignore = os.environ.get("FAKE_V4L2_IGNORE", "")
    for i, a in enumerate(args):
        if a == "-c":
            k, v = args[i + 1].split("=")
            if k != ignore:
                ctrls[k] = int(v)
        if a == "-C":
            for k in args[i + 1].split(","):
                if k in ctrls:
                    print(f"{{k}}: {{ctrls[k]}}")
    json.dump(state, open(state_path, "w"))
    """
)


@pytest.fixture
def fake_v4l2(tmp_path, monkeypatch):
    bindir = tmp_path / "bin"
    bindir.mkdir()
    exe = bindir / "v4l2-ctl"
    exe.write_text(_FAKE.format(python=sys.executable))
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_V4L2_STATE", str(tmp_path / "state.json"))
    return tmp_path / "state.json"


def test_paper_sync_runs_the_papers_commands_and_reads_back(fake_v4l2):
    readback = configure_sync(PAPER_SYNC)
    assert readback == {
        "/dev/video0": {"operation_mode": 0, "synchronizing_function": 1},
        "/dev/video1": {"operation_mode": 0, "synchronizing_function": 2},
    }
    log = (fake_v4l2.parent / "state.json.log").read_text().splitlines()
    assert "-d /dev/video0 -c operation_mode=0 -c synchronizing_function=1" in log[0]
    assert "-d /dev/video1 -c operation_mode=0 -c synchronizing_function=2" in log[2]


def test_a_control_that_does_not_stick_is_an_error(fake_v4l2, monkeypatch):
    monkeypatch.setenv("FAKE_V4L2_IGNORE", "synchronizing_function")
    with pytest.raises(CaptureError, match="synchronizing_function could not be read back"):
        configure_sync(PAPER_SYNC)
    fake_v4l2.write_text('{"/dev/video0": {"synchronizing_function": 0}}')
    with pytest.raises(CaptureError, match="reads 0 after setting 1"):
        configure_sync(PAPER_SYNC)


def test_failing_device_and_missing_tool_are_reported(fake_v4l2, monkeypatch):
    bad = type(PAPER_SYNC)(
        left=DeviceControls(device="/nonexistent", controls={"a": 1}), right=PAPER_SYNC.right
    )
    with pytest.raises(CaptureError, match="failed with status 1: Cannot open device"):
        configure_sync(bad)
    monkeypatch.setenv("PATH", "/nonexistent-bin")
    with pytest.raises(CaptureError, match="v4l2-ctl not found"):
        configure_sync(PAPER_SYNC)


def test_rig_capture_section_is_read_and_checked():
    text = textwrap.dedent(
        """
        cameras: {}
        capture:
          left: {device: /dev/video2, controls: {operation_mode: 0, synchronizing_function: 1}}
          right: {device: /dev/video3, controls: {operation_mode: 0, synchronizing_function: 2}}
        """
    )
    s = sync_settings_from_rig_yaml(text)
    assert s is not None and s.left.device == "/dev/video2"
    assert dict(s.right.controls) == {"operation_mode": 0, "synchronizing_function": 2}
    assert sync_settings_from_rig_yaml("cameras: {}\n") is None
    with pytest.raises(CaptureError, match=r"capture\.right must be a mapping with 'device'"):
        sync_settings_from_rig_yaml("capture: {left: {device: /dev/video0}, right: 3}")
    with pytest.raises(CaptureError, match="must be a name and an integer"):
        sync_settings_from_rig_yaml(
            "capture: {left: {device: a, controls: {x: 1.5}}, right: {device: b}}"
        )
