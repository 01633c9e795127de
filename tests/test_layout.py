"""The house's layout rules, checked statically on every file under ``src/sea3d``.

Pure ``ast``: nothing is imported, so the test is fast and sees imports inside functions too.

Rules (each failure names the file, the line and the rule):

- ``long-function``: no function or method is over ``MAX_FUNCTION_LINES`` lines
  (``end_lineno - lineno + 1``, decorators not counted), except the listed exemptions.
- ``imports-cli``: nothing outside ``sea3d.cli`` (and ``sea3d/__main__.py``) imports ``sea3d.cli``.
- ``imports-sim``: nothing outside ``sea3d.sim`` and the demo imports the simulator.
- ``private-import``: no module imports a private name, or a private module, of another
  top-level subpackage (``sea3d._typing`` and ``sea3d._text`` are house-wide and allowed).
- ``io-imports-stage``: ``sea3d.io`` imports no stage; it may use geometry, refraction,
  errors, ``_typing``, ``_text``.
- ``bottom-imports-up``: ``sea3d.geometry`` and ``sea3d.refraction`` import nothing of sea3d
  but each other (refraction may use geometry; geometry may not use refraction), errors,
  ``_typing`` and ``_text``.
- ``capture-runs-stage``: ``sea3d.capture`` hands frames on and imports only io, geometry,
  refraction, errors, ``_typing`` and ``_text`` (a stage it needs is given by its caller).
- ``eval-runs-stage``: ``sea3d.eval`` computes metrics from given arrays and imports no stage
  at run time (a stage's types only under ``if TYPE_CHECKING:``).
- ``names-cli-flag``: no string literal outside ``sea3d.cli`` (docstrings and attribute
  docstrings aside: they may say which option sets a field) holds a command-line flag
  (``--word``, or ``--`` before an f-string field); the library names the config field or
  parameter and the CLI spells it as its option (``sea3d.cli.error_line``).
- ``knows-file-format``: outside ``sea3d.io`` no call reads or writes a file by its format
  (builtin ``open``, OpenCV's image, FileStorage and video files, NumPy's and pickle's files,
  ``json.dump``/``load`` other than to ``sys.stdout``/``sys.stderr``, Open3D's io, tifffile,
  imageio, PIL, PyAV, a path's ``read_text``/``write_text``/``read_bytes``/``write_bytes``,
  an array's ``tofile``); io is the only place that knows file formats (docs/design.md).

Every rule is also run on a planted violation so that the test is seen to fail.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE_DIR = SRC / "sea3d"

MAX_FUNCTION_LINES = 150

# Functions allowed to stay long, keyed by (path relative to src/, qualified name), with why.
_LONG_FUNCTION_EXEMPT: dict[tuple[str, str], str] = {}

# Modules that may import the simulator although they are not in sea3d.sim, with why.
_SIM_IMPORT_ALLOWED: dict[str, str] = {
    "sea3d/pipeline/demo.py": "the demo simulates a dive by design",
    "sea3d/cli/sim.py": "the `sea3d sim` command is the simulator's own front end",
}

# Private names or modules of another subpackage that a module may import, keyed by
# (path relative to src/, imported dotted name), with why.
_PRIVATE_IMPORT_ALLOWED: dict[tuple[str, str], str] = {
    (
        "sea3d/refraction/_kernels.py",
        "sea3d.geometry._kernels.undistort_point",
    ): "the bottom pair's shared numba kernel: refraction's per-point @njit tracing calls "
    "geometry's lens undistortion inline; an njit function can only be called from njit "
    "code, so it cannot go through PinholeCamera's public (NumPy) API",
}

# House-wide private modules: private to sea3d, shared by every subpackage.
_HOUSE_WIDE_PRIVATE = ("sea3d._typing", "sea3d._text")

_IO_FORBIDDEN = (
    "sea3d.recon",
    "sea3d.odometry",
    "sea3d.pipeline",
    "sea3d.stereo",
    "sea3d.enhance",
    "sea3d.calib",
    "sea3d.sfm",
    "sea3d.monodepth",
    "sea3d.capture",
    "sea3d.eval",
    "sea3d.sim",
    "sea3d.cli",
    "sea3d.rectify",
)
_BOTTOM_ALLOWED = {
    "geometry": ("sea3d.geometry", "sea3d.errors", "sea3d._typing", "sea3d._text"),
    "refraction": (
        "sea3d.refraction",
        "sea3d.geometry",
        "sea3d.errors",
        "sea3d._typing",
        "sea3d._text",
    ),
}

# geometry's camera protocol names the port types in annotations; at run time it never
# imports refraction (that would make the bottom pair a cycle).
_BOTTOM_TYPE_ONLY = {"geometry": ("sea3d.refraction",)}


@dataclass(frozen=True)
class Module:
    """One parsed source file."""

    rel_path: str  # e.g. "sea3d/pipeline/demo.py"
    name: str  # e.g. "sea3d.pipeline.demo"
    is_package: bool  # an __init__.py
    tree: ast.Module

    @property
    def subpackage(self) -> str:
        """The top-level part below sea3d: "pipeline", "errors", "__main__" ..."""
        parts = self.name.split(".")
        return parts[1] if len(parts) > 1 else ""


@dataclass(frozen=True)
class Import:
    """One imported dotted name: the module, or ``module.name`` for ``from module import name``."""

    line: int
    target: str
    type_only: bool = False  # inside ``if TYPE_CHECKING:``: for annotations, not run


def parse_module(source: str, rel_path: str) -> Module:
    """Parse ``source`` as the file ``rel_path`` (relative to src/)."""
    parts = rel_path.removesuffix(".py").split("/")
    is_package = parts[-1] == "__init__"
    if is_package:
        parts = parts[:-1]
    return Module(rel_path, ".".join(parts), is_package, ast.parse(source, filename=rel_path))


def _resolve(module: Module, level: int, name: str | None) -> str:
    if level == 0:
        return name or ""
    base = module.name.split(".")
    if not module.is_package:
        base = base[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join([*base, name] if name else base)


def _type_checking_lines(tree: ast.Module) -> set[int]:
    """Line numbers inside ``if TYPE_CHECKING:`` bodies (not their ``else``)."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and (
            (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
            or (isinstance(node.test, ast.Attribute) and node.test.attr == "TYPE_CHECKING")
        ):
            for stmt in node.body:
                assert stmt.end_lineno is not None
                lines.update(range(stmt.lineno, stmt.end_lineno + 1))
    return lines


def imports_of(module: Module) -> list[Import]:
    """Every import in the file, at any depth, plus ``importlib.import_module("...")`` calls."""
    found: list[Import] = []
    typing_only = _type_checking_lines(module.tree)
    for node in ast.walk(module.tree):
        if isinstance(node, ast.Import):
            found.extend(
                Import(node.lineno, alias.name, node.lineno in typing_only) for alias in node.names
            )
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, node.level, node.module)
            for alias in node.names:
                target = base if alias.name == "*" else f"{base}.{alias.name}"
                found.append(Import(node.lineno, target, node.lineno in typing_only))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute | ast.Name)
            and (node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id)
            == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            found.append(Import(node.lineno, node.args[0].value))
    return [imp for imp in found if imp.target == "sea3d" or imp.target.startswith("sea3d.")]


def _within(target: str, prefix: str) -> bool:
    return target == prefix or target.startswith(prefix + ".")


def functions_of(module: Module) -> list[tuple[str, int, int]]:
    """(qualified name, first line, length in lines) of every function and method."""
    out: list[tuple[str, int, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                qual = f"{prefix}{child.name}"
                assert child.end_lineno is not None
                out.append((qual, child.lineno, child.end_lineno - child.lineno + 1))
                visit(child, f"{qual}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(module.tree, "")
    return out


def check_function_length(
    module: Module, exempt: dict[tuple[str, str], str] | None = None
) -> list[str]:
    """Violations of ``long-function`` in one module."""
    exempt = exempt if exempt is not None else _LONG_FUNCTION_EXEMPT
    return [
        f"src/{module.rel_path}:{line}: [long-function] {qual} is {length} lines "
        f"(limit {MAX_FUNCTION_LINES}); split it into named steps"
        for qual, line, length in functions_of(module)
        if length > MAX_FUNCTION_LINES and (module.rel_path, qual) not in exempt
    ]


def check_imports(module: Module, sim_allowed: dict[str, str] | None = None) -> list[str]:
    """Violations of every import rule in one module.

    A rule matches on the full imported name, so ``from sea3d import sim`` (target
    ``sea3d.sim``) counts the same as ``import sea3d.sim.survey``.
    """
    sim_allowed = sim_allowed if sim_allowed is not None else _SIM_IMPORT_ALLOWED
    problems: list[str] = []
    sub = module.subpackage
    for imp in imports_of(module):
        at = f"src/{module.rel_path}:{imp.line}:"
        if _within(imp.target, "sea3d.cli") and sub not in ("cli", "__main__"):
            problems.append(f"{at} [imports-cli] imports {imp.target}; nothing imports the CLI")
        if _within(imp.target, "sea3d.sim") and sub != "sim" and module.rel_path not in sim_allowed:
            problems.append(
                f"{at} [imports-sim] imports {imp.target}; only the simulator and the demo "
                "may load the simulator"
            )
        problems.extend(_private_import(module, imp, f"{at} [private-import]"))
        stage = next((p for p in _IO_FORBIDDEN if _within(imp.target, p)), None)
        if sub == "io" and stage is not None:
            problems.append(
                f"{at} [io-imports-stage] imports {imp.target}; io is the bottom room for "
                f"file formats and may not import the stage {stage}"
            )
        if sub in _BOTTOM_ALLOWED and imp.target != "sea3d":
            allowed = _BOTTOM_ALLOWED[sub]
            if imp.type_only:
                allowed = (*allowed, *_BOTTOM_TYPE_ONLY.get(sub, ()))
            if not any(_within(imp.target, p) for p in allowed):
                problems.append(
                    f"{at} [bottom-imports-up] imports {imp.target}; sea3d.{sub} may import "
                    f"only {', '.join(allowed)}"
                )
    return problems


def _private_import(module: Module, imp: Import, where: str) -> list[str]:
    parts = imp.target.split(".")
    if len(parts) < 2 or parts[1] == module.subpackage:
        return []
    if any(_within(imp.target, house) for house in _HOUSE_WIDE_PRIVATE):
        return []
    private = [p for p in parts[1:] if p.startswith("_") and not p.startswith("__")]
    if not private or (module.rel_path, imp.target) in _PRIVATE_IMPORT_ALLOWED:
        return []
    return [
        f"{where} imports {imp.target}: {private[0]!r} is private to sea3d.{parts[1]}; "
        "make it public there or move it"
    ]


def _all_modules() -> list[Module]:
    return [
        parse_module(path.read_text(encoding="utf-8"), path.relative_to(SRC).as_posix())
        for path in sorted(PACKAGE_DIR.rglob("*.py"))
    ]


@pytest.fixture(scope="module")
def modules() -> list[Module]:
    found = _all_modules()
    assert len(found) > 100, f"expected the sea3d sources under {PACKAGE_DIR}"
    return found


def test_no_function_is_over_the_line_limit(modules: list[Module]) -> None:
    problems = [p for m in modules for p in check_function_length(m)]
    assert not problems, "\n".join(problems)


def test_length_exemptions_are_still_needed(modules: list[Module]) -> None:
    lengths = {(m.rel_path, q): n for m in modules for q, _, n in functions_of(m)}
    stale = [
        f"{path}: {qual} is {lengths.get((path, qual), 'no longer')} lines; "
        "drop it from the exemption list"
        for path, qual in _LONG_FUNCTION_EXEMPT
        if lengths.get((path, qual), 0) <= MAX_FUNCTION_LINES
    ]
    assert not stale, "\n".join(stale)


def test_imports_follow_the_layout(modules: list[Module]) -> None:
    problems = [p for m in modules for p in check_imports(m)]
    assert not problems, "\n".join(problems)


def test_import_allowances_name_files_that_exist() -> None:
    paths = [*_SIM_IMPORT_ALLOWED, *(path for path, _ in _PRIVATE_IMPORT_ALLOWED)]
    missing = [p for p in paths if not (SRC / p).is_file()]
    assert not missing, f"allowances for files that no longer exist: {missing}"


def _body(lines: int, indent: str = "    ") -> str:
    return "\n".join(f"{indent}x{i} = {i}" for i in range(lines))


_LONG_BODY = _body(MAX_FUNCTION_LINES)  # with its def line: one line over the limit


@pytest.mark.parametrize(
    ("rel_path", "source", "rule"),
    [
        ("sea3d/stereo/x.py", f"def f():\n{_LONG_BODY}\n", "long-function"),
        (
            "sea3d/stereo/x.py",
            f"class A:\n  def m(self):\n{_body(MAX_FUNCTION_LINES, '    ')}\n",
            "long-function",
        ),
        ("sea3d/recon/x.py", "from sea3d.cli.recon import run\n", "imports-cli"),
        ("sea3d/recon/x.py", "def f():\n    from ..cli import _args\n", "imports-cli"),
        ("sea3d/pipeline/x.py", "def f():\n    import sea3d.sim.survey\n", "imports-sim"),
        ("sea3d/pipeline/x.py", "from sea3d import sim\n", "imports-sim"),
        ("sea3d/pipeline/x.py", "from ..sim.survey import scale_rig\n", "imports-sim"),
        (
            "sea3d/pipeline/x.py",
            "import importlib\nm = importlib.import_module('sea3d.sim')\n",
            "imports-sim",
        ),
        ("sea3d/pipeline/x.py", "from sea3d.stereo.planning import _pinhole\n", "private-import"),
        ("sea3d/pipeline/x.py", "from ..stereo import _sgm_kernels\n", "private-import"),
        ("sea3d/pipeline/x.py", "import sea3d.stereo._sgm_kernels\n", "private-import"),
        ("sea3d/io/x.py", "from sea3d.recon.mesh import Mesh\n", "io-imports-stage"),
        ("sea3d/io/sub/x.py", "from ...odometry import Track\n", "io-imports-stage"),
        ("sea3d/io/x.py", "from sea3d import pipeline\n", "io-imports-stage"),
        ("sea3d/geometry/x.py", "from sea3d.refraction import DomePort\n", "bottom-imports-up"),
        ("sea3d/refraction/x.py", "from ..io import rig_file\n", "bottom-imports-up"),
        ("sea3d/geometry/x.py", "from sea3d import stereo\n", "bottom-imports-up"),
        (
            "sea3d/geometry/x.py",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sea3d.stereo import D\n",
            "bottom-imports-up",
        ),
        (
            "sea3d/io/x.py",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sea3d.recon import M\n",
            "io-imports-stage",
        ),
    ],
)
def test_each_rule_trips_on_a_planted_violation(rel_path: str, source: str, rule: str) -> None:
    module = parse_module(source, rel_path)
    problems = check_function_length(module, exempt={}) + check_imports(module, sim_allowed={})
    assert any(f"[{rule}]" in p and f"src/{rel_path}:" in p for p in problems), problems


@pytest.mark.parametrize(
    ("rel_path", "source"),
    [
        ("sea3d/stereo/x.py", f"def f():\n{_body(MAX_FUNCTION_LINES - 1)}\n"),
        ("sea3d/cli/x.py", "from sea3d.cli._args import add\n"),
        ("sea3d/__main__.py", "from sea3d.cli import main\n"),
        ("sea3d/sim/x.py", "from ._kernels import shade_fused\n"),
        ("sea3d/pipeline/x.py", "from sea3d._typing import F64\nfrom sea3d._text import plural\n"),
        ("sea3d/stereo/x.py", "from ._sgm_kernels import aggregate\n"),
        ("sea3d/io/x.py", "from sea3d.geometry import Mesh\nfrom sea3d.errors import IOError_\n"),
        ("sea3d/refraction/x.py", "from sea3d.geometry.se3 import invert_T\n"),
        ("sea3d/geometry/x.py", "from . import _kernels\nfrom sea3d import errors\n"),
        ("sea3d/pipeline/x.py", "from sea3d.stereo.depth import __version__\n"),
        (
            "sea3d/geometry/x.py",
            "import typing\nif typing.TYPE_CHECKING:\n    from sea3d.refraction import DomePort\n",
        ),
    ],
)
def test_allowed_shapes_pass(rel_path: str, source: str) -> None:
    module = parse_module(source, rel_path)
    problems = check_function_length(module, exempt={}) + check_imports(module, sim_allowed={})
    assert not problems, problems


# -- capture hands frames on; eval computes metrics ---------------------------------

# ``capture`` reads cameras and sensors and hands frames on: it runs no stage.
_CAPTURE_ALLOWED = (
    "sea3d.capture",
    "sea3d.io",
    "sea3d.geometry",
    "sea3d.refraction",
    "sea3d.errors",
    "sea3d._typing",
    "sea3d._text",
)
# ``eval`` computes metrics from arrays it is given: it may name a stage's types for
# annotations (under ``if TYPE_CHECKING:``) but never runs one.
_EVAL_FORBIDDEN = (
    "sea3d.stereo",
    "sea3d.rectify",
    "sea3d.enhance",
    "sea3d.odometry",
    "sea3d.recon",
    "sea3d.pipeline",
    "sea3d.calib",
    "sea3d.sfm",
    "sea3d.monodepth",
    "sea3d.sim",
    "sea3d.capture",
    "sea3d.cli",
)


def check_capture_and_eval_imports(module: Module) -> list[str]:
    """Violations of ``capture-runs-stage`` and ``eval-runs-stage`` in one module."""
    problems: list[str] = []
    sub = module.subpackage
    for imp in imports_of(module):
        at = f"src/{module.rel_path}:{imp.line}:"
        if sub == "capture" and imp.target != "sea3d":
            if not any(_within(imp.target, p) for p in _CAPTURE_ALLOWED):
                problems.append(
                    f"{at} [capture-runs-stage] imports {imp.target}; capture hands frames on "
                    f"and may import only {', '.join(_CAPTURE_ALLOWED)} (a stage it needs is "
                    "given by its caller)"
                )
        stage = next((p for p in _EVAL_FORBIDDEN if _within(imp.target, p)), None)
        if sub == "eval" and stage is not None and not imp.type_only:
            problems.append(
                f"{at} [eval-runs-stage] imports {imp.target}; eval computes metrics from the "
                f"arrays it is given and may name {stage} only under `if TYPE_CHECKING:`"
            )
    return problems


def test_capture_and_eval_run_no_stage(modules: list[Module]) -> None:
    problems = [p for m in modules for p in check_capture_and_eval_imports(m)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(
    ("rel_path", "source", "rule"),
    [
        (
            "sea3d/capture/x.py",
            "from sea3d.stereo.recipe import StereoDepth\n",
            "capture-runs-stage",
        ),
        ("sea3d/capture/x.py", "def f():\n    from ..rectify import maps\n", "capture-runs-stage"),
        ("sea3d/capture/sub/x.py", "from ...pipeline import live\n", "capture-runs-stage"),
        ("sea3d/capture/x.py", "from sea3d import enhance\n", "capture-runs-stage"),
        ("sea3d/capture/x.py", "import sea3d.recon.mesh\n", "capture-runs-stage"),
        ("sea3d/capture/x.py", "from sea3d.odometry import track\n", "capture-runs-stage"),
        ("sea3d/eval/x.py", "def f():\n    from sea3d.stereo import match\n", "eval-runs-stage"),
        ("sea3d/eval/x.py", "from ..enhance.api import enhance_pair\n", "eval-runs-stage"),
        ("sea3d/eval/x.py", "from sea3d import pipeline\n", "eval-runs-stage"),
        (
            "sea3d/eval/x.py",
            "import importlib\nm = importlib.import_module('sea3d.odometry')\n",
            "eval-runs-stage",
        ),
        (
            "sea3d/eval/x.py",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    pass\nelse:\n"
            "    from sea3d.rectify.maps import RectifyMaps\n",
            "eval-runs-stage",
        ),
    ],
)
def test_capture_and_eval_rules_trip_on_a_planted_violation(
    rel_path: str, source: str, rule: str
) -> None:
    problems = check_capture_and_eval_imports(parse_module(source, rel_path))
    assert any(f"[{rule}]" in p and f"src/{rel_path}:" in p for p in problems), problems


@pytest.mark.parametrize(
    ("rel_path", "source"),
    [
        ("sea3d/capture/x.py", "from sea3d.io import foxglove_msgs\nfrom .sources import S\n"),
        (
            "sea3d/capture/x.py",
            "from sea3d.geometry.rig import StereoRig\nfrom sea3d import errors\n",
        ),
        (
            "sea3d/capture/x.py",
            "from sea3d.refraction import DomePort\nfrom sea3d._text import p\n",
        ),
        (
            "sea3d/eval/x.py",
            "from sea3d.geometry.camera import CameraModel\nfrom .disparity import d\n",
        ),
        ("sea3d/eval/x.py", "from sea3d.io.ground_truth import load\nfrom sea3d.errors import E\n"),
        (
            "sea3d/eval/x.py",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
            "    from sea3d.stereo.depth import DepthResult\n",
        ),
        ("sea3d/pipeline/x.py", "from sea3d.stereo import match\nfrom sea3d.capture import R\n"),
    ],
)
def test_capture_and_eval_allowed_shapes_pass(rel_path: str, source: str) -> None:
    assert not check_capture_and_eval_imports(parse_module(source, rel_path))


# ---------------------------------------------------------------------- names-cli-flag
import re  # noqa: E402

_FLAG_RE = re.compile(r"(?<![\w-])--[a-z][a-z0-9]*(?:-[a-z0-9]+)*")
_FLAG_BEFORE_FIELD_RE = re.compile(r"(?:^|[^\w-])--$")

# (path relative to src/, flag) of literals that may hold a flag, with why (an external tool's
# own command line, say).
_FLAG_LITERAL_ALLOWED: dict[tuple[str, str], str] = {
    ("sea3d/capture/monitor.py", "--{...}"): "the boundary line of a multipart MJPEG stream "
    "(RFC 2046 writes it '--' + boundary), not a command-line flag",
}


def _doc_strings(tree: ast.Module) -> set[int]:
    """ids of the string constants that are documentation: bare string statements (module,
    class and function docstrings, and the attribute docstrings after an assignment)."""
    return {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    }


def _flag_before_field(parts: list[ast.expr], k: int) -> bool:
    """Part ``k`` of an f-string ends in ``--`` that starts a word (``f"--{name}"``), and a
    field follows."""
    a, b = parts[k], parts[k + 1]
    if not (isinstance(a, ast.Constant) and isinstance(a.value, str)
            and isinstance(b, ast.FormattedValue)):
        return False
    text = a.value if k == 0 else "x" + a.value  # after a field, "--" does not start a word
    return bool(_FLAG_BEFORE_FIELD_RE.search(text))


def check_flag_literals(module: Module) -> list[str]:
    """``names-cli-flag`` problems of one module (none for ``sea3d.cli``)."""
    if module.subpackage == "cli":
        return []
    docs = _doc_strings(module.tree)
    where = f"src/{module.rel_path}"
    problems = []
    for node in ast.walk(module.tree):
        found: list[str] = []
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            found = _FLAG_RE.findall(node.value)
        elif isinstance(node, ast.JoinedStr):
            parts = node.values
            found = ["--{...}" for k in range(len(parts) - 1) if _flag_before_field(parts, k)]
        for flag in found:
            if (module.rel_path, flag) not in _FLAG_LITERAL_ALLOWED:
                problems.append(
                    f"{where}:{node.lineno}: [names-cli-flag] a string names the CLI flag {flag}; "
                    "name the config field or parameter and let sea3d.cli spell it as the flag"
                )
    return problems


def test_library_strings_name_no_cli_flag(modules: list[Module]) -> None:
    problems = [p for m in modules for p in check_flag_literals(m)]
    assert not problems, "\n".join(problems)


def test_flag_literal_allowances_are_still_needed(modules: list[Module]) -> None:
    saved = dict(_FLAG_LITERAL_ALLOWED)
    try:
        _FLAG_LITERAL_ALLOWED.clear()
        flagged = {(m.rel_path, p.split("CLI flag ")[1].split(";")[0])
                   for m in modules for p in check_flag_literals(m)}
    finally:
        _FLAG_LITERAL_ALLOWED.update(saved)
    assert set(saved) <= flagged, set(saved) - flagged


@pytest.mark.parametrize(
    "source",
    [
        'raise ValueError("--max-frames must be >= 1")\n',
        'def f(n):\n    raise ValueError(f"bad {n}; set --min-depth/--max-depth")\n',
        'import logging\nlogging.warning("%s: pass --rig", "x")\n',
        'def f(what):\n    return f"--{what} matches no files"\n',
        'NOTE = "record without --sync"\n',
    ],
)
def test_flag_rule_trips_on_a_planted_violation(source: str) -> None:
    problems = check_flag_literals(parse_module(source, "sea3d/pipeline/x.py"))
    assert any("[names-cli-flag]" in p and "src/sea3d/pipeline/x.py:" in p for p in problems)


@pytest.mark.parametrize(
    ("rel_path", "source"),
    [
        ("sea3d/cli/x.py", 'raise SystemExit("--max-frames must be >= 1")\n'),
        ("sea3d/pipeline/x.py", '"""Run by ``sea3d odometry --no-imu``."""\n'),
        ("sea3d/pipeline/x.py", 'class C:\n    n: int = 1\n    """Set by ``--n``."""\n'),
        ("sea3d/pipeline/x.py", 'raise ValueError("max_frames must be >= 1; a--b, -- x")\n'),
        ("sea3d/pipeline/x.py", 'def f(a, b):\n    return f"{a}--{b} and {a} -- {b}"\n'),
    ],
)
def test_flag_rule_allows_docs_fields_and_dashes(rel_path: str, source: str) -> None:
    assert not check_flag_literals(parse_module(source, rel_path))


# -- io is the only place that knows file formats -----------------------------------

# Calls that open, read or write a file by its format, outside ``sea3d.io``. Aliases are
# spelled as the house imports them (``np``, ``o3d``); ``json.dump`` to ``sys.stdout`` or
# ``sys.stderr`` prints, it writes no file.
_FILE_CALLS = {
    "open", "cv2.imread", "cv2.imwrite", "cv2.imreadmulti", "cv2.FileStorage",
    "np.save", "np.savez", "np.savez_compressed", "np.savetxt", "np.load", "np.loadtxt",
    "np.fromfile", "json.dump", "json.load", "pickle.dump", "pickle.load",
    "cv2.VideoCapture", "cv2.VideoWriter", "av.open",
}
_FILE_CALL_PREFIXES = ("o3d.io.", "tifffile.", "imageio.", "PIL.")
_FILE_METHODS = {"write_text", "write_bytes", "read_text", "read_bytes", "tofile"}
_ALIASES = {"numpy": "np", "open3d": "o3d"}

# (path relative to src/, call) that may stay outside io, with why: a config file whose
# parser builds a stage's own type (io may import no stage), or capture's live sources.
_FILE_CALL_ALLOWED: dict[tuple[str, str], str] = {
    ("sea3d/sim/scene.py", ".read_text"): "a scene YAML file, parsed by the simulator's "
    "scene_from_dict (io may not import sim to build the scene)",
    ("sea3d/calib/targets.py", ".read_text"): "a board YAML file, parsed into the calibration's "
    "BoardSpec (io may not import calib to build it)",
    ("sea3d/calib/targets.py", "cv2.FileStorage"): "an OpenCV FileStorage board file (as "
    "above)",
    ("sea3d/capture/sources.py", "cv2.VideoCapture"): "a camera device or a video file opened "
    "as a live source: capture owns its sources",
    ("sea3d/capture/stream.py", "av.open"): "the tether stream's MPEG-TS (over a pipe or "
    "socket) and its remux copy, written as frames arrive: capture owns its transport "
    "(io/h264.py holds the per-frame metadata it carries)",
}


def _dotted(node: ast.expr) -> str | None:
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    parts.append(_ALIASES.get(node.id, node.id))
    return ".".join(reversed(parts))


def _prints(call: ast.Call) -> bool:
    """``json.dump(obj, sys.stdout)`` (or ``sys.stderr``): printing, not writing a file."""
    stream = call.args[1] if len(call.args) > 1 else None
    return stream is not None and _dotted(stream) in ("sys.stdout", "sys.stderr")


def file_calls_of(module: Module) -> list[tuple[int, str]]:
    """(line, call) of every call in the module that reads or writes a file by its format."""
    found = []
    for node in ast.walk(module.tree):
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func)
        if name is not None and (name in _FILE_CALLS or name.startswith(_FILE_CALL_PREFIXES)):
            if not (name == "json.dump" and _prints(node)):
                found.append((node.lineno, name))
        elif isinstance(node.func, ast.Attribute) and node.func.attr in _FILE_METHODS:
            found.append((node.lineno, "." + node.func.attr))
    return found


def check_file_formats(module: Module, allowed: dict[tuple[str, str], str] | None = None
                       ) -> list[str]:
    """``knows-file-format`` problems of one module (none for ``sea3d.io``)."""
    if module.subpackage == "io":
        return []
    allowed = allowed if allowed is not None else _FILE_CALL_ALLOWED
    return [
        f"src/{module.rel_path}:{line}: [knows-file-format] {name}(...) reads or writes a "
        "file; io is the only place that knows file formats: call an io function"
        for line, name in file_calls_of(module) if (module.rel_path, name) not in allowed
    ]


def test_only_io_reads_and_writes_files(modules: list[Module]) -> None:
    problems = [p for m in modules for p in check_file_formats(m)]
    assert not problems, "\n".join(problems)


def test_file_call_allowances_are_still_needed(modules: list[Module]) -> None:
    found = {(m.rel_path, name) for m in modules for _, name in file_calls_of(m)}
    assert set(_FILE_CALL_ALLOWED) <= found, set(_FILE_CALL_ALLOWED) - found


@pytest.mark.parametrize(
    "source",
    [
        "import cv2\ncv2.imwrite('a.png', img)\n",
        "import cv2\nimg = cv2.imread('a.png')\n",
        "from pathlib import Path\nPath('r.html').write_text(page)\n",
        "def f(out):\n    out.write_bytes(pdf)\n",
        "with open('a.txt', 'w') as fh:\n    fh.write('x')\n",
        "import numpy\nnumpy.save('d.npy', d)\n",
        "import json\njson.dump(summary, fh)\n",
        "import open3d as o3d\nm = o3d.io.read_triangle_mesh('m.ply')\n",
    ],
)
def test_file_format_rule_trips_on_a_planted_violation(source: str) -> None:
    problems = check_file_formats(parse_module(source, "sea3d/cli/x.py"), allowed={})
    assert any("[knows-file-format]" in p and "src/sea3d/cli/x.py:" in p for p in problems)


@pytest.mark.parametrize(
    ("rel_path", "source"),
    [
        ("sea3d/cli/x.py", "import json, sys\njson.dump(summary, sys.stdout, indent=2)\n"),
        ("sea3d/cli/x.py", "import json\nprint(json.dumps(summary))\n"),
        ("sea3d/pipeline/x.py", "import os\nfd = os.open(path, os.O_RDWR)\n"),
        ("sea3d/io/x.py", "import cv2\ncv2.imwrite('a.png', img)\n"),
    ],
)
def test_file_format_rule_allows_printing_and_io(rel_path: str, source: str) -> None:
    assert not check_file_formats(parse_module(source, rel_path), allowed={})
