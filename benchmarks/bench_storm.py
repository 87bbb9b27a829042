"""Benchmark: lesmc's engines against Storm on the same model, the same optimum (issue 31).

The dense scene of bench_unfold.py (a target in a platoon among 40 vehicles) is built
for attack windows 4..7, 4..8 (and ``--big``: 4..9, 1.5 M states); the robustness
property (minimise the payoff so that the summed deviation exceeds 120 px) is checked
by each lesmc engine on the built model (``check_bound``: the engine's seconds, the
model's loading excluded) and, exported as an MDP (``lesmc export --format drn``,
docs/export.md), by Storm's ``Rmin=? [F "violated"]`` (``stormpy.model_checking``:
Storm's model building excluded). Best of ``--repeat`` runs each, alternately; the
optima must be equal.

Run ``python benchmarks/bench_storm.py [--repeat 5] [--big]`` (stormpy: the test extra).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_unfold import dense_scene

from lesmc.engines.check import bind_all, check_bound
from lesmc.language.parser import parse_spec
from lesmc.model.lts_binary import save_lts_npz
from lesmc.unfold.unfold import build_model

SPEC = """property robust {{
    attack window {l}..{u}
    minimize payoff
    subject to dist.sum(0..end) > 120
    holds if optimum > 3
    on x, y
}}
"""
ENGINES = ("levels", "bnb", "enumerate")


def storm_seconds(drn: Path, repeat: int) -> tuple[float, float, float, int]:
    """Storm's build seconds (once), best model-checking seconds, the optimum, MDP states."""
    import stormpy

    t0 = time.perf_counter()
    model = stormpy.build_model_from_drn(str(drn))
    built = time.perf_counter() - t0
    prop = stormpy.parse_properties('Rmin=? [F "violated"]')[0]
    best, value = float("inf"), float("nan")
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = stormpy.model_checking(model, prop)
        best = min(best, time.perf_counter() - t0)
        value = float(res.get_value(model.initial_states[0]))
    return built, best, value, int(model.nr_states)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--big", action="store_true", help="also window 4..9 (1.5 M states)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    scene = dense_scene(40, 20, seed=1)
    table = Table(title=f"engine seconds, best of {args.repeat} (model loading excluded)")
    for col in ("window", "states", "Storm check", *ENGINES, "best lesmc / Storm", "optimum"):
        table.add_column(col)
    windows = [(4, 7), (4, 8)] + ([(4, 9)] if args.big else [])
    for l, u in windows:
        cm = build_model(scene, (l, u))
        text = SPEC.format(l=l, u=u)
        bp = bind_all(cm, [parse_spec(text)])[0]
        npz, spec, drn = tmp / f"m{u}.npz", tmp / f"p{u}.spec", tmp / f"m{u}.drn"
        save_lts_npz(cm, npz)
        spec.write_text(text)
        subprocess.run(
            [sys.executable, "-m", "lesmc", "export", str(npz), "--format", "drn", "--spec",
             str(spec), "--max-nodes", "10000000", "-o", str(drn)],
            check=True, capture_output=True,
        )  # fmt: skip
        _, storm, value, _ = storm_seconds(drn, args.repeat)
        secs: dict[str, float] = {}
        optima = {value}
        for _ in range(args.repeat):
            for engine in ENGINES:
                r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
                secs[engine] = min(secs.get(engine, float("inf")), r.stats.seconds)
                optima.add(r.optimum if r.optimum is not None else float("inf"))
        best = min(secs.values())
        table.add_row(
            f"{l}..{u}",
            f"{cm.n_states:,}",
            f"{storm:.4f}",
            *(f"{secs[e]:.4f}" for e in ENGINES),
            f"{best / storm:.2f}x",
            f"{value:.6g}" + ("" if len(optima) == 1 else f" DIFFER {sorted(optima)}"),
        )
    Console().print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
