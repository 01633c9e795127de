"""Rig files with implausible distortion or a duplicated key are refused."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.errors import RigFileError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.io.rig_file import distortion_coverage, load_rig, rig_to_yaml
from sea3d.refraction.presets import paper_rig

RIG = rig_to_yaml(paper_rig("none"))


def _pin(dist) -> PinholeCamera:
    return PinholeCamera(fx=180.4, fy=180.4, cx=160.0, cy=120.0, width=320, height=240,
                         dist=np.asarray(dist, float))  # fmt: skip


def test_a_huge_monotonic_k1_is_refused_naming_the_file_and_key(tmp_path):
    # k1 = 1e10 never folds (r (1 + k1 r^2) keeps growing), yet squeezes the whole image into
    # a pixel: `depth` then found 0.0 % valid and exited 0.
    assert distortion_coverage(_pin([1e10, 0, 0, 0, 0])) < 0.01
    text = RIG.replace("distortion: []", "distortion: [1.0e+10, 0, 0, 0, 0]", 1)
    assert text != RIG
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    with pytest.raises(RigFileError, match=r"rig\.yaml: key 'left\.distortion': .* keeps only"):
        load_rig(path)


@pytest.mark.parametrize("dist", [[-1e10, 0, 0, 0, 0], [0, 0, 0, 0, 1e12]])
def test_other_implausible_coefficients_are_refused(dist):
    assert distortion_coverage(_pin(dist)) < 0.5


@pytest.mark.parametrize(
    "dist",
    [
        [0.044, -0.008, 0, 0, 0],  # the in-air Sea3D calibration of shared/data
        [-0.28, 0.07, 0, 0, 0],  # a strong barrel (wide-angle) lens
        [0.05, 0.0, 0.001, -0.001, 0.0],  # mild pincushion with tangential terms
    ],
)
def test_real_lenses_keep_most_of_their_image(dist):
    assert distortion_coverage(_pin(dist)) > 0.8


def test_a_duplicated_key_is_refused_with_its_lines(tmp_path):
    lines = RIG.splitlines(keepends=True)
    i = next(k for k, ln in enumerate(lines) if "fx_px:" in ln)
    indent = lines[i][: len(lines[i]) - len(lines[i].lstrip())]
    lines.insert(i + 1, f"{indent}fx_px: 400.0\n")  # a pasted line: was silently last-wins
    path = tmp_path / "rig.yaml"
    path.write_text("".join(lines))
    with pytest.raises(
        RigFileError, match=rf"rig\.yaml: key 'fx_px' is given twice \(lines {i + 1} and {i + 2}\)"
    ):
        load_rig(path)


def test_anchors_and_merge_keys_are_still_allowed(tmp_path):
    from sea3d.io.rig_file import safe_yaml

    data = safe_yaml("base: &b {a: 1}\nx:\n  <<: *b\n  c: 2\ny: *b\n", "t.yaml")
    assert data["x"] == {"a": 1, "c": 2} and data["y"] == {"a": 1}
