"""``resolve_rig``: the rig file if given, else the session's stored rig, else a clear error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.io.rig_file import resolve_rig, rig_to_yaml, save_rig
from sea3d.io.session import SessionWriter, open_session
from sea3d.refraction.presets import paper_rig


def _session(path: Path, rig_yaml: str | None) -> Path:
    img = np.zeros((90, 160, 3), np.uint8)
    with SessionWriter(path, format="folder", rig_yaml=rig_yaml) as w:
        w.write_stereo(1_000_000, img, img)
    return path


def test_the_rig_file_wins_over_the_stored_rig(tmp_path: Path) -> None:
    stored = paper_rig("dome", size_px=(160, 90))
    given = paper_rig("none", size_px=(160, 90), baseline_m=0.2)
    rig_path = save_rig(given, tmp_path / "rig.yaml")
    with open_session(_session(tmp_path / "s", rig_to_yaml(stored))) as s:
        rig = resolve_rig(rig_path, s)
        assert rig.baseline_m == pytest.approx(0.2) and rig.left.port is None
        rig = resolve_rig(None, s)
        assert rig.baseline_m == pytest.approx(stored.baseline_m) and rig.left.is_refractive


def test_no_file_and_no_stored_rig_is_one_clear_error(tmp_path: Path) -> None:
    with open_session(_session(tmp_path / "s", None)) as s, \
            pytest.raises(SessionError, match=r"s stores no rig; give a rig file"):
        resolve_rig(None, s)
