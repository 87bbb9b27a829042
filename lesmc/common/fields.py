"""The rules every JSON input shares, in one place: what counts as an integer, a number, a
format header, and how a bad value is shown in a message.

A JSON ``true`` is not the integer 1 here (Python's ``True == 1`` is), so a
``"version": true`` is refused by scenes, models, truth and results files alike,
with the same message (docs/cli.md, "Limits").
"""

from __future__ import annotations

import math
import re
import reprlib
from typing import Any, TypeGuard

from lesmc.common.errors import Problems, UsageError, clipped

#: The largest step (frame number) anything may name: a scene's frames, a property's
#: window bounds and ranges, ``--window``, a campaign's windows, a model's meta.
MAX_STEP = 10**6

_REPR = reprlib.Repr()
_REPR.maxstring = 40
_REPR.maxother = 40
_REPR.maxlist = 4
_REPR.maxdict = 4
_REPR.maxlevel = 2


#: The values the front end's settings may take (``lesmc perceive --history``,
#: ``--delta-bc``; a scene's ``meta.frontend``, checked as the scene is read by
#: lesmc/scene/meta_attack.py; a results document's ``perception``; the schemas say the
#: same, tests/test_frontend_settings.py checks that they agree). Here, at the bottom of
#: the layers, so that the scene's reader and perception share it without numpy.
FRONTEND_RANGES: dict[str, tuple[int, int]] = {"history": (3, 16), "delta_bc": (1, 255)}


def is_int(x: Any) -> TypeGuard[int]:
    """An integer, not a boolean."""
    return isinstance(x, int) and not isinstance(x, bool)


def is_name(x: Any) -> TypeGuard[str]:
    """A component name of a model file: a Python identifier (docs/lts-format.md)."""
    return isinstance(x, str) and x.isidentifier()


def is_number(x: Any) -> TypeGuard[int | float]:
    """An integer or a float, not a boolean (may be infinite)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def is_finite(x: Any) -> TypeGuard[int | float]:
    """A finite number (an integer beyond the float range is not)."""
    if not is_number(x):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def within(x: Any, limit: float) -> bool:
    """A finite number with ``|x| <= limit``."""
    return is_finite(x) and -limit <= x <= limit


def positive(x: Any, limit: float) -> bool:
    """A finite number in ``(0, limit]``."""
    return is_finite(x) and 0 < x <= limit


def show(x: Any) -> str:
    """A short repr of a value from a file (huge integers and deep lists abridged)."""
    if is_int(x) and x.bit_length() > 64:
        return f"{'-' if x < 0 else ''}<an integer of {x.bit_length()} bits>"
    if isinstance(x, bool) or x is None:
        return "true" if x is True else "false" if x is False else "null"
    try:
        return _REPR.repr(x)
    except (ValueError, RecursionError):
        return f"<{type(x).__name__}>"


def header(data: dict[str, Any], fmt: str, version: int, pr: Problems) -> None:
    """``format`` must be ``fmt`` and ``version`` the integer ``version``."""
    if data.get("format") != fmt:
        pr.add("format", f'must be "{fmt}", got {show(data.get("format"))}')
    if not is_version(data.get("version"), version):
        pr.add("version", f"must be {version}, got {show(data.get('version'))}")


def is_version(got: Any, version: int) -> bool:
    """``got`` is the integer ``version`` (JSON's ``true`` is not 1)."""
    return is_int(got) and got == version


def parse_window(text: str, what: str = "window") -> tuple[int, int]:
    """``L..U`` -> (L, U): ASCII digits only, each at most :data:`MAX_STEP` (``--window``,
    the API's ``window="6..8"``); ``what`` names the option or argument in messages."""
    m = re.fullmatch(r"\s*([0-9]+)\s*\.\.\s*([0-9]+)\s*", text, re.ASCII)
    shown = clipped(text)
    if not m:
        raise UsageError(f"{what} must look like L..U (e.g. 6..8), got '{shown}'")
    if any(len(g.lstrip("0")) > len(str(MAX_STEP)) for g in m.groups()):
        raise UsageError(f"{what} {shown}: steps must be at most {MAX_STEP}")
    lo, hi = int(m.group(1)), int(m.group(2))
    if hi > MAX_STEP:
        raise UsageError(f"{what} {shown}: steps must be at most {MAX_STEP}")
    if lo > hi:
        raise UsageError(f"{what} {shown}: L must not exceed U")
    return lo, hi
