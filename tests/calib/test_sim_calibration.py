"""Port calibration on the simulator's rendered in-water images (``sea3d.sim``), the issue's
validation: known dome centres, boards at 0.5-2.5 m, detected by OpenCV from the images."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.calib.port import PortCalibConfig, calibrate_port_rig
from sea3d.calib.targets import detect_board, parse_board
from sea3d.refraction import DomePort
from sea3d.refraction.presets import paper_rig

sim = pytest.importorskip("sea3d.sim", reason="the simulator (sea3d.sim) is not installed")

# The issue: each dome-centre axis within 0.2 mm, the focal length within 0.3 %.
DOME_CENTER_TOL_M = 0.2e-3
FOCAL_REL_TOL = 3e-3
# In-water extrinsics: measured 0.02 mm with 20 views; 0.5 mm is the paper-level requirement
# (its baseline is 107 mm).
TRANSLATION_TOL_M = 0.5e-3
CENTER_LEFT_M = (-0.54e-3, 0.58e-3, 2.10e-3)  # paper Table 3.7
CENTER_RIGHT_M = (1.5e-3, -2.0e-3, -1.0e-3)


@pytest.mark.slow
def test_dome_centres_and_focal_length_from_simulated_images() -> None:
    size = (1280, 720)  # two thirds of the paper's 1920x1080, to keep the test short
    rig = paper_rig("dome", size_px=size, dome_center_left_m=CENTER_LEFT_M,
                    dome_center_right_m=CENTER_RIGHT_M)
    spec = "checkerboard:9x6:95mm"  # the paper's board squares
    cal = sim.render_calibration_set(rig, spec, 12, medium="water", seed=1,
                                     distance_range_m=(0.5, 2.5), supersample=2)
    board = parse_board(spec)
    left = [detect_board(im, board).with_name(f"left{k:02d}") for k, im in enumerate(cal.lefts)]
    right = [detect_board(im, board).with_name(f"right{k:02d}")
             for k, im in enumerate(cal.rights)]
    assert sum(d.ok for d in left) >= 10 and sum(d.ok for d in right) >= 10
    start = DomePort(center_m=np.zeros(3), inner_radius_m=31.25e-3, thickness_m=3.1e-3)
    air = paper_rig("none", size_px=size)
    truth_pin = air.left
    # The in-air focal length 1 % off: the fit must find it.
    from sea3d.geometry.pinhole import PinholeCamera

    assert isinstance(truth_pin, PinholeCamera)
    off = PinholeCamera(fx=truth_pin.fx * 1.01, fy=truth_pin.fy * 1.01, cx=truth_pin.cx,
                        cy=truth_pin.cy, width=truth_pin.width, height=truth_pin.height)
    air_off = type(air)(left=off, right=off, T_left_right=air.T_left_right)
    res = calibrate_port_rig(air_off, start, start, left, right,
                             PortCalibConfig(refine_focal=True))
    assert res.ok, res.message
    for r, centre in ((res.left, CENTER_LEFT_M), (res.right, CENTER_RIGHT_M)):
        err = r.dome_center_m - np.asarray(centre)
        assert np.all(np.abs(err) < DOME_CENTER_TOL_M), err
        assert r.camera is not None
        assert r.camera.pinhole.fx == pytest.approx(truth_pin.fx, rel=FOCAL_REL_TOL)
    np.testing.assert_allclose(res.T_left_right[:3, 3], rig.T_left_right[:3, 3],
                               atol=TRANSLATION_TOL_M)
    for _left, _right, reason in res.views_rejected:
        assert reason
