"""Why seed 3's joint injection attack needs the repair that re-injects (docs/results.md,
"Attacks that inject"; it diverged in round 22, before the repair re-injected): frame
12's attack (hide 12:45, inject 12:c386) run as the replay runs it
(lesmc/replay/inject.py ``attack_listed``), together and the injection alone, each with
and without the repair round; for each, whether the candidate is detected (within 1 px),
how far the nearest detection is from the candidate and from 12:45, and the repair's
rounds and cost.

DIR holds bench_inject_video.py's ``scene3.json`` (``--within 30``, every candidate)
and its video ``v3``.

Usage: PYTHONPATH=. python benchmarks/why_inject_seed3.py DIR [HIDE INJECT STEP]
(default 12:45 12:c386 8, joint's attack; 11:51 11:c398 7 is single's first attacked
frame, whose candidate's blob the perturbations move: ``no blob``)
"""

from __future__ import annotations

import os
import sys
from typing import Any

import numpy as np


def main(where: str, hide: str = "12:45", inject: str = "12:c386", step: int = 8) -> None:
    from lesmc.perception.attack_settings import attack_of
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.detector import Detector, DetectorConfig
    from lesmc.replay import run as single
    from lesmc.replay.inject import attack_listed, candidate_at
    from lesmc.results.read import HiddenDoc
    from lesmc.scene.io import load_scene
    from lesmc.video.reader import open_frames

    os.chdir(where)
    scene = load_scene("scene3.json")
    fe = single.frontend_settings(4, 12)
    nets = load_nets(None, None, None)
    cfg = attack_of(dict(scene.meta), "scene3.json")
    frame = int(hide.split(":")[0])
    fr = next(f for f in scene.frames if f.step == frame)
    h = next(d for d in fr.detections if d.id == hide)
    c = next(d for d in fr.candidates if d.id == inject)
    print(f"hide {hide} at ({h.x:.1f}, {h.y:.1f}), payoff {h.payoff:.4f}; "
          f"inject {inject} at ({c.x:.1f}, {c.y:.1f}), payoff {c.payoff:.4f}")  # fmt: skip

    def attack(det: Any, out: Any, fd: Any) -> None:
        row = candidate_at(fd, out, inject)
        hid = [HiddenDoc(step, frame, hide, h.x, h.y, h.payoff)]
        ways = [("together", hid, True), ("together, no repair", hid, False),
                ("inject alone", [], True), ("inject alone, no repair", [], False)]  # fmt: skip
        for name, hh, rep in ways:
            fa = attack_listed(nets, det, (out, fd), step, (hh, [(inject, row)]), cfg, repair=rep)
            pos = fa.detections.positions
            d = np.hypot(pos[:, 0] - c.x, pos[:, 1] - c.y)
            dh = np.hypot(pos[:, 0] - h.x, pos[:, 1] - h.y)
            print(f"{name}: not detected {fa.not_injected} (no blob: {fa.no_blob}); nearest "
                  f"detection to the candidate {d.min():.2f} px, to {hide} {dh.min():.2f} px; "
                  "repair rounds "
                  f"{fa.repaired_rounds}, cost {fa.extra_cost:.4f}")  # fmt: skip

    single.detect_attacked_frames(
        open_frames("v3", fe.history + 1),
        lambda: Detector(nets, DetectorConfig(frontend=fe)),
        [frame], fe.history, attack, None,
    )  # fmt: skip


if __name__ == "__main__":
    where = sys.argv[1] if len(sys.argv) > 1 else "/tmp/lesmc-inject-video"
    if len(sys.argv) > 2:  # another frame's attack: HIDE INJECT STEP
        main(where, sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        main(where)
