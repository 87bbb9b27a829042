"""Benchmark: Eq. 2-3 for a stack of covariances, lesmc's stacked matrix products against
the three-operand einsum form they replaced (docs/performance.md, issue 31 fourth round).

Side by side in one process, best of 5 runs of ``--calls`` calls each, on a stack of
``--stack`` covariances of the dense scene's tracker (a stack as the lazy unfolder asks
for one, 26 on average on dense resilience 4..12). Both forms give the same bits alone
or in any batch; this also checks that they agree to 1e-12.

Run ``python benchmarks/bench_kalman.py [--stack 26] [--calls 5000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_unfold import dense_scene

from lesmc.tracking.kalman import Innovation, Matrices, innovations, predict_covariances
from lesmc.tracking.single import SingleDesign


def einsum_predict(m: Matrices, P: np.ndarray) -> np.ndarray:
    """P̂ = F P Fᵀ + Q as lesmc computed it before (three-operand einsum)."""
    out: np.ndarray = np.einsum("ij,njk,lk->nil", m.F, P, m.F) + m.Q
    return out


def einsum_innovations(m: Matrices, P_pred: np.ndarray) -> Innovation:
    """S, S⁻¹, K and the Joseph update as lesmc computed them before (einsum)."""
    S = np.einsum("ij,njk,lk->nil", m.H, P_pred, m.H) + m.R
    a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
    det = a * d - b * c
    S_inv = np.empty_like(S)
    S_inv[:, 0, 0] = d / det
    S_inv[:, 0, 1] = -b / det
    S_inv[:, 1, 0] = -c / det
    S_inv[:, 1, 1] = a / det
    K = np.einsum("nij,kj,nkl->nil", P_pred, m.H, S_inv)
    I_KH = np.eye(P_pred.shape[-1]) - np.einsum("nij,jk->nik", K, m.H)
    P_post = np.einsum("nij,njk,nlk->nil", I_KH, P_pred, I_KH) + np.einsum(
        "nij,jk,nlk->nil", K, m.R, K
    )
    return Innovation(S, S_inv, K, P_post)


def best_us(f: Callable[[], object], calls: int) -> float:
    """Microseconds per call, best of 5 runs."""
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            f()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stack", type=int, default=26)
    ap.add_argument("--calls", type=int, default=5000)
    args = ap.parse_args()
    m = SingleDesign(dense_scene(40, 24, 0, "single")).m
    rng = np.random.default_rng(0)
    P = np.stack([m.P0 * (1 + rng.random()) for _ in range(args.stack)])
    Pp = predict_covariances(m, P)
    assert np.allclose(einsum_predict(m, P), Pp, rtol=1e-12, atol=0)
    new, old = innovations(m, Pp), einsum_innovations(m, Pp)
    assert np.allclose(new.P_post, old.P_post, rtol=1e-12, atol=1e-12)
    assert np.allclose(new.K, old.K, rtol=1e-12, atol=1e-12)
    rows = [
        ("predict (Eq. 2)", lambda: einsum_predict(m, P), lambda: predict_covariances(m, P)),
        ("innovations (Eq. 3)", lambda: einsum_innovations(m, Pp), lambda: innovations(m, Pp)),
    ]
    print(f"{args.stack} covariances per call, µs per call (best of 5 x {args.calls})")
    for name, ref, ours in rows:
        a, b = best_us(ref, args.calls), best_us(ours, args.calls)
        print(f"  {name:20s} einsum {a:6.1f}   matmul {b:6.1f}   {a / b:4.2f}x")


if __name__ == "__main__":
    main()
