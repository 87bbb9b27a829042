"""Benchmark and results: hide vs hide + inject on the nearest-neighbour tracker ``single``
(issue 61), on TUD-Campus pedestrians with the shifted candidates of
``examples/shifted_candidates.py`` (a modelling device: the target's detection payoff 1,
two copies of its box shifted right by 0.3 and 0.6 of its width at price 1 each, every
other detection unattackable), made as benchmarks/bench_inject_tud.py makes them.

Per pedestrian and deviation bound D: ``minimize payoff`` and ``minimize count.frames``
``subject to dist.max(0..end) > D`` in the window 1..4 after the target's first frame
(end 12), once hide-only and once ``allow hide, inject``, with ``--design single``; prints
the optima, the states the model built and the check's wall-clock seconds.

Usage: PYTHONPATH=. python benchmarks/bench_inject_single.py [--tracks 3,7] [--bounds 5,20,40]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from bench_inject_tud import _run, _scene

SPEC = """property rob {{ attack window 1..4{allow} minimize payoff
  subject to dist.max(0..end) > {d} holds if optimum > 1000 end 12 }}
property frames {{ attack window 1..4{allow} minimize count.frames
  subject to dist.max(0..end) > {d} holds if optimum > 1000 end 12 }}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tracks", default="3,7")
    ap.add_argument("--bounds", default="5,20,40")
    ap.add_argument("--out", default="/tmp/lesmc-inject-single")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print("track D | hide: payoff frames states s | hide+inject: payoff frames states s")
    for track in (int(t) for t in args.tracks.split(",")):
        made = _scene(track, out)
        if made is None:
            continue
        scene, (target, _, _) = made
        for d in args.bounds.split(","):
            row = [f"{track} {d}"]
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
            print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
