"""Injection candidates for one pedestrian of a MOT det.txt: a modelling device (issue 61).

The hijacking attack (Jia et al., ICLR 2020) erases the target's true box and fabricates
a shifted one, frame after frame, until the track follows the fake. A det.txt of real
detections has no such boxes, so this script makes them: in every frame where a
detection overlaps the ground-truth box of ``TRACK`` (IoU >= 0.5, the largest), that
detection is the target's; it gets payoff 1 and, as injection candidates, copies of
its box shifted sideways by each fraction of its width in ``--shifts`` (default 0.3
and 0.6 to the right), each of payoff 1. Every other detection is unattackable
(payoff inf): the attacker touches the target only, as the hijacking attack does.

The output is a det.txt whose column 7 (conf) is 1 for detections and 0 for candidates,
column 8 the candidates' price and column 9 the detections' payoff, for

    lesmc import mot OUT --payoff-column 9 --inject-column 8 --threshold 0.5 ...

The shifted boxes are not detector output: they stand for what an attacker could make a
detector report, at a declared unit price, and the results that use them say so
(docs/results.md, "Attacks that inject").

Usage: python examples/shifted_candidates.py DET GT TRACK OUT [--shifts 0.3,0.6]
Prints the target's first frame and its detection's centre (``X,Y@FRAME`` for --target).
"""

from __future__ import annotations

import argparse

import numpy as np


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boxes [left, top, width, height]."""
    w = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def _line(frame: int, box: np.ndarray, conf: float, price: str, payoff: str) -> str:
    left, top, w, h = (repr(float(v)) for v in box)
    return f"{frame},-1,{left},{top},{w},{h},{conf:g},{price},{payoff},-1"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("det")
    ap.add_argument("gt")
    ap.add_argument("track", type=int)
    ap.add_argument("out")
    ap.add_argument("--shifts", default="0.3,0.6", help="fractions of the box's width")
    args = ap.parse_args()
    shifts = [float(s) for s in args.shifts.split(",")]
    det = np.loadtxt(args.det, delimiter=",", ndmin=2)
    gt = np.loadtxt(args.gt, delimiter=",", ndmin=2)
    truth = {int(r[0]): r[2:6] for r in gt if int(r[1]) == args.track}
    lines, first = [], None
    for f in sorted({int(r[0]) for r in det}):
        rows = [r[2:6] for r in det if int(r[0]) == f]
        score = [_iou(b, truth[f]) if f in truth else 0.0 for b in rows]
        mine = int(np.argmax(score)) if score and max(score) >= 0.5 else -1
        for i, b in enumerate(rows):
            lines.append(_line(f, b, 1, "-1", "1" if i == mine else "inf"))
            if i != mine:
                continue
            if first is None:
                first = (f, b[0] + b[2] / 2, b[1] + b[3] / 2)
            for s in shifts:
                moved = b + np.array([s * b[2], 0.0, 0.0, 0.0])
                lines.append(_line(f, moved, 0, "1", "-1"))
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    if first is None:
        raise SystemExit(f"track {args.track}: no detection overlaps it (IoU >= 0.5)")
    print(f"{float(first[1])!r},{float(first[2])!r}@{first[0]}")


if __name__ == "__main__":
    main()
