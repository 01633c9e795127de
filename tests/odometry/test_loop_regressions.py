"""Loop candidates that once passed verification with a wrong pose, kept as data.

Both come from a 600-frame lawnmower survey of the simulator's lake scene (640x360, coastal
water, seed 7) at the keyframes where the odometry closed them: their ORB features, rectified
pixels and 3D points, for the query, the candidate and the candidate's local map, and the true
relative pose. Closed with the poses PnP gave them, they made the survey's trajectory 2.5 times
worse than without loop closure.

- ``ambiguous``: 27 inliers over a fifth of the view; PnP traded 3.4 degrees of rotation for
  93 mm of translation.
- ``crowded``: 31 inliers in a patch of 34 x 24 pixels; PnP was 80 degrees and 2.2 m off.

A loop either is refused or comes within the stated tolerance of the truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.geometry.se3 import R_to_rotvec
from sea3d.odometry import OdometryConfig
from sea3d.odometry.loop import PlaceFeatures, verify_loop
from tolerances import LOOP_RIGHT_DEG, LOOP_RIGHT_M

DATA = Path(__file__).resolve().parents[1] / "data" / "loops" / "lake_survey_loops.npz"


def _case(name: str):
    d = np.load(DATA)
    places = [
        PlaceFeatures(uv=d[f"{name}_uv_{i}"], descriptors=d[f"{name}_desc_{i}"],
                      points_rect=d[f"{name}_points_{i}"])
        for i in range(int(d[f"{name}_places"]))
    ]
    return places[0], places[1], places[2:], d["K"], d[f"{name}_T_cand_query_true"]


def _error(T_est, T_true):
    D = np.linalg.inv(T_true) @ T_est
    rotation_deg = np.degrees(np.linalg.norm(R_to_rotvec(D[:3, :3])))
    return float(np.linalg.norm(D[:3, 3])), float(rotation_deg)


@pytest.mark.parametrize("name", ["ambiguous", "crowded"])
def test_a_loop_is_refused_or_right(name) -> None:
    query, cand, local, K, T_true = _case(name)
    c = OdometryConfig()
    found = verify_loop(query, cand, 1, K, min_inliers=c.loop_min_inliers, local_map=local,
                        min_spread=c.loop_min_spread)
    if found is not None:
        err_m, err_deg = _error(found.T_cand_query, T_true)
        assert err_m < LOOP_RIGHT_M and err_deg < LOOP_RIGHT_DEG


def test_the_ambiguous_loop_is_kept_and_fitted_in_3d() -> None:
    """Its inliers have depth in both keyframes: the rigid 3D fit pins what PnP left loose."""
    query, cand, local, K, T_true = _case("ambiguous")
    c = OdometryConfig()
    found = verify_loop(query, cand, 1, K, min_inliers=c.loop_min_inliers, local_map=local,
                        min_spread=c.loop_min_spread)
    assert found is not None
    assert found.consistent_3d >= c.loop_min_inliers // 2
    # without the 3D fit (no depth in the query) the same matches give PnP's pose, far off
    blind = PlaceFeatures(uv=query.uv, descriptors=query.descriptors,
                          points_rect=np.full_like(query.points_rect, np.nan))
    pnp = verify_loop(blind, cand, 1, K, min_inliers=c.loop_min_inliers, local_map=local,
                      min_spread=c.loop_min_spread)
    assert pnp is not None and _error(pnp.T_cand_query, T_true)[0] > LOOP_RIGHT_M


def test_the_crowded_loop_is_refused_for_its_spread() -> None:
    query, cand, local, K, _ = _case("crowded")
    c = OdometryConfig()
    kwargs = dict(min_inliers=c.loop_min_inliers, local_map=local)
    assert verify_loop(query, cand, 1, K, min_spread=c.loop_min_spread, **kwargs) is None
    assert verify_loop(query, cand, 1, K, min_spread=0.0, **kwargs) is not None
