"""Make examples/mot/det.txt and gt.txt with lesmc itself (run from the repository root).

A synthetic WAMI video (lesmc synth) is perceived (lesmc perceive: the shipped CNNs,
DeepFool payoffs); its detections are written as a MOTChallenge det.txt, with each
detection's payoff in the conf column (7), and the video's truth as gt.txt. Boxes are
12 x 8 pixels centred on the detections (lesmc's detections are points).

    python examples/mot/make_mot.py
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from lesmc.common.files import read_json
from lesmc.scene import footage_from_dict
from lesmc.scene.mot import write_det, write_gt

HERE = Path(__file__).resolve().parent
BOX = (12.0, 8.0)


def lesmc(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "lesmc", *args], check=True)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        video, scene = Path(tmp) / "video", Path(tmp) / "scene.json"
        lesmc("synth", str(video), "--frames", "16", "--size", "512x512", "--density", "3")
        lesmc("perceive", str(video), "-o", str(scene), "--max-iter", "30")
        footage, _ = footage_from_dict(read_json(scene), str(scene))
        write_det(footage, HERE / "det.txt", BOX)
        truth = json.loads((video / "truth.json").read_text())
        rows = [
            (int(v["id"]), int(f["step"]), float(v["x"]), float(v["y"]))
            for f in truth["frames"]
            for v in f["vehicles"]
        ]
        write_gt(sorted(rows), HERE / "gt.txt", BOX)
        print(f"dt = {truth['dt']} s (--fps {1 / truth['dt']:g})")


if __name__ == "__main__":
    main()
