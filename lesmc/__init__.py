"""lesmc: model checking robustness and resilience of learning-enabled state estimators.

The Python API is :mod:`lesmc.api` (docs/api.md); its functions are also reachable
from here (``lesmc.check``, ``lesmc.load_model``, ...), imported when first used so
that ``import lesmc`` stays light.
"""

from __future__ import annotations

import sys as _sys
import types as _types
from typing import Any as _Any

_ERRORS = ("LesmcError", "InputError", "SpecError", "ModelError", "UsageError", "BudgetError")

_API = (
    "CheckResult",
    "DesignRun",
    "PerceiveRequest",
    "Perceived",
    "Results",
    "VerifyOutcome",
    "VerifyRequest",
    "build",
    "check",
    "check_job",
    "expand_designs",
    "export",
    "export_model",
    "load_model",
    "load_model_or_scene",
    "load_scene",
    "load_spec",
    "parse_spec",
    "perceive",
    "save_scene",
    "verify",
)

__all__ = [*_API, *_ERRORS]


def __getattr__(name: str) -> _Any:
    """The API's names, from :mod:`lesmc.api` on first use."""
    if name in _API:
        from lesmc import api

        return getattr(api, name)
    if name in _ERRORS:
        from lesmc.common import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'lesmc' has no attribute {name!r}")


def __dir__() -> list[str]:
    """Exactly the public names (``__all__``): not the subpackages, nor this module's own
    imports."""
    return sorted(__all__)


#: API functions that share their name with a subpackage (lesmc/build/, lesmc/export/,
#: lesmc/verify/).
_SHADOWED = ("build", "export", "verify")


class _CallableModule(_types.ModuleType):
    """A subpackage named like an API function: calling it calls the function, so that
    ``lesmc.build(...)`` works once ``lesmc.build`` (the package) has been imported, which
    rebinds the name; its modules stay reachable as attributes (``lesmc.build.unfold``)."""

    def __call__(self, *args: _Any, **kwargs: _Any) -> _Any:
        from lesmc import api

        return getattr(api, self.__name__.rpartition(".")[2])(*args, **kwargs)


class _Package(_types.ModuleType):
    """``lesmc`` itself: the import system binds each subpackage here as it loads; the
    two named like API functions become callable (:class:`_CallableModule`)."""

    def __setattr__(self, name: str, value: _Any) -> None:
        if name in _SHADOWED and type(value) is _types.ModuleType:
            value.__class__ = _CallableModule
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
