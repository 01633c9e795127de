"""A test run that dies of a signal names the Python stack of the test it died in, also
after pycolmap has put glog's failure handler in place of Python's (``crash_handlers.py``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

TESTS = Path(__file__).resolve().parent
SRC = TESTS.parent / "src"


def test_a_bus_error_after_pycolmap_was_imported_prints_the_python_stack(tmp_path):
    (tmp_path / "test_dies.py").write_text(textwrap.dedent("""
        import os
        import signal


        def test_imports_pycolmap():
            import pycolmap  # noqa: F401


        def test_dies_of_a_bus_error():
            os.kill(os.getpid(), signal.SIGBUS)
        """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), str(SRC)])}
    env.pop("PYTHONFAULTHANDLER", None)
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "-p", "crash_handlers", "test_dies.py"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode in (-signal.SIGBUS, 128 + signal.SIGBUS), run
    assert "Fatal Python error: Bus error" in run.stderr, run.stderr[-2000:]
    assert 'test_dies.py", line 11 in test_dies_of_a_bus_error' in run.stderr
