"""Scenes: built-ins, YAML files, boards, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.calib.targets import parse_board
from sea3d.errors import SimulationError
from sea3d.sim.scene import builtin_scene, load_scene, sim_board


@pytest.mark.parametrize("name", ["tank", "lake", "reef"])
def test_builtin_scenes_build_with_a_seafloor_first(name: str) -> None:
    scene = builtin_scene(name)
    assert scene.objects[0].name == "seafloor"
    assert all(len(o.mesh.triangles) > 0 for o in scene.objects)


def test_tank_has_the_papers_dimensions() -> None:
    scene = builtin_scene("tank")
    wall = next(o for o in scene.objects if o.name == "tank_wall")
    v = np.asarray(wall.mesh.vertices)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), 1.23 / 2, atol=1e-9)
    assert v[:, 2].max() - v[:, 2].min() == pytest.approx(1.25)


def test_scene_yaml_file_loads(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(
        "name: mine\nseafloor: {size_m: [2, 2], resolution_m: 0.05, slope_deg: 5}\n"
        "objects:\n  - {type: aruco_cube, size_m: 0.1, position_m: [0, 0, 0]}\n"
        "  - {type: rock, radius_m: 0.1, position_m: [0.5, 0.5, 0]}\n"
        "  - {type: board, board: 'charuco:5x7:40mm:30mm', position_m: [0, 0, 0.5],"
        " rotation_deg: [180, 0, 0]}\n"
    )
    scene = load_scene(path)
    assert [o.name for o in scene.objects] == ["seafloor", "aruco_cube", "rock", "board_charuco"]
    cube = scene.objects[1]
    floor_z = scene.floor_height(np.array([0.0]), np.array([0.0]))[0]
    assert np.asarray(cube.mesh.vertices)[:, 2].min() == pytest.approx(floor_z - 0.01, abs=1e-9)


def test_bad_scenes_are_rejected_with_the_offending_value(tmp_path: Path) -> None:
    with pytest.raises(SimulationError, match="atlantis"):
        load_scene("atlantis")
    bad = tmp_path / "bad.yaml"
    bad.write_text("objects:\n  - {type: submarine}\n")
    with pytest.raises(SimulationError, match="submarine"):
        load_scene(bad)


def test_board_specs_parse_and_reject_garbage() -> None:
    b = sim_board("checkerboard:9x6:40mm")
    assert (b.corner_grid, b.square_m) == ((9, 6), pytest.approx(0.04))
    c = sim_board("charuco:5x7:4cm:3cm:DICT_4X4_50")
    # charuco counts squares: 5x7 squares have 4x6 inner corners
    assert (c.cols, c.rows, c.corner_grid) == (5, 7, (4, 6))
    assert (c.marker_m, c.dictionary) == (pytest.approx(0.03), "DICT_4X4_50")
    assert c == parse_board("charuco:5x7:4cm:3cm:DICT_4X4_50")  # the calibrator's board
    for text in ("checkerboard:9x6", "circles:4x11:20mm", "checkerboard:nine:40mm"):
        with pytest.raises(SimulationError, match="bad board spec"):
            sim_board(text)
    with pytest.raises(SimulationError, match="apriltag"):
        sim_board("apriltag:7x5:91.4mm:114.3mm")  # a calib board the simulator cannot draw
