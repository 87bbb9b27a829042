"""How often the runtime monitor fires without an attack: its false-alarm rate.

The monitor of section 7.1 (Eq. 12-13) flags a track when its uncertainty τ
rises. A detector that misses a vehicle now and then makes τ rise with no
attack at all; then the monitor also flags unattacked tracks, and a property
checked under it "holds" vacuously. This module runs the unattacked tracker
from every vehicle of the truth (the video's truth tracks) and counts the
steps at which Eq. 13 fires, for the default tolerance and for a tolerance
calibrated on these tracks (the largest relative rise of τ they show, the
smallest tolerance that keeps them all silent).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lesmc.language.properties import DEFAULT_MONITOR_TOLERANCE
from lesmc.model.kernel import alarm, tau
from lesmc.perception.quality import TruthFrame
from lesmc.scene import Scene, Target
from lesmc.tracking.design import Batch
from lesmc.tracking.trackers import make_tracker


@dataclass(frozen=True)
class TruthStart:
    """A truth vehicle where a track may start: id, position and velocity (frame px, px/s)."""

    vid: int
    x: float
    y: float
    vx: float
    vy: float


def truth_starts(
    tf: TruthFrame, size: tuple[int, int], margin: float = 150.0, min_speed: float = 5.0
) -> list[TruthStart]:
    """The moving, visible vehicles of a truth frame away from its border."""
    out = []
    for j, vid in enumerate(tf.ids):
        x, y = tf.positions[j]
        if tf.occluded[j] or tf.speed_mps[j] < min_speed:
            continue
        if not (margin <= x <= size[0] - margin and margin <= y <= size[1] - margin):
            continue
        v = tf.velocity[j] if tf.velocity is not None else np.zeros(2)
        out.append(TruthStart(vid, float(x), float(y), float(v[0]), float(v[1])))
    return out


def truth_track(
    frames: Sequence[TruthFrame], start: tuple[float, float], snap: float = 6.0
) -> list[list[float] | None]:
    """The true positions, per step, of the vehicle nearest ``start`` in ``frames[0]``.

    None at steps where the vehicle is not in the truth; [] when none is within ``snap`` px.
    """
    tf0 = frames[0]
    if not len(tf0.positions):
        return []
    d = np.linalg.norm(tf0.positions - np.asarray(start), axis=1)
    j = int(np.argmin(d))
    if d[j] > snap:
        return []
    vid = tf0.ids[j]
    out: list[list[float] | None] = []
    for tf in frames:
        if vid in tf.ids:
            x, y = tf.positions[tf.ids.index(vid)]
            out.append([float(x), float(y)])
        else:
            out.append(None)
    return out


def unattacked_taus(
    scene: Scene, starts: Sequence[TruthStart], design: str, steps: int
) -> list[np.ndarray]:
    """τ along the unattacked track (Eq. 12) started at each truth vehicle, up to ``steps``
    (until it halts): the τ of :func:`unattacked_tracks`."""
    return [t.tau for t in unattacked_tracks(scene, starts, design, steps)]


@dataclass(frozen=True)
class Series:
    """One unattacked track as a monitor reads it: τ (Eq. 12) at steps 0..n and the NIS of
    the update entering each step (NaN: none; at step 0 and for a design that reports
    none); and where it was (``lesmc tune``'s tracking error against the truth)."""

    tau: np.ndarray
    nis: np.ndarray
    #: the track's position (the measured components of the state) at steps 0..n, (n+1, 2)
    xy: np.ndarray


def unattacked_tracks(
    scene: Scene, starts: Sequence[TruthStart], design: str, steps: int
) -> list[Series]:
    """τ and the NIS along the unattacked track started at each truth vehicle, up to
    ``steps`` (until it halts).

    All tracks run in one batch through one tracker (the design computes the successors
    of a batch at once, tracking/design.py): each starts where ``track`` of a scene with
    that vehicle as its target would, and takes the same unattacked outcome at every
    step (tests/test_false_alarms.py compares with ``track`` vehicle by vehicle)."""
    if not starts:
        return []
    base = scene.with_tracker(design=design)
    tracker = make_tracker(base)
    firsts = []
    for s in starts:  # each vehicle's first state: the design starts from its scene's target
        tracker.scene = dataclasses.replace(
            base, target=Target(base.target.step, (s.x, s.y), (s.vx, s.vy))
        )
        firsts.append(tracker.initial())
    tracker.scene = base
    batch = _stacked(firsts)
    loc = base.tracker.measured
    taus = [[float(tau(tracker.covariances[int(c)], loc))] for c in batch.cov]
    xys = [[batch.X[i, list(loc)].tolist()] for i in range(len(batch))]
    nis: list[list[float]] = [[math.nan] for _ in batch.cov]
    live = np.flatnonzero(~batch.halted)  # the starts still tracked; ``batch`` holds them
    batch = batch.take(live)
    last = min(steps, base.last_step - base.target.step)
    for k in range(1, last + 1):
        if not live.size:
            break
        succ = tracker.successors(batch, base.target.step + k, False)
        batch = succ.states
        got = succ.nis.tolist() if succ.nis is not None else [math.nan] * len(live)
        for j, (i, c, v) in enumerate(zip(live.tolist(), batch.cov.tolist(), got, strict=True)):
            taus[i].append(float(tau(tracker.covariances[int(c)], loc)))
            nis[i].append(float(v))
            xys[i].append(batch.X[j, list(loc)].tolist())
        keep = ~batch.halted
        live, batch = live[keep], batch.take(np.flatnonzero(keep))
    return [
        Series(np.array(t), np.array(n), np.array(p, dtype=float).reshape(-1, 2))
        for t, n, p in zip(taus, nis, xys, strict=True)
    ]


def _stacked(batches: list[Batch]) -> Batch:
    """One batch of the states of ``batches`` (of one design), in order."""
    store = None
    if batches[0].objects is not None:
        store = batches[0].objects.store()
        for b in batches:
            assert b.objects is not None
            store.extend(b.objects)
    n = sum(len(b) for b in batches)
    return Batch(
        np.concatenate([b.X for b in batches]),
        np.concatenate([b.cov for b in batches]),
        np.concatenate([b.halted for b in batches]),
        None if store is None else store.take(np.arange(n)),
    )


def rates(taus: Sequence[np.ndarray], tolerance: float, first: int = 1) -> dict[str, int]:
    """Alarms (Eq. 13) over steps ``first``.. of every track, and tracks with at least one."""
    steps = alarms = alarmed = 0
    for t in taus:
        if len(t) <= first:
            continue
        fired = alarm(t[first - 1 : -1], t[first:], tolerance)
        steps += int(fired.size)
        alarms += int(fired.sum())
        alarmed += int(fired.any())
    n = sum(1 for t in taus if len(t) > first)
    return {"tracks": n, "steps": steps, "alarms": alarms, "tracks_alarmed": alarmed}


def calibrated_tolerance(taus: Sequence[np.ndarray], rate: float = 0.0, first: int = 1) -> float:
    """The least tolerance under which at most ``rate`` of the steps raise an alarm.

    ``rate`` 0 gives the largest relative rise of τ over the tracks (all silent);
    0.01 the 99th percentile of the rises (one step in a hundred alarms).
    """
    rises = np.concatenate(
        [t[first:] / t[first - 1 : -1] - 1.0 for t in taus if len(t) > first] or [np.zeros(0)]
    )
    if not rises.size:
        return 0.0
    return max(float(np.quantile(rises, 1.0 - rate, method="higher")), 0.0)


def false_alarm_report(
    scene: Scene,
    frames: Sequence[TruthFrame],
    size: tuple[int, int],
    steps: int,
    designs: Sequence[str],
    first: int = 1,
) -> dict[str, Any]:
    """The monitor's false alarms on the video's truth tracks, for the results file."""
    starts = truth_starts(frames[0], size)
    rows = []
    for design in designs:
        taus = unattacked_taus(scene, starts, design, steps)
        default = DEFAULT_MONITOR_TOLERANCE
        one = calibrated_tolerance(taus, 0.01, first)
        none = calibrated_tolerance(taus, 0.0, first)
        for label, tol in (
            (f"{design}: Eq. 13, tolerance {default:g} (default)", default),
            (f"{design}: tolerance {one:.4g} (calibrated: 99th percentile of the rises)", one),
            (f"{design}: tolerance {none:.4g} (calibrated: the largest rise)", none),
        ):
            row = {"monitor": label, "design": design, "tolerance": tol}
            rows.append(row | rates(taus, tol, first))
    return {
        "what": (
            f"The unattacked tracker started at each of the {len(starts)} moving, visible "
            f"vehicles of the truth in the target's frame {scene.target.step} (its true "
            f"position and velocity), run for up to {steps} steps; alarms counted at steps "
            f"{first}..{steps} as Eq. 13 defines them. Every alarm here is a false alarm: "
            "nothing is attacked. The calibrated tolerances are measured on the same tracks, "
            "not held out. 'except original' "
            "(docs/language.md) is not a runtime monitor: it needs the unattacked track, "
            "which the checker knows and a deployed tracker does not."
        ),
        "rows": rows,
    }
