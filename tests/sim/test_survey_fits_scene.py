"""A long lawnmower survey stays over its scene: more lanes flown again, never longer ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.sim import SurveyConfig, builtin_scene
from sea3d.sim.motion import Lawnmower, lanes_within, poses
from sea3d.sim.survey import default_trajectory

FPS = 10.0


def _axis_on_floor(scene, T_world_body, tilt_deg: float) -> np.ndarray:
    """Where the view's centre meets the floor: the body's heading tilted down by the mount."""
    fwd = T_world_body[:, :3, 0]
    down = np.radians(tilt_deg)
    d = np.cos(down) * fwd + np.sin(down) * np.array([0.0, 0.0, -1.0])
    p = T_world_body[:, :3, 3]
    lo, _ = scene.bounds_m()
    floor = np.full(len(p), lo[2])
    for _ in range(5):  # fixed point: the floor's height where the axis meets it
        hit = p + ((p[:, 2] - floor) / -d[:, 2])[:, None] * d
        if scene.floor_height is None:
            break
        floor = np.asarray(scene.floor_height(hit[:, 0], hit[:, 1]), dtype=np.float64)
    return hit


@pytest.mark.parametrize("name", ["lake", "tank", "reef"])
def test_a_3000_frame_survey_keeps_its_view_over_the_scene(name: str) -> None:
    scene = builtin_scene(name)
    config = SurveyConfig(frames=3000, fps=FPS)
    traj = default_trajectory(scene, config)
    assert isinstance(traj, Lawnmower) and traj.lanes is not None
    t = np.arange(config.frames) / FPS
    T = poses(traj, t)
    lo, hi = scene.bounds_m()
    hit = _axis_on_floor(scene, T, config.tilt_deg())
    # Along y, the direction the lanes advance (the lanes' length along x is the scene's own
    # choice and unchanged; in the tank the view's end of a lane is on its walls).
    assert np.all(hit[:, 1] > lo[1]) and np.all(hit[:, 1] < hi[1])
    # Without the fit it leaves (the issue: past the 10 m lake after about 1,250 frames).
    free = poses(dataclasses.replace(traj, lanes=None), t)
    free_hit = _axis_on_floor(scene, free, config.tilt_deg())
    assert np.any(free_hit[:, 1] > hi[1])


def test_the_turn_back_is_smooth_and_flies_the_same_lanes() -> None:
    traj = default_trajectory(builtin_scene("lake"), SurveyConfig(frames=3000, fps=FPS))
    t = np.arange(0.0, 300.0, 0.01)
    p = traj.position_m(t)
    v = np.diff(p, axis=0) / 0.01
    # No jump in velocity anywhere (the fold falls mid-lane, where the y velocity is zero):
    # the largest change per 10 ms step is what the turns at the lane ends already have.
    dv = np.linalg.norm(np.diff(v, axis=0), axis=1)
    first_pass = t[1:-1] < traj.pass_s - 1.0
    assert dv.max() < 1.05 * dv[first_pass].max()
    # Heading follows the velocity through the fold
    R = traj.rotation(t)
    step = np.degrees(np.arccos(np.clip(
        (np.einsum("nij,nij->n", R[1:], R[:-1]) - 1) / 2, -1, 1)))
    assert step.max() < 1.05 * step[t[1:] < traj.pass_s - 1.0].max()
    assert p[:, 1].max() == pytest.approx(traj.center_m[1] + traj.lanes * traj.lane_spacing_m,
                                          abs=1e-6)


def test_short_surveys_are_unchanged() -> None:
    traj = default_trajectory(builtin_scene("lake"), SurveyConfig(frames=300, fps=FPS))
    t = np.arange(300) / FPS
    free = dataclasses.replace(traj, lanes=None)
    np.testing.assert_array_equal(traj.position_m(t), free.position_m(t))
    np.testing.assert_array_equal(traj.rotation(t), free.rotation(t))


def test_lanes_within() -> None:
    assert lanes_within(-1.0, 3.5, 0.5) == 9
    assert lanes_within(0.0, 0.1, 0.5) == 1


def test_sim_says_how_many_frames_the_scene_holds(tmp_path, capsys, monkeypatch) -> None:
    import sea3d.sim.survey as survey

    def stop(*a, **k):
        raise KeyboardInterrupt  # stop before rendering: only the plan is under test

    monkeypatch.setattr(survey, "simulate_survey", stop)
    assert main(["sim", "--scene", "lake", "--frames", "3000", "--size", "64x36", "-o",
                 str(tmp_path / "x.mcap")]) == 130
    out = capsys.readouterr().out
    assert "note: lake holds 9 lanes of this survey, 1170 frames at 10 fps" in out
