"""Benchmark and results: hide vs hide + inject on the nearest-neighbour tracker ``single``
(issue 61), on pedestrians drawn at run time (benchmarks/bench_inject_tud.py
``draw_tracks``: TUD-Campus and TUD-Stadtmitte, from ``--seed-base``, printed) with
the shifted candidates of ``examples/shifted_candidates.py`` (a modelling device: the
target's detection payoff 1,
two copies of its box shifted right by 0.3 and 0.6 of its width at price 1 each, every
other detection unattackable), made as benchmarks/bench_inject_tud.py makes them.

Per pedestrian and deviation bound D: ``minimize payoff`` and ``minimize count.frames``
``subject to dist.max(0..end) > D`` in the window 1..4 after the target's first frame
(end 12), once hide-only and once ``allow hide, inject``, with ``--design single``; prints
the optima, the states the model built and the check's wall-clock seconds; at the end the
median and the worst seconds and states of each column.

Usage: PYTHONPATH=. python benchmarks/bench_inject_single.py [--seed-base N] [--instances 3]
[--bounds 5,20,40] [--tracks 1,2 (TUD-Campus pedestrians instead of drawn ones)]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench_inject_tud import _run, _scene, chosen, seed_base, summary

SPEC = """property rob {{ attack window 1..4{allow} minimize payoff
  subject to dist.max(0..end) > {d} holds if optimum > 1000 end 12 }}
property frames {{ attack window 1..4{allow} minimize count.frames
  subject to dist.max(0..end) > {d} holds if optimum > 1000 end 12 }}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed-base", type=int, default=None)
    ap.add_argument("--instances", type=int, default=3)
    ap.add_argument("--tracks", help="TUD-Campus gt tracks (1,2,...) instead of drawn ones")
    ap.add_argument("--bounds", default="5,20,40")
    ap.add_argument("--out", default="/tmp/lesmc-inject-single")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = seed_base(args.seed_base)
    print(f"seed base {base}")
    print("seq track D | hide: payoff frames states s | hide+inject: payoff frames states s")
    cols: dict[str, list[float]] = {}
    for seq, track in chosen(args.tracks, base, args.instances):
        made = _scene(seq, track, out)
        if made is None:
            print(f"{seq} {track}: no detection overlaps the track", flush=True)
            continue
        scene, (target, _, _) = made
        for d in args.bounds.split(","):
            row = [f"{seq} {track} {d}"]
            for allow in ("", " allow hide, inject"):
                spec = out / "p.spec"
                spec.write_text(SPEC.format(allow=allow, d=d))
                t0 = time.perf_counter()
                r = _run(
                    "-m", "lesmc", "check", str(scene), str(spec), "--design", "single",
                    "--target", target, "--json",
                )  # fmt: skip
                secs = time.perf_counter() - t0
                if r.returncode not in (0, 1):
                    raise SystemExit(r.stderr)
                res = {x["property"]: x for x in json.loads(r.stdout)["results"]}
                opt = [res[p]["optimum"] for p in ("rob", "frames")]
                states = res["rob"]["stats"]["states_built"]
                row.append(" ".join(str(o) for o in opt) + f" {states} {secs:.1f}")
                key = "hide+inject" if allow else "hide"
                cols.setdefault(f"{key} seconds", []).append(secs)
                cols.setdefault(f"{key} states", []).append(states)
            print(" | ".join(row), flush=True)
    for label, values in cols.items():
        print(summary(label, values))


if __name__ == "__main__":
    main()
