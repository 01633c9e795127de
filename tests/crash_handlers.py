"""A pytest plugin (loaded by ``tests/conftest.py``): Python's crash report stays on for the
whole run.

pytest turns on :mod:`faulthandler`, which prints every thread's Python stack when the
process dies of SIGSEGV, SIGBUS, SIGFPE, SIGABRT or SIGILL. Importing pycolmap installs
glog's failure handler for those signals over it, so a crash in any test after the first
one that used pycolmap printed no Python stack (and glog's C stack went to the test's
captured stderr, lost with the process). After the first test that leaves pycolmap
imported, faulthandler's handlers are installed again (``enable`` alone keeps glog's: it
only changes the file of an enabled handler), writing to the stderr the run started with.
"""

from __future__ import annotations

import faulthandler
import os
import sys

import pytest

_state: dict[str, int | bool] = {"fd": -1, "rearmed": False}


def pytest_configure(config: pytest.Config) -> None:
    del config
    if _state["fd"] == -1:
        _state["fd"] = os.dup(2)  # outside any test's capture: the run's own stderr


def pytest_runtest_teardown(item: pytest.Item) -> None:
    del item
    if _state["rearmed"] or "pycolmap" not in sys.modules or not faulthandler.is_enabled():
        return
    faulthandler.disable()
    faulthandler.enable(file=int(_state["fd"]), all_threads=True)
    _state["rearmed"] = True


def pytest_unconfigure(config: pytest.Config) -> None:
    del config
    if _state["rearmed"]:
        faulthandler.disable()
        _state["rearmed"] = False
    if int(_state["fd"]) >= 0:
        os.close(int(_state["fd"]))
        _state["fd"] = -1
