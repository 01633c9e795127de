"""The one registry of enhancement names: ``sea3d enhance --method``, ``sea3d process
--enhance`` and :func:`sea3d.enhance.enhance_image` all read it.

It imports nothing heavy, so the CLI can build its ``choices`` from it without loading
OpenCV or SciPy; each entry names its function as ``package.module:function``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sea3d.errors import EnhanceError

__all__ = ["ENHANCEMENTS", "METHODS", "Enhancement", "enhancement", "process_enhance_hook",
           "resolve"]


@dataclass(frozen=True, kw_only=True)
class Enhancement:
    """One named enhancement.

    Attributes:
        name: the name users type.
        function: ``package.module:function`` taking one image (and keyword parameters).
        needs_range: the function needs the metric range of every pixel (Sea-thru); it cannot
            run before matching.
        pair_balance: a white balance whose statistics a stereo pair shares
            (:func:`sea3d.enhance.white_balance_pair`).
        summary: one line for help texts.
    """

    name: str
    function: str
    needs_range: bool = False
    pair_balance: bool = False
    summary: str = ""


ENHANCEMENTS: dict[str, Enhancement] = {
    e.name: e
    for e in (
        Enhancement(name="seathru", function="sea3d.enhance.seathru:seathru", needs_range=True,
                    summary="Sea-thru colour restoration with metric range"),
        Enhancement(name="grey-world", function="sea3d.enhance.colour:grey_world",
                    pair_balance=True, summary="grey-world white balance"),
        Enhancement(name="shades-of-grey", function="sea3d.enhance.colour:shades_of_grey",
                    pair_balance=True, summary="shades-of-grey (p = 6) white balance"),
        Enhancement(name="red-comp", function="sea3d.enhance.colour:red_compensation",
                    pair_balance=True, summary="red-channel compensation, then grey world"),
        Enhancement(name="clahe", function="sea3d.enhance.contrast:clahe",
                    summary="CLAHE on L*"),
        Enhancement(name="udcp", function="sea3d.enhance.udcp:udcp",
                    summary="underwater dark channel prior dehazing"),
    )
}
"""Every enhancement, by name."""

METHODS: tuple[str, ...] = tuple(ENHANCEMENTS)
"""The names of :data:`ENHANCEMENTS` (``sea3d enhance --method``)."""


def enhancement(name: str) -> Enhancement:
    """The registry entry of ``name``.

    Raises:
        EnhanceError: an unknown name (the message lists the known ones).
    """
    try:
        return ENHANCEMENTS[name]
    except KeyError:
        raise EnhanceError(
            f"unknown method {name!r}; choose one of {', '.join(METHODS)}"
        ) from None


def resolve(path: str) -> Callable[..., Any]:
    """The callable a ``package.module:function`` path names.

    Raises:
        EnhanceError: no such module or attribute, or it is not callable.
    """
    module, _, attr = path.partition(":")
    try:
        fn = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as err:
        raise EnhanceError(f"cannot find the enhancement {path!r}: {err}") from err
    if not callable(fn):
        raise EnhanceError(f"enhancement {path!r} is not callable")
    return fn


def process_enhance_hook(name: str) -> str | None:
    """``sea3d process --enhance NAME``: the per-image hook (``module:function``) applied to
    the raw images before matching, ``None`` for ``none`` (the measured default: none helped
    our SGM, ``docs/enhance.md``), or ``name`` itself when it is already a path. Each hook
    works on one image, so white balances are per image there, not shared by the pair.

    Raises:
        EnhanceError: an unknown name, or one that needs range (Sea-thru needs the depth that
            matching produces: use ``--restore-colours seathru``).
    """
    if name == "none":
        return None
    if ":" in name:
        return name
    if name not in ENHANCEMENTS:
        raise EnhanceError(
            f"unknown enhancement {name!r}: use one of "
            f"{', '.join(['none', *(n for n in METHODS if not ENHANCEMENTS[n].needs_range)])} "
            "or package.module:function"
        )
    entry = ENHANCEMENTS[name]
    if entry.needs_range:
        raise EnhanceError(
            f"{name} needs the depth that matching produces; use restore_colours {name}"
        )
    return entry.function
