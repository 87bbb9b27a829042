"""Confirms a joint counterexample under ``allow hide, inject`` on a perceived video with
the independent oracle of tests/joint_oracle.py (filterpy filters, the greedy likelihood
scan; written from the paper, not from lesmc/tracking).

Reads a scene and the ``lesmc check --json`` output of one property on it (``--design
joint``, a violated ``dist.sum(0..end) > B`` with ``allow hide, inject``). Walks the
counterexample's outcome ranks with the joint design (``JointDesign.attack_in``: the
detections hidden and the candidates injected by the cheapest way to each attacked
step's outcome), applies those through the oracle tracker, and prints the attack, its
cost (from the scene's payoffs) and the oracle's ``dist.sum`` against its own unattacked
run, beside the check's optimum and bound.

Usage: PYTHONPATH=. python benchmarks/confirm_inject_oracle.py SCENE.json CHECK.json
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main() -> None:
    from joint_oracle import oracle_paths
    from test_inject_joint_listed import Applied, cost_of

    from lesmc import api
    from lesmc.tracking.joint import JointDesign

    scene = api.load_scene(Path(sys.argv[1])).with_tracker(design="joint")
    (r,) = json.loads(Path(sys.argv[2]).read_text())["results"]
    steps = r["counterexample"]["steps"]
    design = JointDesign(scene, inject=True)
    first, batch = scene.target.step, design.initial()
    attack: dict[int, tuple[list[str], list[str]]] = {}
    for s in steps[1:]:
        k, rank = int(s["step"]), int(s["rank"])
        if s["attacked"]:
            attack[k] = design.attack_in(batch, first + k, rank)
        succ = design.successors(batch, first + k, bool(s["attacked"]))
        batch = succ.states.take(np.flatnonzero(succ.rank == rank)[:1])
    end = int(steps[-1]["step"])
    print(f"check: optimum {r['optimum']}, constraint {r['constraint']}, end {end}")
    print("attack (step: hidden, injected):", {k: v for k, v in attack.items() if v != ([], [])})
    original = oracle_paths(scene, (end + 1, end + 1), end)[0][0]
    oracle = Applied(scene)
    st, cost, total = oracle.initial(), 0.0, 0.0
    for k in range(1, end + 1):
        at = first + k
        hid, inj = attack.get(k, ([], []))
        cost += cost_of(scene, at, hid, inj)
        st = oracle.apply(st, at, hid, inj)
        total += math.dist(st.tracks[0][0][:2], original[k][:2])
    bound = float(r["constraint_bound"])
    print(f"oracle: cost {cost:.6g}, dist.sum(0..{end}) {total:.6g} (> {bound:g}: {total > bound})")


if __name__ == "__main__":
    main()
