"""Moved to :mod:`sea3d.io.session.common` (issue 18 item 6). This alias keeps imports from
other branches working until they follow; new code imports the new module."""

from typing import Any

from sea3d.io.session import common as _moved


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
