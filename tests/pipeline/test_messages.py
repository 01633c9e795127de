"""Messages that say what went wrong, not what happened to fail next."""

from __future__ import annotations

import numpy as np
import pytest

from _rigs import real_sea3d_rig
from sea3d.errors import ConfigError, ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.io.mesh_files import write_mesh
from sea3d.monodepth.align import align_depth
from sea3d.pipeline.frame_stage import FrameStageConfig


def test_an_empty_mesh_is_named_empty_not_a_refused_format(tmp_path):
    empty = Mesh(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int32))
    with pytest.raises(ReconError, match=r"mesh\.ply: the mesh is empty \(0 vertices, 0 "
                       r"triangles\): nothing was fused") as err:  # fmt: skip
        write_mesh(tmp_path / "mesh.ply", empty)
    assert "refused the format" not in str(err.value)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["nosuch.module:fn", "sea3d.enhance:no_such_function"])
def test_an_enhancement_that_cannot_be_found_is_a_config_error_before_any_frame(name):
    with pytest.raises(ConfigError, match=rf"cannot find the enhancement '{name}'"):
        FrameStageConfig(rig=real_sea3d_rig(), enhance=name)


def test_the_cli_says_the_enhancement_cannot_be_found(sim_session, tmp_path, capsys):
    from sea3d.cli import main

    rc = main(["process", str(sim_session), "-o", str(tmp_path / "o"), "--workers", "0",
               "--enhance", "nosuch.module:fn"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc != 0
    assert "cannot find the enhancement 'nosuch.module:fn'" in err
    assert "no frame could be processed" not in err


def test_a_network_that_outputs_nan_is_said_to_give_no_finite_depth():
    sparse = np.full((20, 30), np.nan)
    sparse[::3, ::3] = 2.0
    depth, how = align_depth(np.full((20, 30), np.nan), sparse)
    assert how.status == "failed"
    assert how.message.startswith("the network produced no finite depth: all 600 values")
    assert np.isnan(depth).all()
    # a finite prediction with too few samples keeps the old, true message
    _, how = align_depth(np.ones((20, 30)), np.full((20, 30), np.nan))
    assert how.message.startswith("only 0 sparse depth samples")


@pytest.mark.slow  # about 10 s on a loaded 2-core machine; the readers' tests are in tests/io
def test_process_never_uses_a_renamed_image_of_a_folder_session(sim_session, tmp_path, caplog):
    """The issue's headline: `mv left/T.png left/T'.png` was processed at the wrong stamp and
    `process` exited 0 with three times the trajectory error."""
    import csv
    import logging
    import os

    from sea3d.io.session import convert_session, open_session
    from sea3d.pipeline.process import ExecutorConfig, ProcessConfig, run_process

    folder = tmp_path / "dive"
    convert_session(sim_session, folder)
    with open_session(folder) as s:
        stamps = s.stamps("left").tolist()
    moved = stamps[1]
    new = moved + 50_000_000  # half a frame interval later
    os.replace(folder / "left" / f"{moved}.png", folder / "left" / f"{new}.png")
    with caplog.at_level(logging.WARNING):
        res = run_process(folder, ProcessConfig(out_dir=tmp_path / "out",
                                                executor=ExecutorConfig(workers=0),
                                                max_frames=4))  # fmt: skip
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert f"{new}.png" in text and "no line in checksums.csv" in text
    with open(res.out_dir / "status.csv") as fh:
        used = [int(row["t_ns"]) for row in csv.DictReader(fh)]
    assert new not in used and moved not in used
    assert used == [t for t in stamps if t != moved][:4]
