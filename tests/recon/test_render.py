"""Point-cloud pictures: z-buffering and framing."""

import numpy as np
import pytest

from sea3d.errors import ReconError
from sea3d.recon.render import render_points


def test_nearer_points_hide_farther_ones():
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [0.0, 0.0, 3.0]])
    cols = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    img = render_points(pts, cols, np.eye(4), size_px=(11, 11), splat_px=1)
    assert img[5, 5].tolist() == [0, 255, 0]
    assert img[0, 0].tolist() == [24, 24, 28]


def test_points_behind_the_view_are_not_drawn():
    img = render_points(
        np.array([[0.0, 0.0, -1.0]]),
        np.array([[255, 255, 255]], np.uint8),
        np.eye(4),
        size_px=(9, 9),
    )
    assert (img == [24, 24, 28]).all()


def test_bad_shapes():
    with pytest.raises(ReconError):
        render_points(np.zeros((3, 2)), np.zeros((3, 3), np.uint8), np.eye(4))
