"""Benchmark: ``lesmc tune`` over 50 designs against 50 separate ``lesmc check`` runs.

Row of docs/performance.md (issue 59): on the default video's scene, ``lesmc tune`` over
a space of 50 designs (2 trackers x 5 gates x 5 monitors: 10 tracker configurations)
should take at most 0.3x the summed wall time of checking the 50 designs one by one
with ``lesmc check SCENE --design D --tracker T`` (one process each), through model
reuse (a group's monitors share one model) and one process; and ``--workers 2``
(a Dask LocalCluster, start-up included) is timed beside them. All runs are side by
side in one session, and every design's verdicts and optima are compared between
``tune`` and the separate checks (they must agree).

The scene is ``lesmc verify --price-all``'s OUT/scene.json (every detection priced, so
that any gate can read any payoff without the networks), made once when absent.

Run ``python benchmarks/bench_tune.py [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPECS = [str(ROOT / "specs" / "robustness.spec"), str(ROOT / "specs" / "resilience.spec")]
SPACE = """design = ["single", "joint"]
gate = [1.5, 2.0, 2.5, 3.0, 4.0]
[monitor]
none = true
tau_rise = [1e-9, 1.577]
nis = [0.8]
trace = [200.0]
"""


def lesmc(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m lesmc ARGS`` with this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "lesmc", *args], capture_output=True, text=True, env=env
    )


def timed(*args: str) -> tuple[float, subprocess.CompletedProcess[str]]:
    t0 = time.perf_counter()
    r = lesmc(*args)
    if r.returncode not in (0, 1):
        raise SystemExit(f"lesmc {' '.join(args)} failed ({r.returncode}):\n{r.stderr}")
    return time.perf_counter() - t0, r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lesmc-bench-tune"))
    args = ap.parse_args()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    scene = out / "verify" / "scene.json"
    if not scene.is_file():
        print("making the scene: lesmc verify --price-all", file=sys.stderr)
        lesmc("verify", "--price-all", "--out", str(out / "verify"))
    space = out / "space.toml"
    space.write_text(SPACE)

    t_tune, r = timed("tune", str(scene), *SPECS, "--space", str(space), "--json")
    doc = json.loads(r.stdout)
    t_dask, r2 = timed(
        "tune", str(scene), *SPECS, "--space", str(space), "--workers", "2", "--json"
    )
    assert json.loads(r2.stdout)["designs"] == doc["designs"]

    t_checks = 0.0
    for d in doc["designs"]:
        t = out / f"t{d['id']}.toml"
        lines = [f"{k} = {v!r}" for k, v in d["parameters"].items()]
        lines.append(f'design = "{d["tracker"]}"')
        if d["monitor"] is not None:
            lines.append(f'monitor = "{d["monitor"]["kind"]} {d["monitor"]["parameter"]!r}"')
        t.write_text("\n".join(lines) + "\n")
        dt, c = timed(
            "check", str(scene), *SPECS, "--design", d["check_design"], "--tracker", str(t),
            "--json",
        )  # fmt: skip
        t_checks += dt
        got = [(x["verdict"], x["optimum"], x["vacuous"]) for x in json.loads(c.stdout)["results"]]
        want = [(x["verdict"], x["optimum"], x["vacuous"]) for x in d["results"]]
        assert got == want, (d["label"], got, want)

    n = len(doc["designs"])
    print(f"{n} designs on {scene} (the default video's scene, every payoff priced)")
    print(f"  lesmc tune, one process          {t_tune:8.1f} s")
    print(f"  lesmc tune --workers 2           {t_dask:8.1f} s")
    print(f"  {n} x lesmc check, summed         {t_checks:8.1f} s")
    print(f"  tune / checks                    {t_tune / t_checks:8.2f}x (target <= 0.3x)")
    print(f"  tune --workers 2 / checks        {t_dask / t_checks:8.2f}x")
    print("  every design's verdicts and optima agree")


if __name__ == "__main__":
    main()
