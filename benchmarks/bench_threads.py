"""Certified bounds on a busy machine: torch threads fitted to the free cores vs torch's default.

    python benchmarks/bench_threads.py [--n 64] [--frames 8]

Side by side in one run, on the same ``--n`` attacked N_dr windows of the
default video (benchmarks/bench_certify.py's sample): certification in a fresh
process (1) on the idle machine with fitted threads, (2) beside one CPU-bound
process with torch's default (one thread per core, ``LESMC_THREADS`` = cores),
(3) beside the same process with fitted threads (lesmc/perception/threads.py).
Prints wall seconds and the ratios busy/idle: spin-waiting threads make (2)
several times (1); the target is (3) at most 2x (1).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

CHILD = """
import sys, time
sys.path.insert(0, {bench!r})
import numpy as np
from bench_certify import sample_windows
from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import payoffs
from lesmc.perception.certify import CertifyConfig, certified_radius, detect_chain
from lesmc.perception.cnn import load_nets
import torch
nets = load_nets()
w = sample_windows(nets, {frames}, {n})
pay = payoffs(nets.dr, w, nets.settings.delta_dr, AttackConfig()).payoff
chain = detect_chain(nets.dr, threshold_logit(nets.settings.delta_dr))
t0 = time.perf_counter()
cert = certified_radius(chain, w, pay, CertifyConfig())
secs, used = time.perf_counter() - t0, torch.get_num_threads()
print(f"RESULT {{secs:.3f}} {{used}} {{float(np.nansum(cert)):.9g}}")
"""


def _spin(stop: float) -> None:
    while time.monotonic() < stop:
        pass


def run(frames: int, n: int, threads: str | None, busy: bool) -> tuple[float, int, str]:
    env = dict(os.environ)
    env.pop("LESMC_THREADS", None)
    if threads is not None:
        env["LESMC_THREADS"] = threads
    hog = None
    if busy:
        hog = mp.Process(target=_spin, args=(time.monotonic() + 3600,), daemon=True)
        hog.start()
        time.sleep(1.0)
    try:
        code = CHILD.format(bench=str(Path(__file__).parent), frames=frames, n=n)
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        ).stdout
    finally:
        if hog is not None:
            hog.terminate()
            hog.join()
    line = next(x for x in out.splitlines() if x.startswith("RESULT"))
    _, secs, used, total = line.split()
    return float(secs), int(used), total


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--n", type=int, default=64)
    args = ap.parse_args()
    cores = str(len(os.sched_getaffinity(0)))
    print(f"{cores} cores; load average {os.getloadavg()[0]:.1f}")
    rows = [
        ("idle, fitted threads", None, False),
        ("busy, torch default threads", cores, True),
        ("busy, fitted threads", None, True),
    ]
    got = {}
    for name, threads, busy in rows:
        got[name] = run(args.frames, args.n, threads, busy)
        secs, used, total = got[name]
        print(f"{name:30s} {secs:8.2f} s  ({used} threads; sum of bounds {total})")
    idle = got["idle, fitted threads"][0]
    for name in ("busy, torch default threads", "busy, fitted threads"):
        print(f"{name:30s} {got[name][0] / idle:6.2f}x idle")
    bounds = {v[2] for v in got.values()}
    print("bounds equal in every run:", len(bounds) == 1)


if __name__ == "__main__":
    main()
