"""Hostile rig files: physics checks, YAML limits, encodings, and mangled text.

Every bad rig must end in one :class:`RigFileError` naming the file and the key, of bounded
length, never a traceback; every rig that loads must be physically possible.
"""

from __future__ import annotations

import copy
import os
import resource
import tracemalloc

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sea3d.errors import RigFileError
from sea3d.io.rig_file import (
    check_rig_physics,
    load_rig,
    rig_from_dict,
    rig_from_yaml,
    rig_to_dict,
    rig_to_yaml,
)
from sea3d.refraction.presets import paper_rig


def _examples(ci: int) -> int:
    """Examples per property: ``ci`` in the default profile, 1000 with SEA3D_DRILLS=full."""
    return 1000 if os.environ.get("SEA3D_DRILLS") == "full" else ci


# A message is one line a person reads: bounded whatever the file holds.
MAX_MESSAGE_CHARS = 1000
GOOD = rig_to_dict(paper_rig("dome"))
GOOD_TEXT = rig_to_yaml(paper_rig("dome"))


def _edited(**changes: object) -> dict:
    data = copy.deepcopy(GOOD)
    for dotted, value in changes.items():
        node = data
        *path, last = dotted.split("__")
        for key in path:
            node = node[key]
        node[last] = value
    return data


@pytest.mark.parametrize(
    ("changes", "key", "why"),
    [
        ({"left__port__thickness_m": 10.0}, "left.port.thickness_m", "not below the inner radius"),
        ({"right__port__n_water": 1e308}, "right.port.n_water", "outside the range of real"),
        ({"left__port__n_glass": 0.5}, "left.port", "n_glass must be a finite index >= 1"),
        ({"left__port__inner_radius_m": 5.0}, "left.port.inner_radius_m", "larger than any dome"),
        ({"left__port__center_m": [0.0, 0.0, 0.04]}, "left.port", "outside the dome"),
        ({"image_width_px": 10**9}, "image_width_px", "outside the range of cameras"),
        ({"image_width_px": 40_000, "image_height_px": 40_000}, "image_width_px", "cameras"),
        ({"left__cx_px": 5000.0}, "left.cx_px", "outside the 1920x1080 image"),
        ({"right__cy_px": -3.0}, "right.cx_px", "outside the 1920x1080 image"),
        ({"left__fx_px": 1e-3}, "left.fx_px", "not between 1/100 and 100 image widths"),
        ({"left__distortion": [-2.0, 0.0, 0.0, 0.0]}, "left.distortion", "folds over"),
        ({"T_left_right": np.eye(4).tolist()}, "T_left_right", "baseline"),
    ],
)
def test_physically_impossible_rigs_are_refused_naming_the_key(changes, key, why):
    with pytest.raises(RigFileError) as info:
        rig_from_dict(_edited(**changes), "rig.yaml")
    text = str(info.value)
    assert text.startswith("rig.yaml: ") and f"'{key}" in text and why in text, text


def test_a_fold_near_the_corners_is_a_warning_as_in_opencvs_own_sample_calibration(caplog):
    # k2 = -1.0355 is OpenCV's stereo_calib reference for its 640x480 sample (left camera): the
    # model folds at about 80 % of the way to the corners, where the board never was.
    data = _edited(
        image_width_px=640,
        image_height_px=480,
        left__fx_px=534.8,
        left__fy_px=534.8,
        left__cx_px=335.7,
        left__cy_px=240.7,
        left__distortion=[0.2959, -1.0355, 0.0, 0.0, 0.0],
        right__fx_px=534.8,
        right__fy_px=534.8,
        right__cx_px=334.6,
        right__cy_px=242.1,
    )
    rig = rig_from_dict(data, "opencv.yaml")
    assert rig.width == 640
    assert any("folds over" in r.message and "left.distortion" in r.message for r in caplog.records)


def test_a_yaml_alias_bomb_is_refused_quickly_with_a_short_message():
    bomb = 'a: &a ["x","x","x","x","x","x","x","x","x"]\n'
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        bomb += f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]\n"
    bomb += "format: sea3d-rig\nversion: 1\nimage_width_px: *i\n"
    tracemalloc.start()
    with pytest.raises(RigFileError, match="alias bomb") as info:
        rig_from_yaml(bomb, "bomb.yaml")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert len(str(info.value)) < MAX_MESSAGE_CHARS
    assert peak < 50 * 2**20  # was 1.9 GB and a 322 MB message


def test_recursive_aliases_and_deep_nesting_are_refused():
    with pytest.raises(RigFileError, match="recursive alias"):
        rig_from_yaml("a: &a [*a]\n", "loop.yaml")
    with pytest.raises(RigFileError, match=r"nested too deeply|not valid YAML"):
        rig_from_yaml("[" * 5000 + "]" * 5000, "deep.yaml")
    with pytest.raises(RigFileError, match="too large"):
        rig_from_yaml("# " + "x" * (2 << 20), "big.yaml")


def test_shared_port_blocks_through_yaml_anchors_still_load():
    text = GOOD_TEXT.replace("  port:\n    type: dome", "  port: &dome\n    type: dome", 1)
    head, _, tail = text.partition("right:\n")
    tail = (
        tail.split("  port:\n", 1)[0]
        + "  port: *dome\n"
        + "T_left_right"
        + tail.split("T_left_right", 1)[1]
    )
    rig = rig_from_yaml(head + "right:\n" + tail, "anchors.yaml")
    assert rig.right.port.inner_radius_m == 0.03125  # type: ignore[attr-defined]


def test_rig_files_in_utf16_load_or_fail_with_a_clear_line(tmp_path):
    with_bom = tmp_path / "rig_utf16.yaml"
    with_bom.write_bytes(GOOD_TEXT.encode("utf-16"))  # a byte-order mark first
    assert load_rig(with_bom).width == 1920
    without = tmp_path / "rig_utf16le.yaml"
    without.write_bytes(GOOD_TEXT.encode("utf-16-le"))
    with pytest.raises(RigFileError, match=r"rig_utf16le\.yaml: not UTF-8 text.*UTF-16"):
        load_rig(without)
    latin = tmp_path / "rig_latin1.yaml"
    latin.write_bytes(GOOD_TEXT.replace("# sea3d", "# s\xe9a3d").encode("latin-1"))
    with pytest.raises(RigFileError, match=r"byte 0xe9 at offset 3"):
        load_rig(latin)


def test_a_huge_image_size_does_not_allocate(tmp_path):
    path = tmp_path / "huge.yaml"
    path.write_text(yaml.safe_dump(_edited(image_width_px=2**40, image_height_px=2**40)))
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with pytest.raises(RigFileError, match="outside the range of cameras"):
        load_rig(path)
    assert resource.getrlimit(resource.RLIMIT_AS) == (soft, hard)


_NASTY = st.one_of(
    st.sampled_from([0, -1, 1e308, -1e308, float("nan"), float("inf"), 2**64, True, None, "", []]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
    st.text(max_size=8),
    st.lists(st.floats(), max_size=20),
)


def _leaves(data: object, prefix: str = "") -> list[str]:
    if isinstance(data, dict):
        return [p for k, v in data.items() for p in _leaves(v, f"{prefix}{k}__")]
    return [prefix.rstrip("_")] if prefix else []


_KEYS = _leaves(GOOD)


@settings(max_examples=_examples(80))
@given(key=st.sampled_from(_KEYS), value=_NASTY)
def test_any_value_anywhere_loads_a_physical_rig_or_fails_in_one_line(key, value):
    try:
        rig = rig_from_dict(_edited(**{key: value}), "mangled.yaml")
    except RigFileError as err:
        assert len(str(err)) < MAX_MESSAGE_CHARS and "\n" not in str(err)
        assert str(err).startswith("mangled.yaml")
        return
    check_rig_physics(rig, "mangled.yaml")  # whatever loads is physically possible


@settings(max_examples=_examples(80))
@given(data=st.data())
def test_mangled_yaml_text_loads_or_fails_in_one_line(data):
    raw = bytearray(GOOD_TEXT.encode())
    for _ in range(data.draw(st.integers(1, 6))):
        kind = data.draw(st.sampled_from(["flip", "cut", "insert", "delete"]))
        pos = data.draw(st.integers(0, max(len(raw) - 1, 0)))
        if kind == "flip" and raw:
            raw[pos] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "cut":
            del raw[pos:]
        elif kind == "insert":
            raw[pos:pos] = data.draw(
                st.sampled_from(
                    [
                        b"&a ",
                        b"*a",
                        b"[",
                        b"{",
                        b": ",
                        b"\x00",
                        b"!!python/object:os.system ",
                        b"\t",
                    ]
                )
            )
        elif raw:
            del raw[pos : pos + data.draw(st.integers(1, 20))]
    try:
        from sea3d.io.rig_file import decode_rig_bytes

        rig = rig_from_yaml(decode_rig_bytes(bytes(raw), "m.yaml"), "m.yaml")
    except RigFileError as err:
        assert len(str(err)) < MAX_MESSAGE_CHARS
        return
    check_rig_physics(rig, "m.yaml")
