"""What can still happen after a label of the ``levels`` engine (lesmc/engines/levels.py):
the bounds its passes prune with. Trivial on a space unfolded on demand; on an explicit
model exact suffix minima and maxima (one backward pass, lesmc/engines/bounds.py) and,
when objective and constraint are both sums, Lagrangian bounds
``o + min_suffix Σ(c_obj − sλ c_con) + sλ(B − c)`` for a grid of λ ≥ 0: the relaxation
that makes the 0-1 knapsack's fractional bound (docs/engines.md)."""

from __future__ import annotations

import math

import numpy as np

from lesmc.engines.bounds import Bounds, suffix_bounds
from lesmc.engines.labels import SLICE
from lesmc.engines.labels import grain as _grain
from lesmc.engines.labels import hi as _hi
from lesmc.engines.labels import lo as _lo
from lesmc.engines.labels import truth as _truth
from lesmc.engines.space import SearchSpace, Space
from lesmc.model.kernel import aggregate_arrays

#: λ values of the Lagrangian bound.
LAMBDAS = 48
#: :meth:`LevelBounds._useful_lambdas` looks at this many states (at most) and constraint values.
LAMBDA_SAMPLE_STATES = 4096
LAMBDA_SAMPLE_VALUES = 33
#: Grid points over [0, B] at which :meth:`LevelBounds._best_lambdas` picks each state's λ.
LAMBDA_GRID = 64


class LevelBounds:
    """What can still happen after a label: trivial on a lazy space, exact suffix bounds
    (and Lagrangian ones) on an explicit one."""

    def __init__(
        self, space: SearchSpace, lagrangian: bool = True, suffix: Bounds | None = None
    ) -> None:
        self.space = space
        self.omin = self.omax = self.cmin = self.cmax = None
        self.alive: np.ndarray | None = None
        self.lam: np.ndarray | None = None
        self.h: np.ndarray | None = None  # (n, K): min suffix Σ(c_obj − sλ c_con)
        self.best_k: np.ndarray | None = None  # see _best_lambdas
        self.grain: float | None = None  # every objective a multiple of it (explicit sums)
        if isinstance(space, Space):
            b = suffix if suffix is not None else suffix_bounds(space)
            self.omin, self.omax, self.cmin, self.cmax = b.obj_min, b.obj_max, b.con_min, b.con_max
            self.alive = b.alive
            self.reachable = b.states
            if lagrangian and not space.obj_max and not space.con_max:
                self._lagrangian(space)
            if not space.obj_max:
                self.grain = _grain(space)

    @property
    def exact(self) -> bool:
        return self.omin is not None

    def cut(self, best: float) -> float:
        """Labels whose violating lower bound is not below this cannot beat ``best``.

        On an explicit model whose objective contributions are all multiples of g
        (sums), a better path ends at best − g or lower, so the cut is best − g
        (less a hair, so that a bound equal to best − g is kept).
        """
        g = self.grain
        return best if g is None or not math.isfinite(best) else best - g * (1 - 1e-9)

    def violating_lb(self, q: np.ndarray, o: np.ndarray, c: np.ndarray) -> np.ndarray:
        """A lower bound on the final objective of any *violating* completion; +inf
        where none can violate."""
        sp = self.space
        if self.omin is None:
            return o.copy()
        assert self.alive is not None and self.cmax is not None and self.cmin is not None
        # a dead state's suffix bounds are ±inf: with an infinite label value they give
        # nan, which the `can` mask below replaces by +inf
        with np.errstate(invalid="ignore"):
            lb = _lo(aggregate_arrays(sp.obj_max, o, self.omin[q]))
            if sp.con_up:
                reach = _hi(aggregate_arrays(sp.con_max, c, self.cmax[q]))
            else:
                reach = _lo(aggregate_arrays(sp.con_max, c, self.cmin[q]))
        can = self.alive[q] & _truth(sp.satisfies(reach, sp.bp.bound))
        if self.h is not None and self.lam is not None:
            lb = np.maximum(lb, _lo(o + self._lagrangian_at(q, c)))
        return np.where(can, lb, math.inf)

    def _lagrangian_at(self, q: np.ndarray, c: np.ndarray) -> np.ndarray:
        """max over λ of h[q, λ] + sλ(B − c): a lower bound on the objective still to come
        of a violating completion (each λ alone gives one).

        Where ``best_k`` is built, each label tries only the two λ that are best at the
        grid points around its x = B − min(c, B) (the max over λ is convex in x), not
        every λ: a max over fewer λ is still a valid bound, and nearly as tight.
        """
        assert self.h is not None and self.lam is not None
        sp = self.space
        B = sp.bp.bound
        s = 1.0 if sp.con_up else -1.0
        # past the bound, λ·(B − c) ≤ 0 only weakens the bound; λ = 0 alone is valid there
        cb = np.minimum(c, B) if sp.con_up else c
        with np.errstate(invalid="ignore"):
            x = s * (B - cb)
        finite = bool(np.isfinite(x).all())
        if self.best_k is not None and finite:
            j = np.minimum((x * ((LAMBDA_GRID - 1) / B)).astype(np.int64), LAMBDA_GRID - 2)
            row = q * LAMBDA_GRID + j
            k1, k2 = self.best_k[row], self.best_k[row + 1]
            v1 = self.h[q, k1] + self.lam[k1] * x
            v2 = self.h[q, k2] + self.lam[k2] * x
            best: np.ndarray = np.maximum(v1, v2)
            return best
        lag = np.multiply.outer(x, self.lam)  # (labels × λ)
        lag += self.h[q]
        if not finite:  # only then can inf − inf give nan
            lag[np.isnan(lag)] = -math.inf
        out: np.ndarray = lag.max(axis=1)
        return out

    def _best_lambdas(self) -> np.ndarray | None:
        """best_k[q·G + j]: the λ that maximizes h[q, λ] + λ x_j at G grid points x_j
        spanning [0, B] (``>``/``>=`` constraints with a finite bound B > 0 only, and one
        whose grid step (G − 1)/B is finite: not a subnormal B; None where the table would
        be too big to be worth it)."""
        assert self.h is not None and self.lam is not None
        sp = self.space
        B = sp.bp.bound
        n, k = self.h.shape
        if not (sp.con_up and math.isfinite(B) and B > 0) or n * k * LAMBDA_GRID > 1 << 26:
            return None
        if not math.isfinite((LAMBDA_GRID - 1) / B):  # B subnormal: the exact max instead
            return None
        return _winning_lambdas(self.h, self.lam, np.linspace(0.0, B, LAMBDA_GRID)).ravel()

    def least_lb(self, q: np.ndarray, o: np.ndarray, c: np.ndarray) -> float:
        """The least :meth:`violating_lb` of many labels, in chunks (its λ grid is wide)."""
        out = math.inf
        for a in range(0, q.size, SLICE):
            lb = self.violating_lb(q[a : a + SLICE], o[a : a + SLICE], c[a : a + SLICE])
            out = min(out, float(lb.min(initial=math.inf)))
        return out

    def range(self, q: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest and largest final objective over all completions (dead: +inf, −inf)."""
        sp = self.space
        if self.omin is None:
            return o.copy(), np.full(o.shape, math.inf)
        assert self.omax is not None and self.alive is not None
        lo = _lo(aggregate_arrays(sp.obj_max, o, self.omin[q]))
        hi = _hi(aggregate_arrays(sp.obj_max, o, self.omax[q]))
        return np.where(self.alive[q], lo, math.inf), np.where(self.alive[q], hi, -math.inf)

    def _lagrangian(self, space: Space) -> None:
        """h[q, k] = min over completions of Σ(c_obj − sλ_k c_con), tails included.

        λ runs over a geometric grid spanning the transitions' cost/constraint ratios,
        then over a finer grid around the λ that bounds the root best.
        """
        co, cc = space.c_obj[space.adj], space.c_con[space.adj]
        ok = (cc > 0) & np.isfinite(cc) & np.isfinite(co) & (co > 0)
        if not ok.any() or space.cm.n_states == 0:
            return
        k = max(2, min(LAMBDAS, int(1e7 // max(space.cm.n_states, 1))))
        lo, hi = np.quantile(co[ok] / cc[ok], [0.01, 0.99])
        lam = np.r_[0.0, np.geomspace(lo / 4, hi * 4, k - 1)]
        h = self._suffix_lagrangian(space, lam)
        s = 1.0 if space.con_up else -1.0
        with np.errstate(invalid="ignore"):
            root = h[space.root] + s * lam * (space.bp.bound - space.root_con)
        i = int(np.nanargmax(np.where(np.isnan(root), -math.inf, root)))
        fine = np.linspace(lam[max(i - 1, 0)], lam[min(i + 1, lam.size - 1)], k + 2)[1:-1]
        self.lam = np.r_[lam, fine]
        self.h = np.concatenate([h, self._suffix_lagrangian(space, fine)], axis=1)
        if space.con_up:
            keep = self._useful_lambdas(space)
            self.lam, self.h = self.lam[keep], self.h[:, keep]
        self.best_k = self._best_lambdas()

    def _useful_lambdas(self, space: Space) -> np.ndarray:
        """The λ that give the best bound for some state and some constraint value in
        [0, B] (sampled): every λ gives a valid bound, so dropping the others keeps the
        bound valid; on the knapsack classes a quarter of the grid wins anywhere, and
        each label's bound then costs a quarter as much."""
        assert self.h is not None and self.lam is not None
        h, lam = self.h, self.lam
        states = np.flatnonzero(np.isfinite(h).any(axis=1))
        if states.size > LAMBDA_SAMPLE_STATES:
            states = np.random.default_rng(0).choice(states, LAMBDA_SAMPLE_STATES, replace=False)
        B = space.bp.bound
        if not (math.isfinite(B) and B > 0 and states.size):
            return np.arange(lam.size)
        win = np.zeros(lam.size, dtype=bool)
        win[0] = True  # λ = 0: the plain suffix minimum, kept always
        xs = B - np.linspace(0.0, B, LAMBDA_SAMPLE_VALUES)  # x = B − c
        win[_winning_lambdas(h[states], lam, xs)] = True
        return np.flatnonzero(win)

    @staticmethod
    def _suffix_lagrangian(space: Space, lam: np.ndarray) -> np.ndarray:
        cm = space.cm
        s = 1.0 if space.con_up else -1.0
        leaf = space.leaves()
        h = np.full((cm.n_states, lam.size), math.inf)
        levels = space.reachable_levels()
        for i in reversed(range(len(levels))):
            level = levels[i]
            ends = level[leaf[level]]
            if ends.size:
                to, tc = space.tails(ends)
                with np.errstate(invalid="ignore"):
                    rows = to[:, None] - s * lam[None, :] * tc[:, None]
                h[ends] = np.where(np.isnan(rows), to[:, None], rows)
            inner, t, seg, has = space.level_moves(i)
            if not t.size:
                continue
            vals = (space.c_obj[t] - s * np.outer(space.c_con[t], lam).T).T + h[cm.dst[t]]
            vals = np.where(np.isnan(vals), math.inf, vals)
            h[inner[has]] = np.minimum.reduceat(vals, seg[:-1][has], axis=0)
        return h


def _winning_lambdas(h: np.ndarray, lam: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """(states × x): the index of the λ that maximizes h[q, λ] + λ x at each x (a nan
    from inf − inf counts as −inf); in chunks of states of 4 M values at most."""
    out = np.empty((h.shape[0], xs.size), dtype=np.int64)
    rows = max(1, (1 << 22) // max(1, lam.size * xs.size))
    lx = lam[None, :] * xs[:, None]  # (x, λ)
    exact = bool(np.isfinite(lx).all())  # then no inf − inf (h holds no nan)
    for a in range(0, h.shape[0], rows):
        with np.errstate(invalid="ignore"):
            v = h[a : a + rows, None, :] + lx[None]
        if not exact:
            v[np.isnan(v)] = -math.inf
        out[a : a + rows] = v.argmax(axis=2)
    return out
