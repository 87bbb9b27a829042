"""lesmc: model checking robustness and resilience of learning-enabled state estimators.

The Python API is :mod:`lesmc.api` (docs/api.md); its functions are also reachable
from here (``lesmc.check``, ``lesmc.load_model``, ...), imported when first used so
that ``import lesmc`` stays light.
"""

from __future__ import annotations

from typing import Any as _Any

_ERRORS = ("LesmcError", "InputError", "SpecError", "ModelError", "UsageError", "BudgetError")

_API = (
    "CheckResult",
    "DesignRun",
    "MultiCheckResult",
    "MultiModel",
    "AttackStep",
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
    "load_model",
    "load_model_or_scene",
    "load_scene",
    "load_spec",
    "parse_spec",
    "perceive",
    "save_model",
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
    """Exactly the public names (``__all__``), as ``dir(module)`` shows for a plain module."""
    return sorted(__all__)
