"""The runtime monitors a design may carry, in one registry: name, summary, parameter
domain and alarm function (docs/semantics.md, "Runtime monitors").

A monitor watches one track step by step and raises an alarm at a step from what the
tracker did entering it: the uncertainty τ (Eq. 12, the trace of the position block of
P) before and after the step, and the normalised innovation squared (NIS) of the update
the step took (NaN: the step took none). Every alarm function here reads those per-step
arrays along their last axis (steps 0..n of a track, or the two ends of one
transition), so the checker (one transition at a time), ``lesmc alarms`` (whole
unattacked tracks) and the tests all call the same function.

The registry lives in the language package because every layer may import it: the
parser checks a ``monitor KIND PARAM`` clause against it (a parameter outside the
domain is a located error), the model's kernel and the engines cut the transitions
its alarm fires on, and the tracking and verify packages run it on unattacked tracks.
Adding a monitor is one function and one :func:`register` call at the end of this file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from lesmc.language.properties import DEFAULT_MONITOR_TOLERANCE, Monitor

#: The dimension of a detection (a position x, y): the χ² degrees of freedom of one NIS.
MEASUREMENT_DIM = 2


@dataclass(frozen=True)
class Domain:
    """The values a monitor's parameter may take: an interval, open or closed at each
    end, optionally of whole numbers only."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def contains(self, v: float) -> bool:
        """``v`` lies in the domain (NaN and the infinities never do)."""
        if not math.isfinite(v) or (self.integer and v != int(v)):
            return False
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return above and below

    def text(self) -> str:
        """The domain as users read it: ``in (0, 1)``, ``>= 0``, ``a whole number >= 1``."""
        if self.integer:
            return f"a whole number >= {self.lo:g}" + (
                "" if math.isinf(self.hi) else f" and <= {self.hi:g}"
            )
        if math.isinf(self.hi):
            return f"a finite number {'>' if self.lo_open else '>='} {self.lo:g}"
        left, right = "(" if self.lo_open else "[", ")" if self.hi_open else "]"
        return f"in {left}{self.lo:g}, {self.hi:g}{right}"


#: An alarm function: (parameter, window k, τ (..., n+1), NIS (..., n+1)) -> alarms (..., n+1).
AlarmFunction = Callable[[float, int, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class MonitorKind:
    """One registered monitor.

    ``parameter`` names its number (a tolerance, a quantile, a count of steps, a bound),
    ``default`` is used when a spec gives none (None: a spec must give one),
    ``windowed`` whether it takes ``window k`` (the NIS over the last k steps),
    ``reads`` what per-step quantity it needs: ``tau`` (the covariance P of every
    state) or ``nis`` (the NIS of every transition's update, docs/lts-format.md).
    ``memory`` is how many steps back its alarm looks beyond the step itself
    (window k: k − 1; ``misses`` k: k − 1): the checker evaluates monitors per
    transition, so it accepts only memory 0.
    """

    name: str
    summary: str
    parameter: str
    domain: Domain
    default: float | None
    windowed: bool
    reads: str
    alarm: AlarmFunction

    def memory(self, param: float, window: int) -> int:
        """Steps before the current one that the alarm reads."""
        if self.name == "misses":
            return int(param) - 1
        return window - 1 if self.windowed else 0


_KINDS: dict[str, MonitorKind] = {}


def register(kind: MonitorKind) -> MonitorKind:
    """Add a monitor kind (replacing one of the same name); returns it."""
    _KINDS[kind.name] = kind
    return kind


def names() -> tuple[str, ...]:
    """Every registered monitor kind, in registration order."""
    return tuple(_KINDS)


def get(name: str) -> MonitorKind:
    """The monitor kind ``name`` (KeyError if none)."""
    return _KINDS[name]


def spelled() -> str:
    """The kinds with their parameter, as ``--help`` lists them: ``tau_rise TOLERANCE, ...
    or trace BOUND``."""
    words = [f"{k.name} {k.parameter.upper()}" for k in _KINDS.values()]
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


#: The longest window (and ``misses`` run) a monitor may read: a scene's last step.
MAX_WINDOW = 10**6


def resolve(kind: str, parameter: float | None, window: int = 1) -> tuple[str, float, int]:
    """A monitor named outside a spec (``--monitor``, a tracker file's ``monitor``): its
    kind, its parameter (the kind's default when None) and window, checked against the
    registry; ValueError with the reason otherwise."""
    if kind not in _KINDS:
        raise ValueError(f"unknown monitor {kind!r}; the monitors are {', '.join(_KINDS)}")
    declared = _KINDS[kind]
    if parameter is None:
        if declared.default is None:
            raise ValueError(
                f"the {kind} monitor needs its {declared.parameter} ({declared.domain.text()})"
            )
        parameter = declared.default
    if not declared.domain.contains(parameter):
        raise ValueError(
            f"the {kind} monitor's {declared.parameter} must be {declared.domain.text()}, "
            f"got {parameter:g}"
        )
    if window != 1 and not declared.windowed:
        raise ValueError(f"the {kind} monitor takes no window")
    if window < 1:
        raise ValueError("the monitor's window must be at least 1 step")
    if window > MAX_WINDOW:
        raise ValueError(f"the monitor's window must be at most {MAX_WINDOW} steps")
    return kind, parameter, window


def from_text(text: str) -> tuple[str, float, int]:
    """``KIND [PARAM] [window K]`` (a spec's monitor clause without ``monitor``; ``uncertainty``
    is ``tau_rise``), checked by :func:`resolve`."""
    words = text.split()
    if not words:
        raise ValueError("empty monitor: write KIND [PARAM] [window K], e.g. 'nis 0.99'")
    kind = "tau_rise" if words[0] == "uncertainty" else words[0]
    rest = words[1:]
    window = 1
    if len(rest) >= 2 and rest[-2] == "window":
        if not rest[-1].isdigit():
            raise ValueError(f"window must be a whole number of steps, got {rest[-1]!r}")
        window = int(rest[-1])
        rest = rest[:-2]
    if len(rest) > 1:
        raise ValueError(f"{text!r}: write KIND [PARAM] [window K]")
    parameter = None
    if rest:
        try:
            parameter = float(rest[0])
        except ValueError:
            raise ValueError(
                f"the {kind} monitor's parameter {rest[0]!r} is not a number"
            ) from None
        if not math.isfinite(parameter):
            raise ValueError(f"the {kind} monitor's parameter must be finite")
    return resolve(kind, parameter, window)


def unchecked_reason(mon: Monitor) -> str | None:
    """Why the checker cannot filter paths with ``mon`` (None: it can): it evaluates a
    monitor one transition at a time, and a window of k > 1 steps reads the path's last k."""
    memory = _KINDS[mon.kind].memory(mon.parameter, mon.window)
    if not memory:
        return None
    return (
        f"'monitor {mon.text()}' reads {memory + 1} steps of a path; the checker "
        "evaluates a monitor one transition at a time (window 1, misses 1): "
        "'lesmc alarms' measures the longer ones on unattacked tracks"
    )


def declared(text: str | None) -> Monitor:
    """The monitor a tracker declares (its ``monitor`` key, :func:`from_text`; checked when
    the tracker was read), else Eq. 13's: what the monitored designs add to properties."""
    if text is None:
        return Monitor()
    kind, value, window = from_text(text)
    return Monitor(parameter=value, kind=kind, window=window)


def rises(tau_prev: np.ndarray, tau_next: np.ndarray, tolerance: float) -> np.ndarray:
    """Eq. 13's Γ = 0: τ rose from one step to the next beyond the relative tolerance (a
    tolerance so large that the bound overflows to inf: never)."""
    with np.errstate(over="ignore"):
        out: np.ndarray = np.asarray(tau_next) > np.asarray(tau_prev) * (1.0 + tolerance) + 1e-300
    return out


@cache
def chi2_bound(quantile: float, dof: int) -> float:
    """The ``quantile`` of the χ² distribution with ``dof`` degrees of freedom."""
    from scipy.stats import chi2  # imported only where a NIS monitor runs

    return float(chi2.ppf(quantile, dof))


def _first_steps(tau: np.ndarray) -> np.ndarray:
    """No alarm at step 0 of a track: nothing happened before it."""
    return np.zeros(tau.shape, dtype=bool)


def _tau_rise(param: float, window: int, tau: np.ndarray, nis: np.ndarray) -> np.ndarray:
    """Eq. 13 with tolerance ``param``: the alarm fires entering step j when τ_j rises above
    τ_{j-1}·(1 + param)."""
    out = _first_steps(tau)
    out[..., 1:] = rises(tau[..., :-1], tau[..., 1:], param)
    return out


def _trace(param: float, window: int, tau: np.ndarray, nis: np.ndarray) -> np.ndarray:
    """τ above the bound ``param`` at step j (the paper's trace limit read as an alarm)."""
    out = _first_steps(tau)
    out[..., 1:] = tau[..., 1:] > param
    return out


def _sliding_sum(a: np.ndarray, k: int) -> np.ndarray:
    """Per step j, the sum of ``a`` over steps max(0, j−k+1)..j (along the last axis)."""
    c = np.cumsum(a, axis=-1)
    out: np.ndarray = c.copy()
    out[..., k:] -= c[..., :-k]
    return out


def _nis(param: float, window: int, tau: np.ndarray, nis: np.ndarray) -> np.ndarray:
    """The NIS test: the sum of the NIS of the updates over the last ``window`` steps
    exceeds the ``param`` quantile of χ² with (updates in the window) × 2 degrees of
    freedom; a window without an update raises none."""
    nis = np.asarray(nis, dtype=float)
    updated = np.isfinite(nis)
    total = _sliding_sum(np.where(updated, nis, 0.0), window)
    count = _sliding_sum(updated.astype(np.int64), window)
    bound = np.full(count.shape, np.inf)
    for n in np.unique(count[count > 0]).tolist():
        bound[count == n] = chi2_bound(param, int(n) * MEASUREMENT_DIM)
    out: np.ndarray = (count > 0) & (total > bound)
    out[..., 0] = False
    return out


def _misses(param: float, window: int, tau: np.ndarray, nis: np.ndarray) -> np.ndarray:
    """``param`` = k consecutive steps without an update, ending at step j (step 0, the
    track's start, is no miss)."""
    k = int(param)
    missed = ~np.isfinite(np.asarray(nis, dtype=float))
    missed[..., 0] = False
    run = _sliding_sum(missed.astype(np.int64), k)
    out: np.ndarray = run >= k
    return out


register(
    MonitorKind(
        "tau_rise",
        "the paper's Eq. 13: τ rises by more than a relative tolerance (section 7.1)",
        "tolerance",
        Domain(0.0, math.inf),
        DEFAULT_MONITOR_TOLERANCE,
        False,
        "tau",
        _tau_rise,
    )
)
register(
    MonitorKind(
        "nis",
        "the normalised innovation squared of the updates above a χ² quantile "
        "(optionally summed over a window of k steps)",
        "quantile",
        Domain(0.0, 1.0, lo_open=True, hi_open=True),
        None,
        True,
        "nis",
        _nis,
    )
)
register(
    MonitorKind(
        "misses",
        "k consecutive steps without an update",
        "steps",
        Domain(1.0, MAX_WINDOW, integer=True),
        None,
        False,
        "nis",
        _misses,
    )
)
register(
    MonitorKind(
        "trace",
        "τ (the trace of the position block of P) above a bound",
        "bound",
        Domain(0.0, math.inf, lo_open=True),
        None,
        False,
        "tau",
        _trace,
    )
)
