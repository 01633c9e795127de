"""io is a room of its own: it imports no stage, and its session package
reaches no private name of another module."""

from __future__ import annotations

import ast
from pathlib import Path

IO = Path(__file__).resolve().parents[2] / "src" / "sea3d" / "io"
# The per-frame result cache still holds recon's Submap until the submap store moves up to
# pipeline (the throughput work owns it); nothing else in io may import a stage.
STILL_WAITING = {"result_cache.py"}
STAGES = ("sea3d.recon", "sea3d.pipeline", "sea3d.cli", "sea3d.odometry", "sea3d.stereo",
          "sea3d.capture", "sea3d.sim")  # fmt: skip


def _imports(path: Path) -> list[tuple[str, list[str]]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.append((node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            out.extend((a.name, []) for a in node.names)
    return out


def test_io_imports_no_stage():
    bad = [
        f"{p.relative_to(IO)}: {mod}"
        for p in sorted(IO.rglob("*.py"))
        if p.name not in STILL_WAITING
        for mod, _names in _imports(p)
        if mod.startswith(STAGES)
    ]
    assert not bad


def test_the_session_package_imports_no_private_name():
    bad = [
        f"{p.name}: {mod}.{name}"
        for p in sorted((IO / "session").glob("*.py"))
        for mod, names in _imports(p)
        if mod.startswith("sea3d.")
        for name in names
        if name.startswith("_") and name != "__version__"
    ]
    assert not bad


def test_one_atomic_write():
    """os.replace appears only in io/_atomic.py: every file is put in place one way."""
    src = IO.parent
    users = sorted(
        str(p.relative_to(src)) for p in src.rglob("*.py") if "os.replace(" in p.read_text()
    )
    assert users == ["io/_atomic.py"]
