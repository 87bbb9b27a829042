"""The tracker's linear-Gaussian model (Eq. 1-3): a named preset or matrices the user declares.

A scene's ``tracker.model`` (docs/scene-format.md, "Tracker models") is either

* a preset name: ``"cv2d"``, the paper's near-constant-velocity model (Eq. 16-18,
  from ``sigma_q``, ``sigma_r``, ``P0_sd``; the default), or ``"ca2d"``, constant
  acceleration (state x, y, vx, vy, ax, ay; white-noise jerk of density σ_q²); or
* a :class:`DeclaredModel`: state names and the per-step matrices F, H, Q, R, P0
  (dt already applied), given entry by entry.

Detections are positions, so H has two rows, and each row measures one state
component directly (a single 1): the first row is the detection's x, the second
its y. Those two components are the track's position: what the gate compares with
detections, what a frame's homography carries, what the monitor's τ (Eq. 12)
reads, and where a new track of the joint design starts. The components named
``vx`` and ``vy``, if the state has them, take the target's initial velocity.

This module only reads and validates; lesmc/tracking/kalman.py turns a model into
the matrices the filter uses.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from lesmc.common.errors import Problems
from lesmc.common.fields import is_finite, show

#: The presets' state components, in order.
PRESETS: dict[str, tuple[str, ...]] = {
    "cv2d": ("x", "y", "vx", "vy"),
    "ca2d": ("x", "y", "vx", "vy", "ax", "ay"),
}
#: The presets' default initial standard deviations (P0 = diag(P0_sd)²).
PRESET_P0_SD: dict[str, tuple[float, ...]] = {
    "cv2d": (30.0, 30.0, 20.0, 20.0),
    "ca2d": (30.0, 30.0, 20.0, 20.0, 10.0, 10.0),
}
DEFAULT_MODEL = "cv2d"
#: The components that take the target's initial velocity, when the state has them.
VELOCITY = ("vx", "vy")
#: Largest state a declared model may have, and the largest |entry| of its matrices.
MAX_STATE = 32
MAX_ENTRY = 1e12
#: Relative tolerance of the symmetry and semi-definiteness checks (entries typed in
#: by hand or printed from numpy are symmetric only to rounding).
SYMMETRY_TOL = 1e-9
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_\-]*\Z")  # the spec language's NAME


@dataclass(frozen=True)
class EntryFault:
    """A failed entry of the filter's F, H, Q or R (section 9.2), bound to indices: from
    frame ``frame`` on, the entry (row, col) is multiplied by ``value`` (``op`` ``*``) or
    replaced by it (``=``). A covariance (Q, R) is symmetric, so its (col, row) entry
    fails with it. The language's ``fault NAME: Q[vx, vx] * 0`` (lesmc/pipeline/faults.py
    binds it); scenes never store one."""

    matrix: str
    row: int
    col: int
    op: str
    value: float
    frame: int

    def apply(self, M: np.ndarray) -> None:
        """Change ``M`` (this fault's matrix) in place."""
        cells = {(self.row, self.col)}
        if self.matrix in ("Q", "R"):
            cells.add((self.col, self.row))
        for i, j in cells:
            M[i, j] = M[i, j] * self.value if self.op == "*" else self.value


@dataclass(frozen=True)
class DeclaredModel:
    """A model given by its matrices: state names and F, H, Q, R, P0 as rows of numbers."""

    state: tuple[str, ...]
    F: tuple[tuple[float, ...], ...]
    H: tuple[tuple[float, ...], ...]
    Q: tuple[tuple[float, ...], ...]
    R: tuple[tuple[float, ...], ...]
    P0: tuple[tuple[float, ...], ...]

    def matrix(self, name: str) -> np.ndarray:
        """One of F, H, Q, R, P0 as a float array (a fresh copy)."""
        return np.array(getattr(self, name), dtype=float)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"state": list(self.state)}
        for name in MATRICES:
            out[name] = [list(row) for row in getattr(self, name)]
        return out


TrackerModel = str | DeclaredModel
"""A preset's name or a declared model."""

MATRICES = ("F", "H", "Q", "R", "P0")


def state_names(model: TrackerModel) -> tuple[str, ...]:
    """The state components' names, in order: what a spec's ``on x, y`` refers to."""
    return PRESETS[model] if isinstance(model, str) else model.state


def measured(model: TrackerModel) -> tuple[int, int]:
    """The state components the detection's x and y measure (H's two unit rows)."""
    if isinstance(model, str):
        return (0, 1)
    i, j = (row.index(1.0) for row in model.H)
    return (i, j)


def velocity(model: TrackerModel) -> tuple[int, int] | None:
    """The components named ``vx`` and ``vy`` (the target's initial velocity), if present."""
    names = state_names(model)
    if all(v in names for v in VELOCITY):
        return (names.index(VELOCITY[0]), names.index(VELOCITY[1]))
    return None


def preset_R(sigma_r: float) -> np.ndarray:
    """A preset's measurement noise covariance R = σ_r² I (Eq. 18)."""
    return np.eye(2) * sigma_r**2


def singular_innovation(R: np.ndarray) -> str | None:
    """Why the innovation covariance S = H P Hᵀ + R (Eq. 3) could be numerically singular
    with this R, or None. S ⪰ R, so det S ≥ det R; the filter inverts S in closed form
    (lesmc/tracking/kalman.py: innovations), which needs det R = ad − bc to be a normal
    float and R⁻¹ finite. A tiny but positive R (1e-300·I) passes the definiteness test
    and would make every gate test divide by zero."""
    det = float(R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0])
    inv_max = float(np.abs(R).max()) / det if det > 0 else math.inf
    if det >= np.finfo(float).tiny and math.isfinite(inv_max):
        return None
    return (
        f"is numerically singular: its determinant {det:.6g} is below the smallest normal "
        f"float {np.finfo(float).tiny:.6g}, so S = H P Hᵀ + R cannot be inverted "
        "(express positions in larger units, or give a larger measurement noise)"
    )


# ---------------------------------------------------------------- reading


def parse_model(raw: Any, pr: Problems, item: str = "tracker") -> TrackerModel | None:
    """``tracker.model`` from a file: a preset's name or a declared model (None if invalid;
    every problem is added to ``pr`` under ``item``, naming the matrix and the dimension)."""
    if isinstance(raw, str):
        if raw in PRESETS:
            return raw
        known = " or ".join(f'"{n}"' for n in PRESETS)
        pr.add(item, f"model must be {known}, or an object of matrices, got {show(raw)}")
        return None
    if not isinstance(raw, dict):
        pr.add(item, f"model must be a preset's name or an object of matrices, got {show(raw)}")
        return None
    n0 = len(pr.items)
    for key in sorted(set(raw) - {"state", *MATRICES}):
        pr.add(item, f"model: unknown key '{key}' (expected state, {', '.join(MATRICES)})")
    state = _state(raw.get("state"), pr, item)
    if state is None:
        return None
    d = len(state)
    shapes = {"F": (d, d), "H": (2, d), "Q": (d, d), "R": (2, 2), "P0": (d, d)}
    mats: dict[str, np.ndarray] = {}
    for name, shape in shapes.items():
        m = _matrix(raw.get(name), name, shape, state, pr, item)
        if m is not None:
            mats[name] = m
    if len(mats) == len(MATRICES):
        _check_h(mats["H"], state, pr, item)
        for name, definite in (("Q", False), ("R", True), ("P0", True)):
            mats[name] = _covariance(mats[name], name, definite, pr, item)
        if len(pr.items) == n0 and (why := singular_innovation(mats["R"])) is not None:
            pr.add(item, f"model.R {why}")
    if len(pr.items) > n0:
        return None
    rows = {k: tuple(tuple(float(v) for v in r) for r in m) for k, m in mats.items()}
    return DeclaredModel(state, rows["F"], rows["H"], rows["Q"], rows["R"], rows["P0"])


def _state(raw: Any, pr: Problems, item: str) -> tuple[str, ...] | None:
    if raw is None:
        pr.add(item, f"model.state is missing: a list of 2 to {MAX_STATE} component names")
        return None
    ok = (
        isinstance(raw, list)
        and 2 <= len(raw) <= MAX_STATE
        and all(isinstance(s, str) and _NAME.match(s) for s in raw)
    )
    if not ok:
        pr.add(
            item,
            f"model.state must be a list of 2 to {MAX_STATE} component names "
            f"(letters, digits, _ and -, not starting with a digit), got {show(raw)}",
        )
        return None
    if len(set(raw)) != len(raw):
        dup = next(s for s in raw if raw.count(s) > 1)
        pr.add(item, f"model.state names component '{dup}' twice")
        return None
    return tuple(raw)


def _matrix(
    raw: Any, name: str, shape: tuple[int, int], state: tuple[str, ...], pr: Problems, item: str
) -> np.ndarray | None:
    """A matrix of ``shape`` given as a list of rows of finite numbers."""
    rows, cols = shape
    note = (
        "one row per detection coordinate"
        if name == "H"
        else "the detection's x, y"
        if name == "R"
        else f"the state has {len(state)} components"
    )
    what = f"a {rows}x{cols} matrix ({note})"
    if raw is None:
        pr.add(item, f"model.{name} is missing: {what}")
        return None
    if not isinstance(raw, list) or len(raw) != rows:
        got = f"{len(raw)} rows" if isinstance(raw, list) else show(raw)
        pr.add(item, f"model.{name} must be {what}, got {got}")
        return None
    for r, row in enumerate(raw):
        if not isinstance(row, list) or len(row) != cols:
            got = f"{len(row)}" if isinstance(row, list) else f"{show(row)}, not a list"
            pr.add(
                item, f"model.{name} row {r} must have {cols} entries, got {got}: {name} is {what}"
            )
            return None
        for c, v in enumerate(row):
            if not (is_finite(v) and abs(v) <= MAX_ENTRY):
                pr.add(
                    item,
                    f"model.{name}[{r}][{c}] must be a finite number within ±{MAX_ENTRY:g}, "
                    f"got {show(v)}",
                )
                return None
    return np.array(raw, dtype=float)


def _check_h(H: np.ndarray, state: tuple[str, ...], pr: Problems, item: str) -> None:
    """Each row of H measures one component directly; the two rows measure different ones."""
    picked: list[int] = []
    for r, coord in enumerate(("x", "y")):
        row = H[r]
        ones = np.flatnonzero(row == 1.0)
        if len(ones) != 1 or np.count_nonzero(row) != 1:
            pr.add(
                item,
                f"model.H row {r} (the detection's {coord}) must measure one state component "
                "directly: a single 1 and zeros elsewhere",
            )
            return
        picked.append(int(ones[0]))
    if picked[0] == picked[1]:
        pr.add(
            item,
            f"model.H measures fewer than two components: both rows measure "
            f"'{state[picked[0]]}' (a detection gives two coordinates)",
        )


def _covariance(m: np.ndarray, name: str, definite: bool, pr: Problems, item: str) -> np.ndarray:
    """``m`` symmetrised, after checking it is symmetric and positive (semi-)definite."""
    scale = max(float(np.abs(m).max()), 1e-300)
    asym = float(np.abs(m - m.T).max())
    if asym > SYMMETRY_TOL * scale:
        r, c = np.unravel_index(int(np.argmax(np.abs(m - m.T))), m.shape)
        pr.add(
            item,
            f"model.{name} must be symmetric: [{r}][{c}] = {float(m[r, c])!r} "
            f"but [{c}][{r}] = {float(m[c, r])!r}",
        )
        return m
    sym: np.ndarray = 0.5 * (m + m.T)
    low = float(np.linalg.eigvalsh(sym).min())
    kind = "positive definite" if definite else "positive semi-definite"
    if definite:
        try:
            np.linalg.cholesky(sym)
            bad = low <= 0
        except np.linalg.LinAlgError:
            bad = True
    else:
        bad = low < -SYMMETRY_TOL * scale
    if bad or not math.isfinite(low):
        pr.add(item, f"model.{name} must be {kind}; its smallest eigenvalue is {low:.6g}")
    return sym
