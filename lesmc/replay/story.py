"""A frame's attack in words, as a replay reports it (lesmc/replay/run.py for the point
designs, lesmc/replay/multi.py for the multi-target ones): which hidden detections the
perturbed frame still has and why (overlapping 21x21 windows), which detections were lost,
moved or added, which injected candidates came out or not, and the rounds of the repaired
attack (lesmc/replay/perturbed.py ``repair_frame``)."""

from __future__ import annotations

from lesmc.replay.case import FrameAttack


def frame_story(fa: FrameAttack) -> str:
    """What the perturbations did to one frame's detections, in words."""
    parts = []
    if fa.still:
        ov = sorted({b for a, b in fa.overlaps if a in fa.still})
        parts.append(
            f"hidden detection{'s' if len(fa.still) > 1 else ''} {', '.join(fa.still)} still "
            "detected with all perturbations of the frame applied"
            + (f" (21x21 windows overlap {', '.join(ov)})" if ov else "")
        )
    if fa.shared:
        parts.append(
            f"detection{'s' if len(fa.shared) > 1 else ''} {', '.join(fa.shared)} lost as well: "
            "N_lp found it in the same Q_dr blob as a hidden detection, and hiding that blob's "
            "N_dr window hides both (the model prices them as separate attacks)"
        )
    other = [d for d in fa.lost if d not in fa.shared]
    if other:
        parts.append(
            f"detection{'s' if len(other) > 1 else ''} {', '.join(other)} lost as well "
            "(overlapping windows interact)"
        )
    moved = [(d, e) for d, e in fa.moved if e > 0.05]
    if moved:
        parts.append(
            "detection"
            + ("s " if len(moved) > 1 else " ")
            + ", ".join(f"{d} moved {e:.2f} px" for d, e in moved[:4])
            + (f" and {len(moved) - 4} more" if len(moved) > 4 else "")
        )
    if fa.extra:
        parts.append(
            "extra detection"
            + ("s " if len(fa.extra) > 1 else " ")
            + ", ".join(f"({x:.1f}, {y:.1f})" for x, y in fa.extra)
        )
    if fa.injected:
        parts.append(
            f"injected {', '.join(fa.injected)} (perturbed until the detector reports it: "
            "its N_dr window towards vehicle, a heatmap cell above the threshold)"
        )
    if fa.not_injected:
        parts.append(_not_injected(fa))
    if fa.repaired_rounds:
        parts.append(f"after {fa.repaired_rounds} round(s) of the repaired joint attack")
    return "; ".join(parts)


def _not_injected(fa: FrameAttack) -> str:
    """The injected candidates not detected, in words: the hidden detections whose windows
    overlap theirs, and those whose blob the perturbed frame no longer has."""
    ov = sorted({a for a, b in fa.overlaps if b in fa.not_injected})
    gone = ", ".join(fa.no_blob)
    return (
        f"injected {', '.join(fa.not_injected)} not detected after all"
        + (f" (21x21 windows overlap {', '.join(ov)})" if ov else "")
        + (f": no blob of the perturbed frame within 1 px of {gone} to attack" if gone else "")
    )
