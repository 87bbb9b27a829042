"""lesmc: model checking robustness and resilience of learning-enabled state estimators.

The Python API is :mod:`lesmc.api` (docs/api.md); its functions are also reachable
from here (``lesmc.check``, ``lesmc.load_model``, ...), imported when first used so
that ``import lesmc`` stays light.
"""

from __future__ import annotations

import sys
import types
from typing import Any

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


def __getattr__(name: str) -> Any:
    """The API's names, from :mod:`lesmc.api` on first use."""
    if name in _API:
        from lesmc import api

        return getattr(api, name)
    if name in _ERRORS:
        from lesmc.common import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'lesmc' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API, *_ERRORS])


#: API functions that share their name with a subpackage (lesmc/build/, lesmc/verify/).
_SHADOWED = ("build", "verify")


class _CallableModule(types.ModuleType):
    """A subpackage named like an API function: calling it calls the function, so that
    ``lesmc.build(...)`` works once ``lesmc.build`` (the package) has been imported, which
    rebinds the name; its modules stay reachable as attributes (``lesmc.build.unfold``)."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from lesmc import api

        return getattr(api, self.__name__.rpartition(".")[2])(*args, **kwargs)


class _Package(types.ModuleType):
    """``lesmc`` itself: the import system binds each subpackage here as it loads; the
    two named like API functions become callable (:class:`_CallableModule`)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _SHADOWED and type(value) is types.ModuleType:
            value.__class__ = _CallableModule
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
