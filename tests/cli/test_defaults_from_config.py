"""Options whose value lands in a config dataclass field or a library parameter take their
default from there (``cli._args.config_option`` / ``param_option``), so the CLI's default and
the library's are one value and cannot drift."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from collections.abc import Iterator
from typing import Any

import pytest

from sea3d.cli import build_parser
from sea3d.cli._args import config_option, param_option


def _parsers(parser: argparse.ArgumentParser, name: str = "sea3d"
             ) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def _library_default(source: Any, name: str) -> Any:
    if dataclasses.is_dataclass(source):
        f = {x.name: x for x in dataclasses.fields(source)}[name]
        if f.default is not dataclasses.MISSING:
            return f.default
        return f.default_factory() if f.default_factory is not dataclasses.MISSING else None
    p = inspect.signature(source).parameters[name]
    return None if p.default is inspect.Parameter.empty else p.default


def drifted(parser: argparse.ArgumentParser) -> list[str]:
    """Options built from a library default whose parsed default differs from it (also through
    a later ``set_defaults``)."""
    out = []
    for where, p in _parsers(parser):
        for action in p._actions:
            source = getattr(action, "sea3d_default_from", None)
            if source is None:
                continue
            want = _library_default(*source)
            got = p._defaults.get(action.dest, action.default)
            if got != want or type(got) is not type(want):
                out.append(f"{where} {action.option_strings[0]}: CLI default {got!r}, "
                           f"{source[0].__name__}.{source[1]} default {want!r}")
    return out


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    return build_parser()


def test_options_from_the_library_keep_its_defaults(parser: argparse.ArgumentParser) -> None:
    assert not drifted(parser), "\n".join(drifted(parser))
    tagged = [a for _, p in _parsers(parser) for a in p._actions
              if getattr(a, "sea3d_default_from", None) is not None]
    assert len(tagged) >= 50, f"expected the options built from configs, found {len(tagged)}"


def test_a_drifted_default_is_caught() -> None:
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Config:
        rate_hz: float = 10.0

    def run(*, speed: float = 1.0) -> None:
        del speed

    p = argparse.ArgumentParser()
    config_option(p, Config, "rate_hz", type=float, help="rate")
    param_option(p, run, "speed", type=float, help="speed")
    assert drifted(p) == []
    p.set_defaults(rate_hz=12.0)
    assert len(drifted(p)) == 1 and "rate_hz default 10.0" in drifted(p)[0]
    with pytest.raises(TypeError, match="do not pass default"):
        config_option(p, Config, "rate_hz", "--rate2", default=5.0)


def _default(parser: argparse.ArgumentParser, argv: list[str], dest: str) -> Any:
    return getattr(parser.parse_args(argv), dest)


def test_defaults_derived_in_other_units(parser: argparse.ArgumentParser, tmp_path) -> None:
    """Options in other units than their field (GB for bytes, mm for metres) derive the default
    from the library too."""
    from sea3d.capture.recorder import RecorderConfig
    from sea3d.eval.surface import DEFAULT_THRESHOLDS_M
    from sea3d.refraction.ports import FlatPort
    from sea3d.refraction.presets import PAPER_DOME_INNER_RADIUS_M

    rec = ["record", "--left", "a", "--right", "b", "-o", str(tmp_path / "x.mcap")]
    gb = _default(parser, rec, "min_free_gb")
    assert int(gb * 1e9) == RecorderConfig(out_path=tmp_path).min_free_bytes
    mm = _default(parser, ["eval", "surface", "m.ply", "r.ply"], "thresholds_mm")
    assert [t / 1e3 for t in mm] == pytest.approx(list(DEFAULT_THRESHOLDS_M), abs=1e-12)
    for argv in (["rig", "create", "--preset", "sea3d-paper", "-o", "r.yaml"],
                 ["calibrate", "port", "--rig", "r", "--port", "dome", "--left", "l",
                  "--right", "r", "--board", "b", "-o", "o"]):
        args = parser.parse_args(argv)
        assert args.inner_radius_mm * 1e-3 == pytest.approx(PAPER_DOME_INNER_RADIUS_M, abs=1e-12)
        assert args.flat_distance_mm * 1e-3 == pytest.approx(FlatPort.distance_m, abs=1e-12)


def test_sim_options_come_from_the_light_sim_configs(parser: argparse.ArgumentParser) -> None:
    """``sea3d sim``'s defaults are SurveyConfig's and CalibrationSetConfig's, read from
    sea3d.sim.config without loading the renderer (numba kernels, Open3D)."""
    import subprocess
    import sys

    from sea3d.sim.config import CalibrationSetConfig, SurveyConfig

    subs = dict(_parsers(parser))
    for where, cls, fields in (
        ("sea3d sim", SurveyConfig, {"frames", "fps", "water", "trajectory", "seed",
                                     "supersample"}),
        ("sea3d sim calibration", CalibrationSetConfig, {"board", "views", "medium",
                                                         "distance_range_m", "water", "seed"}),
    ):
        tagged = {a.sea3d_default_from[1] for a in subs[where]._actions
                  if getattr(a, "sea3d_default_from", (None,))[0] is cls}
        assert tagged == fields, where
    code = ("import sys; from sea3d.cli import build_parser; build_parser(); "
            "print(sorted(m for m in sys.modules if m.startswith(('sea3d.sim.', 'open3d'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "['sea3d.sim.config']", out
