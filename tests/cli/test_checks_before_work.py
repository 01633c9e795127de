"""Arguments that a command can check without doing anything are checked first.

Each test replaces the command's expensive step (matching, the live run, opening cameras) with
one that fails the test, so a refusal that comes after the work shows up as that failure, not
as a slow run; the refusal itself is exit status 2, one line naming the flag, and no output.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import pytest

from _rigs import real_sea3d_rig
from sea3d.cli import main
from sea3d.io.rig_file import save_rig


def _no_work(real):
    """A stand-in for ``real`` (same signature, for the parser's defaults) that fails the test."""

    @functools.wraps(real)
    def fail(*args, **kwargs):
        raise AssertionError(f"{real.__name__} ran before the arguments were checked")

    return fail


def _one_line_error(capsys, *names: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("sea3d: error: ")
    for name in names:
        assert name in err, err
    return err


@pytest.fixture
def raw_pair(tmp_path):
    rng = np.random.default_rng(0)
    rig = real_sea3d_rig(size_px=(96, 64))
    save_rig(rig, tmp_path / "rig.yaml")
    for side in ("left", "right"):
        img = rng.integers(0, 256, (64, 96, 3), dtype=np.uint8)
        assert cv2.imwrite(str(tmp_path / f"{side}.png"), img)
    return tmp_path


@pytest.mark.parametrize("name", ["dnoext", "depth.jpg"])
def test_depth_refuses_an_unknown_output_suffix_before_matching(raw_pair, monkeypatch, capsys,
                                                                name):
    import sea3d.pipeline.depth_pair as depth_pair

    monkeypatch.setattr(depth_pair, "depth_pair", _no_work(depth_pair.depth_pair))
    out = raw_pair / name
    assert main(["depth", "--rig", str(raw_pair / "rig.yaml"), "--left",
                 str(raw_pair / "left.png"), "--right", str(raw_pair / "right.png"),
                 "-o", str(out)]) == 2
    err = _one_line_error(capsys, "-o/--output", name, ".png", ".npy", ".pfm", ".tiff")
    assert "unknown" not in err.split(":")[0]
    assert not out.exists()


def test_depth_refuses_a_points_file_that_is_not_ply_before_matching(raw_pair, monkeypatch,
                                                                    capsys):
    import sea3d.pipeline.depth_pair as depth_pair

    monkeypatch.setattr(depth_pair, "depth_pair", _no_work(depth_pair.depth_pair))
    assert main(["depth", "--rig", str(raw_pair / "rig.yaml"), "--left",
                 str(raw_pair / "left.png"), "--right", str(raw_pair / "right.png"),
                 "-o", str(raw_pair / "d.tiff"), "--points", str(raw_pair / "cloud")]) == 2
    _one_line_error(capsys, "--points", ".ply")
    assert not (raw_pair / "d.tiff").exists()


@pytest.mark.parametrize("flag", ["-o", "--confidence"])
def test_stereo_refuses_an_unknown_output_suffix_before_matching(raw_pair, monkeypatch, capsys,
                                                                 flag):
    import sea3d.stereo

    monkeypatch.setattr(sea3d.stereo, "match", _no_work(sea3d.stereo.match))
    outputs = {"-o": str(raw_pair / "d.pfm"), "--confidence": str(raw_pair / "c.pfm")}
    outputs[flag] = str(raw_pair / "noext")
    assert main(["stereo", str(raw_pair / "left.png"), str(raw_pair / "right.png"),
                 "--max-disparity", "15", "--engine", "opencv", "-o", outputs["-o"],
                 "--confidence", outputs["--confidence"]]) == 2
    _one_line_error(capsys, flag, "noext", ".pfm", ".npy", ".tiff")
    assert not any(raw_pair.glob("*.pfm")) and not (raw_pair / "noext").exists()


@pytest.mark.parametrize("rate", ["0", "-1"])
def test_live_refuses_a_rate_not_above_zero_before_the_replay(tmp_path, monkeypatch, capsys,
                                                              rate):
    import sea3d.pipeline.live as live

    monkeypatch.setattr(live, "run_live_replay", _no_work(live.run_live_replay))
    out = tmp_path / "out"
    assert main(["live", "--replay", str(tmp_path / "s.mcap"), "-o", str(out),
                 "--rate", rate]) == 2
    _one_line_error(capsys, "--rate", "> 0")
    assert not out.exists()


def test_live_refuses_to_record_onto_an_existing_session_before_opening_cameras(
        tmp_path, monkeypatch, capsys):
    import sea3d.capture.spec as spec
    import sea3d.pipeline.live as live

    monkeypatch.setattr(spec, "open_source", _no_work(spec.open_source))
    monkeypatch.setattr(live, "run_live_cameras", _no_work(live.run_live_cameras))
    existing = tmp_path / "s.mcap"
    existing.write_bytes(b"an earlier recording")
    out = tmp_path / "out"
    assert main(["live", "--record", str(existing), "--left", "test:left", "--right",
                 "test:right", "-o", str(out)]) == 2
    _one_line_error(capsys, "--record", str(existing), "exists")
    assert existing.read_bytes() == b"an earlier recording"
    assert not out.exists()


def test_live_replay_library_refuses_a_bad_rate_before_opening_the_session(tmp_path):
    from sea3d.errors import ConfigError
    from sea3d.pipeline.live import run_live_replay
    from sea3d.pipeline.process import ProcessConfig

    config = ProcessConfig(out_dir=tmp_path / "out", report=False)
    with pytest.raises(ConfigError, match="rate must be > 0"):
        run_live_replay(tmp_path / "missing.mcap", config, rate=0.0)


@pytest.mark.parametrize("layout", ["mcap", "folder"])
def test_sim_refuses_an_existing_session_before_loading_the_scene(tmp_path, monkeypatch, capsys,
                                                                  layout):
    import sea3d.sim.scene as scene

    monkeypatch.setattr(scene, "load_scene", _no_work(scene.load_scene))
    if layout == "mcap":
        out = tmp_path / "s.mcap"
        out.write_bytes(b"an earlier session")
    else:
        out = tmp_path / "s"
        (out / "left").mkdir(parents=True)
        (out / "left" / "0.png").write_bytes(b"an earlier image")
    assert main(["sim", "--scene", "lake", "--frames", "2", "--size", "64x48",
                 "-o", str(out)]) == 2
    _one_line_error(capsys, str(out), "refusing to overwrite")
    assert not (tmp_path / f"{out.stem}_gt").exists()


def test_enhance_refuses_an_unknown_output_suffix_before_enhancing(raw_pair, monkeypatch,
                                                                   capsys):
    import sea3d.enhance.api as api

    monkeypatch.setattr(api, "enhance_image", _no_work(api.enhance_image))
    assert main(["enhance", str(raw_pair / "left.png"), "--method", "grey-world",
                 "-o", str(raw_pair / "restored.xyz")]) == 2
    _one_line_error(capsys, "-o/--output", "restored.xyz", ".png", ".jpg")
    assert not (raw_pair / "restored.xyz").exists()


@pytest.mark.parametrize(("name", "names"), [
    ("depthnoext", ("-o/--output", ".png", ".npy")),
    ("relative.png", ("relative (not metric)", ".npy/.pfm/.tiff")),
])
def test_mono_depth_refuses_an_output_it_cannot_write_before_loading_the_network(
        raw_pair, monkeypatch, capsys, name, names):
    import sea3d.monodepth

    monkeypatch.setattr(sea3d.monodepth, "OnnxDepthModel",
                        _no_work(sea3d.monodepth.OnnxDepthModel))
    out = raw_pair / name
    assert main(["mono-depth", str(raw_pair / "left.png"), "--model",
                 str(raw_pair / "net.onnx"), "-o", str(out)]) == 2
    _one_line_error(capsys, name, *names)
    assert not out.exists()


@pytest.mark.parametrize("flag", ["-o", "--cloud"])
def test_fuse_refuses_an_unknown_output_suffix_before_fusing(tmp_path, monkeypatch, capsys,
                                                             flag):
    import sea3d.pipeline.fuse as fuse
    from sea3d.io.trajectory_files import write_tum

    monkeypatch.setattr(fuse, "fuse_rgbd", _no_work(fuse.fuse_rgbd))
    assert cv2.imwrite(str(tmp_path / "0.jpg"), np.zeros((48, 64, 3), np.uint8))
    assert cv2.imwrite(str(tmp_path / "0.png"), np.full((48, 64), 1000, np.uint16))
    write_tum(tmp_path / "p.tum", [0], np.eye(4)[None])
    outputs = {"-o": str(tmp_path / "mesh.ply"), "--cloud": str(tmp_path / "cloud.ply")}
    outputs[flag] = str(tmp_path / "noext")
    assert main(["fuse", "--color", str(tmp_path / "*.jpg"), "--depth", str(tmp_path / "*.png"),
                 "--poses", str(tmp_path / "p.tum"), "--intrinsics", "50", "50", "32", "24",
                 "--voxel-m", "0.02", "-o", outputs["-o"], "--cloud", outputs["--cloud"]]) == 2
    _one_line_error(capsys, flag, "noext", ".ply")
    assert not any(tmp_path.glob("*.ply")) and not (tmp_path / "noext").exists()


def _earlier_session(tmp_path):
    existing = tmp_path / "s.mcap"
    existing.write_bytes(b"an earlier recording")
    return existing


@pytest.mark.parametrize(("args", "names"), [
    (["-o", "{existing}"], ("-o/--output", "s.mcap", "already exists")),
    (["-o", "{tmp}/dive.png"], ("-o/--output", "dive.png", "'.png'", ".mcap file or a folder",
                                "--format folder")),
    (["-o", "{tmp}/dive.mcap", "--format", "folder"], ("-o/--output", "dive.mcap",
                                                       "--format folder")),
    (["-o", "{tmp}/dive", "--image-encoding", "raw"], ("--image-encoding raw", "MCAP only",
                                                       "dive")),
    (["-o", "{tmp}/d.mcap", "--duration", "0"], ("--duration", "> 0")),
    (["-o", "{tmp}/d.mcap", "--duration", "nan"], ("--duration", "nan")),
    (["-o", "{tmp}/d.mcap", "--min-free-gb", "nan"], ("--min-free-gb", "nan")),
    (["-o", "{tmp}/d.mcap", "--min-free-gb", "inf"], ("--min-free-gb", "inf")),
    (["-o", "{tmp}/d.mcap", "--queue", "0"], ("--queue", ">= 1")),
    (["-o", "{tmp}/d.mcap", "--jpeg-quality", "200"], ("--jpeg-quality", "0..100")),
    (["-o", "{tmp}/d.mcap", "--stall-warn", "0"], ("--stall-warn", "> 0")),
    (["-o", "{tmp}/d.mcap", "--stall-stop", "1"], ("--stall-stop", ">= --stall-warn (2)")),
])
def test_record_refuses_its_arguments_before_opening_or_syncing_cameras(
        tmp_path, monkeypatch, capsys, args, names):
    """Opening the cameras (and configuring their sync) takes seconds and changes the
    devices' state: every argument that can be checked without them is checked first."""
    import sea3d.capture.spec as spec
    import sea3d.capture.v4l2_sync as v4l2_sync

    monkeypatch.setattr(spec, "open_source", _no_work(spec.open_source))
    monkeypatch.setattr(v4l2_sync, "configure_sync", _no_work(v4l2_sync.configure_sync))
    existing = _earlier_session(tmp_path)
    argv = [a.format(existing=existing, tmp=tmp_path) for a in args]
    assert main(["record", "--left", "0", "--right", "1", "--sync", *argv]) == 2
    _one_line_error(capsys, *names)
    assert existing.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mcap"]


@pytest.mark.parametrize(("args", "names"), [
    (["-o", "{existing}"], ("-o/--output", "s.mcap", "already exists")),
    (["-o", "{tmp}/restored.png"], ("-o/--output", "restored.png", ".mcap file or a folder")),
    (["-o", "{tmp}/restored.mcap", "--format", "folder"], ("-o/--output", "--format folder")),
    (["-o", "{tmp}/restored.mcap", "--method", "clahe", "--clip-limit", "-1"],
     ("--clip-limit", "> 0")),
])
def test_enhance_session_refuses_its_arguments_before_opening_the_session(
        tmp_path, monkeypatch, capsys, args, names):
    import sea3d.io.session as session

    monkeypatch.setattr(session, "open_session", _no_work(session.open_session))
    existing = _earlier_session(tmp_path)
    argv = [a.format(existing=existing, tmp=tmp_path) for a in args]
    assert main(["enhance", "--session", str(existing), *argv]) == 2
    _one_line_error(capsys, *names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mcap"]


def test_enhance_refuses_a_clip_limit_not_above_zero_before_reading_the_image(
        raw_pair, monkeypatch, capsys):
    import sea3d.cli.enhance as cli_enhance

    monkeypatch.setattr(cli_enhance, "_read_image", _no_work(cli_enhance._read_image))
    out = raw_pair / "restored.png"
    assert main(["enhance", str(raw_pair / "left.png"), "--method", "clahe", "--clip-limit",
                 "0", "-o", str(out)]) == 2
    _one_line_error(capsys, "--clip-limit", "> 0")
    assert not out.exists()


def test_live_refuses_to_record_into_a_name_with_a_file_suffix_before_opening_cameras(
        tmp_path, monkeypatch, capsys):
    import sea3d.capture.spec as spec
    import sea3d.pipeline.live as live

    monkeypatch.setattr(spec, "open_source", _no_work(spec.open_source))
    monkeypatch.setattr(live, "run_live_cameras", _no_work(live.run_live_cameras))
    out = tmp_path / "out"
    assert main(["live", "--record", str(tmp_path / "dive.mp4"), "--left", "0", "--right", "1",
                 "-o", str(out)]) == 2
    err = _one_line_error(capsys, "--record", "dive.mp4", ".mcap file or a folder")
    assert "--format" not in err  # live has no --format
    assert not any(tmp_path.iterdir())
