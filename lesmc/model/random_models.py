"""Random layered <PO>²-LTSs, for property-based tests and benchmarks.

Layer k holds the states of step k; every state reaches 1..``branching``
states of the next layer, so paths share states (a DAG, not a tree) unless
``tree=True``. Ranks order each state's transitions with a unique minimum and
occasional ties above it (a partial order); some off-original states halt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.model.lts import HALTED, LTS, State, Transition


@dataclass(frozen=True)
class RandomModelConfig:
    """Shape of a random model; every field has a direct effect on the path count."""

    steps: int = 10  # e: the original path has steps 0..e
    width: int = 6  # states per layer (DAG mode)
    branching: tuple[int, int] = (2, 4)  # min/max successors per state
    dim: int = 2  # size of s
    halt_prob: float = 0.05  # chance that an off-original state halts
    covariance: bool = False  # give every state a P (for the monitor)
    tree: bool = False  # no sharing: every transition enters a fresh state
    integer_values: bool = False  # small integers: exact float sums, many ties


def random_lts(cfg: RandomModelConfig, seed: int) -> LTS:
    """Draw a valid model from ``cfg`` with a numpy generator seeded by ``seed``."""
    rng = np.random.default_rng(seed)
    states: list[State] = []
    trans: list[Transition] = []
    counter = iter(range(1 << 62))

    def new_state(step: int, halted: bool = False) -> str:
        sid = f"q{next(counter)}"
        s = _values(rng, cfg.dim, cfg.integer_values, scale=10.0 * (step + 1))
        P = None
        if cfg.covariance:
            a = rng.normal(size=(cfg.dim, cfg.dim))
            P = a @ a.T + np.eye(cfg.dim) * float(rng.uniform(0.5, 5.0))
        labels = frozenset({HALTED}) if halted else frozenset()
        states.append(State(sid, step, s, P, labels))
        return sid

    root = new_state(0)
    original = [root]
    layer = [root]
    for k in range(1, cfg.steps + 1):
        shared = [] if cfg.tree else [new_state(k) for _ in range(max(cfg.width, 1))]
        nxt: list[str] = []
        for src in layer:
            if src != original[-1] and rng.random() < cfg.halt_prob:
                _halt(states, src)
                continue
            deg = int(rng.integers(cfg.branching[0], cfg.branching[1] + 1))
            if cfg.tree:
                targets = [new_state(k) for _ in range(deg)]
            else:
                pick = rng.choice(len(shared), size=min(deg, len(shared)), replace=False)
                targets = [shared[i] for i in pick]
            ranks = _ranks(rng, len(targets))
            for dst, r in zip(targets, ranks, strict=True):
                payoff = _values(rng, 1, cfg.integer_values, scale=5.0)[0]
                trans.append(Transition(src, dst, float(payoff), int(r), f"d{len(trans)}"))
            if src == original[-1]:
                original.append(targets[int(np.argmin(ranks))])
            nxt.extend(targets)
        # unreached shared states are dropped so every state is reachable
        reached = set(nxt)
        keep = {st.id for st in states if st.step != k or st.id in reached}
        states[:] = [st for st in states if st.id in keep]
        layer = list(dict.fromkeys(nxt))
    return LTS.from_parts(states, trans, root, original, [f"c{i}" for i in range(cfg.dim)])


def _halt(states: list[State], sid: str) -> None:
    i = next(j for j, st in enumerate(states) if st.id == sid)
    st = states[i]
    states[i] = State(st.id, st.step, st.s, st.P, st.labels | {HALTED})


def _ranks(rng: np.random.Generator, n: int) -> list[int]:
    """A unique minimum (rank 0) and ranks 1..n−1 with some ties among them."""
    if n == 1:
        return [0]
    rest = sorted(int(x) for x in rng.integers(1, n, size=n - 1))
    ranks = [0, *rest]
    rng.shuffle(ranks)
    return ranks


def _values(rng: np.random.Generator, n: int, integer: bool, scale: float) -> np.ndarray:
    if integer:
        return rng.integers(0, int(scale) + 1, size=n).astype(float)
    return np.round(rng.uniform(0.0, scale, size=n), 3)
