"""A campaign's targets: the truth's vehicles ranked as ``lesmc verify`` ranks them, the
scene's own when it has no truth, and a targets file's (lesmc campaign --targets).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lesmc.campaign.run import Prepared, least_frames
from lesmc.common.errors import InputError, Location, UsageError
from lesmc.common.files import read_text
from lesmc.designs.registry import BASELINE
from lesmc.perception.quality import load_truth
from lesmc.scene import Scene
from lesmc.tracking.targets import (
    AutoTarget,
    TargetSpec,
    initiated_targets,
    parse_target,
    place_target,
    rounded,
)
from lesmc.unfold.unfold import max_end, original_end


def truth_targets(p: Prepared, window: tuple[int, int], horizon: int) -> list[AutoTarget]:
    """Vehicles of the truth ranked as lesmc verify ranks them (``rank_targets``), starting at
    each frame that leaves ``horizon`` steps, each vehicle once (at its earliest start), kept
    when the unattacked plain tracker, started on it from the scene, follows it through
    ``horizon``. Most neighbouring traffic first; ties by frame, then vehicle id."""
    from lesmc.experiment.targets import rank_targets
    from lesmc.video.reader import open_frames

    assert p.video.truth is not None
    truth = load_truth(str(p.video.truth))
    frames = open_frames(p.video.frames_dir, least_frames(p.footage.meta), check=False)
    first = p.footage.frames[0].step
    tfs = [truth.frames.get(f.name) for f in frames.paths[first : p.footage.last_step + 1]]
    found: list[tuple[int, int, int, AutoTarget]] = []
    seen: set[int] = set()
    for s in range(first, p.footage.last_step - horizon + 1):
        window_s = tfs[s - first :]
        if any(tf is None for tf in window_s):
            break
        ranked = rank_targets(window_s, (frames.width, frames.height), (window[0], horizon - 1))  # type: ignore[arg-type]
        for c in ranked:
            if c.vid in seen:
                continue
            spec = rounded(c.spec.x, c.spec.y, s)
            try:
                scene = place_target(p.footage, spec)
            except UsageError:
                continue  # no detection of it in the gate: the detector missed it
            if _lasts_and_follows(scene, horizon, c.truth_track[: horizon + 1]):
                seen.add(c.vid)
                origin = f"vehicle {c.vid} of the truth, from frame {s}"
                found.append((-c.crowd, s, c.vid, AutoTarget(spec, c.crowd, origin)))
    found.sort(key=lambda f: f[:3])
    return [f[3] for f in found]


def _lasts_and_follows(scene: Scene, horizon: int, truth_track: np.ndarray) -> bool:
    """:func:`_lasts` and ``follows`` (lesmc/experiment/targets.py): the scene's unattacked track
    runs through ``horizon`` and the plain tracker's stays on the vehicle of ``truth_track``.
    With the plain tracker as the scene's, both read one unattacked track."""
    from lesmc.experiment.targets import baseline_track, follows, on_vehicle

    if scene.tracker.design != BASELINE:
        return _lasts(scene, horizon) and follows(scene, truth_track)
    if horizon > max_end(scene):  # the frames end before
        return False
    run = baseline_track(scene, horizon)  # truth_track has at most horizon + 1 steps
    return len(run) > horizon and on_vehicle(scene, run, truth_track)


def _lasts(scene: Scene, horizon: int) -> bool:
    """Whether the unattacked track runs through step ``horizon``, unfolded that far only
    (not to the end of the scene's frames)."""
    try:
        return original_end(scene, end=horizon) >= horizon
    except UsageError:  # it halts before, or the scene's frames end before
        return False


def auto_targets(p: Prepared, windows: list[tuple[int, int]], use_truth: bool) -> list[AutoTarget]:
    """Ranked automatic targets: from the truth when there is one, else initiated tracks."""

    lo = min(w[0] for w in windows)
    hi = max(w[1] for w in windows)
    horizon = hi + 1  # one step after the last window, to see a recovery
    if use_truth and p.video.truth is not None:
        return truth_targets(p, (lo, hi), horizon)
    return initiated_targets(p.footage, horizon, (lo, hi))


def file_targets(path: Path, videos: list[str]) -> dict[str, list[tuple[TargetSpec, Location]]]:
    """``--targets FILE``: one ``X,Y@STEP`` per line (``VIDEO X,Y@STEP`` with several videos);
    blank lines and ``#`` comments are skipped."""

    text = read_text(path)
    out: dict[str, list[tuple[TargetSpec, Location]]] = {v: [] for v in videos}
    for n, raw in enumerate(text.split("\n"), start=1):  # lines end at \n only
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = Location(str(path), n, raw.index(line[0]) + 1)
        parts = line.split()
        if len(videos) > 1 and len(parts) != 2:
            raise InputError("with several videos a line is 'VIDEO X,Y@STEP'", where)
        name, text_t = (parts[0], parts[1]) if len(parts) == 2 else (videos[0], parts[0])
        if len(parts) > 2:
            form = "VIDEO X,Y@STEP" if len(videos) > 1 else "X,Y@STEP (or VIDEO X,Y@STEP)"
            raise InputError(f"a line is '{form}', got {len(parts)} fields", where)
        if name not in out:
            raise InputError(f"unknown video '{name}' (videos: {', '.join(videos)})", where)
        try:
            spec = parse_target(text_t)
        except UsageError as exc:
            raise InputError(exc.message, where) from None
        if spec.step is None:
            raise InputError("give the target's frame: X,Y@STEP", where)
        out[name].append((spec, where))
    if not any(out.values()):
        raise InputError("no targets: every line is blank or a comment", Location(str(path)))
    return out


def check_file_target(
    p: Prepared, spec: TargetSpec, where: Location, windows: list[tuple[int, int]]
) -> None:
    """A file's target must be in the gate of a detection and tracked past every window."""

    try:
        scene = place_target(p.footage, spec)
    except UsageError as exc:
        raise InputError(exc.message, where) from None
    e = original_end(scene)
    hi = max(w[1] for w in windows)
    if e < hi:
        raise InputError(
            f"the unattacked track of {spec.text()} ends at step {e}, before the last "
            f"window's step {hi}",
            where,
        )
