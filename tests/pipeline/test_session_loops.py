"""The session loops behind ``sea3d depth --session``, ``enhance --session`` and ``mono-depth
SESSION`` as library calls: each returns its result and hands every frame to the caller."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.errors import EnhanceError, MonoDepthError
from sea3d.io.rig_file import resolve_rig
from sea3d.io.session import open_session
from sea3d.pipeline.depth_session import depth_session
from sea3d.pipeline.enhance_session import SessionEnhancement
from sea3d.pipeline.monodepth_session import monodepth_session
from sea3d.stereo.recipe import DepthConfig, StereoDepth


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("loops") / "s.mcap"
    assert main(["-q", "sim", "--scene", "lake", "--frames", "2", "--size", "320x180",
                 "--water", "none", "--out", str(path)]) == 0
    return path


def _stereo(reader) -> StereoDepth:  # type: ignore[no-untyped-def]
    return StereoDepth(resolve_rig(None, reader), DepthConfig(engine="opencv"))


def test_depth_session_hands_each_pair_on_and_sums_them_up(session: Path) -> None:
    got: list[tuple[int, float]] = []
    with open_session(session) as reader:
        stereo = _stereo(reader)
        res = depth_session(reader, stereo, on_pair=lambda t, r: got.append(
            (t, float(np.isfinite(r.depth_m).mean()))))
    assert [t for t, _ in got] == [0, 100_000_000]
    assert res.pairs == 2 and res.unpaired_left == res.unpaired_right == 0
    assert res.mean_valid_fraction == pytest.approx(np.mean([v for _, v in got]), abs=1e-12)
    assert 0.3 < res.mean_valid_fraction <= 1.0  # the lake fills most of the view
    assert res.refractive is True and res.depth_range_m == stereo.depth_range_m


def test_enhance_session_refuses_seathru_without_stereo_before_writing(session: Path) -> None:
    with open_session(session) as reader, pytest.raises(EnhanceError, match="needs stereo"):
        SessionEnhancement(reader, "seathru")


def test_enhance_session_counts_a_status_per_pair(session: Path) -> None:
    seen: list[int] = []
    with open_session(session) as reader:
        res = SessionEnhancement(reader, "grey-world").run(
            lambda pair, lo, ro, status: seen.append(pair.t_ns))
    assert seen == [0, 100_000_000] and res.pairs == 2 and sum(res.status_counts.values()) == 2


class _Oracle:
    """A 'network' whose output is the inverse of a depth map known for each view."""

    def __init__(self) -> None:
        self.inverse: dict[str, np.ndarray] = {}

    def predict(self, image: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
        return self.inverse[hashlib.sha1(image.tobytes()).hexdigest()], {"inference_s": 0.0}


def test_monodepth_session_aligns_every_pair_to_stereo(session: Path) -> None:
    oracle = _Oracle()
    written: dict[int, np.ndarray] = {}
    with open_session(session) as reader:
        stereo = _stereo(reader)
        for pair in reader.pairs():
            r = stereo.compute(pair.left, pair.right)
            inv = (0.5 / r.depth_m).astype(np.float32)  # inverse depth at half the scale
            oracle.inverse[hashlib.sha1(r.rect_left.tobytes()).hexdigest()] = np.nan_to_num(inv)
        with pytest.raises(MonoDepthError, match="give stereo depth or SfM points"):
            monodepth_session(reader, oracle, kind="inverse", on_frame=written.__setitem__)
        res = monodepth_session(reader, oracle, kind="inverse", stereo=stereo,
                                on_frame=written.__setitem__)
    assert res.aligned == 2 and res.frame == "rect_left" and sorted(written) == [0, 100_000_000]
    assert [f["t_ns"] for f in res.frames] == [0, 100_000_000]
    for f in res.frames:
        assert f["alignment"]["status"] == "ok"
        assert f["alignment"]["scale"] == pytest.approx(2.0, rel=1e-3)
    assert res.median_rel_error is not None and res.median_rel_error < 1e-3
