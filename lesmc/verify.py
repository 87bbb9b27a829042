"""``verify``: the paper's whole experiment in one call (section 8).

frames -> scene (perception, payoffs) -> model per design -> check every
property -> report. Each stage is the same code as its own verb; this module
only chains them and picks defaults: the embedded synthetic video, a target
with neighbouring traffic, the bundled robustness and resilience specs.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.engines.budget import Budget
from lesmc.engines.check import DEFAULT_MAX_STATES, bind_all, check_bound
from lesmc.engines.result import CheckResult
from lesmc.errors import LesmcError, UsageError
from lesmc.language.parser import load_spec
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import GrowingModel
from lesmc.model.lts import LTS, to_lts
from lesmc.perception.quality import Truth, TruthFrame
from lesmc.perception.run import PerceiveRun
from lesmc.perception.to_scene import TargetSpec, make_scene
from lesmc.report.results import DesignRun, window_of
from lesmc.tracking.design import make_design
from lesmc.tracking.monitor import track
from lesmc.tracking.scene import Scene
from lesmc.video.reader import FrameSet, open_frames
from lesmc.video.synth import SynthConfig, write_video

#: The embedded default video: `lesmc synth` with these settings.
DEFAULT_VIDEO = {"frames": 24, "width": 2048, "height": 2048, "seed": 1}
DESIGNS = {
    "single": ["single"],
    "joint": ["joint"],
    "improved": ["improved"],
    "both": ["single", "improved"],
    "all": ["single", "joint", "improved"],
}


def bundled_specs() -> list[Path]:
    """The robustness and resilience specs shipped with lesmc (specs/ in the repository)."""
    names = ("robustness.spec", "resilience.spec")
    packaged = resources.files("lesmc") / "specs"
    if all((packaged / n).is_file() for n in names):  # an installed wheel
        return [Path(str(packaged / n)) for n in names]
    repo = Path(__file__).resolve().parents[1] / "specs"  # an editable install or a checkout
    return [repo / n for n in names]


def with_window(spec: SpecFile, window: tuple[int, int] | None) -> SpecFile:
    """``spec`` attacked in ``window`` (see :meth:`Property.with_window`); None keeps it."""
    return spec.with_window(window)


def with_monitor(spec: SpecFile) -> SpecFile:
    """Every property filtered by the runtime monitor (the improved design of section 7.1)."""
    return spec.with_monitor()


@dataclass(frozen=True)
class Candidate:
    """A possible target: where it starts and where it truly is at each later step."""

    vid: int
    crowd: int  # moving neighbours within ``near`` px, summed over the window's frames
    spec: TargetSpec
    truth_track: np.ndarray  # (n, 2) true positions at steps 0..n-1


def rank_targets(
    frames: list[TruthFrame],
    size: tuple[int, int],
    window: tuple[int, int],
    margin: float = 150.0,
    near: float = 40.0,
    min_speed: float = 5.0,
    max_turn_deg: float = 30.0,
) -> list[Candidate]:
    """Vehicles of ``frames[0]`` worth attacking, most neighbouring traffic first.

    A candidate keeps moving (>= ``min_speed`` m/s), stays visible and inside the
    frame, and does not turn by more than ``max_turn_deg`` between frames until
    two steps after the window (the tracker's model is constant velocity); its
    score is the number of moving vehicles within ``near`` pixels of it over the
    window's frames: the observations an attacker can make the tracker take.
    Ties go to the lower vehicle id, so the choice is deterministic.
    """
    l, u = window
    horizon = min(u + 2, len(frames) - 1)
    first = frames[0]
    out = []
    for vid in first.ids:
        track, ok = [], True
        for tf in frames[: horizon + 1]:
            if vid not in tf.ids:
                ok = False
                break
            j = tf.ids.index(vid)
            x, y = tf.positions[j]
            if (
                tf.occluded[j]
                or tf.speed_mps[j] < min_speed
                or not (margin <= x <= size[0] - margin and margin <= y <= size[1] - margin)
            ):
                ok = False
                break
            track.append((x, y))
        if not ok:
            continue
        pts = np.array(track)
        steps = np.diff(pts, axis=0)
        ang = np.degrees(np.arctan2(steps[:, 1], steps[:, 0]))
        turn = np.abs((np.diff(ang) + 180) % 360 - 180)
        if len(turn) and turn.max() > max_turn_deg:
            continue
        crowd = 0
        for k in range(l, min(horizon, u) + 1):
            tf = frames[k]
            moving = (tf.speed_mps >= 1.5) & ~tf.occluded
            d = np.linalg.norm(tf.positions[moving] - pts[k], axis=1)
            crowd += int(((d > 0.5) & (d < near)).sum())
        if crowd == 0:
            continue
        out.append(Candidate(vid, crowd, TargetSpec(float(pts[0, 0]), float(pts[0, 1])), pts))
    out.sort(key=lambda c: (-c.crowd, c.vid))
    return out


def follows(scene: Scene, truth_track: np.ndarray, tolerance: float = 6.0) -> bool:
    """Whether the unattacked single-KF track stays on the vehicle for ``truth_track``'s steps."""
    run = track(make_design(scene.with_tracker(design="single")), len(truth_track) - 1)
    if len(run) < len(truth_track):
        return False
    est = np.array([p.x[:2] for p in run])
    return bool((np.linalg.norm(est[1:] - truth_track[1:], axis=1) <= tolerance).all())


def load_specs(paths: list[Path], window: tuple[int, int] | None) -> list[SpecFile]:
    if not paths:
        raise UsageError("no property files")
    return [with_window(load_spec(str(p)), window) for p in paths]


#: One design's share of a run: design, tracker, its scene, its properties, the model's window.
DesignUnit = tuple[str, str, Scene, list[SpecFile], tuple[int, int]]

#: Display name and tracker design of each design run.
RUN_NAMES = {"single": "single", "joint": "joint KFs", "improved": "joint KFs + monitor"}


def check_designs(
    scene: Scene,
    specs: list[SpecFile],
    designs: list[str],
    engine: str = "levels",
    on_stage: Callable[[str], None] | None = None,
    only: Callable[[str], bool] | None = None,
    budget: Budget | None = None,
    on_batch: Callable[[GrowingModel], None] | None = None,
    payoffs: str = "attack",
) -> list[DesignRun]:
    """Build the model of each design over the properties' window and check them on it.

    Designs: ``single`` (plain KF, section 6.7), ``joint`` (joint KFs, section 7.2)
    and ``improved`` (joint KFs and the runtime monitor of section 7.1 on every
    property: the paper's Table 5). ``only`` filters properties by name.
    ``budget`` limits each check (what is left of its time, its states and memory;
    past it the verdict may be unknown); ``on_batch`` is :func:`lesmc.unfold.build_model`'s.
    ``payoffs`` (docs/semantics.md, "Payoff intervals"): ``certified`` checks the model of the
    certified lower payoffs, ``interval`` both models, combined by lesmc/engines/interval.py;
    the run's model (what the report draws) is always the attack payoffs' model.
    """
    b = Budget() if budget is None else budget
    from lesmc.unfold import build_model, unbounded_note

    runs = []
    models: dict[tuple[str, tuple[int, int]], tuple[ArrayModel, LTS]] = {}
    unbounded: dict[tuple[str, tuple[int, int]], list[str]] = {}  # certified models' notes
    for d, tracker, sc, sp, win in design_windows(scene, specs, designs, only):
        if (tracker, win) not in models:  # joint and improved share one model
            if on_stage:
                on_stage(f"building the {tracker} model")
            built = build_model(sc, win, on_batch=on_batch)
            models[(tracker, win)] = (built, to_lts(built))
        model, view = models[(tracker, win)]
        bound = _selected(bind_all(model, sp), only)
        low_bound: list[BoundProperty] = []
        if payoffs != "attack":
            key = (tracker + "/certified", win)
            if key not in models:
                if on_stage:
                    on_stage(f"building the {tracker} model with certified payoffs")
                low = sc.priced("certified")
                built = build_model(low, win, on_batch=on_batch)
                models[key] = (built, to_lts(built))
                unbounded[key] = unbounded_note(low, win)
            low_bound = _selected(bind_all(models[key][0], sp), only)
        results = []
        for i, bp in enumerate(bound):
            if on_stage:
                on_stage(f"checking {bp.name} ({RUN_NAMES[d]})")
            notes = unbounded.get((tracker + "/certified", win), [])
            results.append(
                _check(models, tracker, win, bp, low_bound, i, payoffs, engine, b, notes)
            )
        runs.append(DesignRun(RUN_NAMES[d], view, bound, results, sc))
    return runs


def design_windows(
    scene: Scene,
    specs: list[SpecFile],
    designs: list[str],
    only: Callable[[str], bool] | None = None,
) -> list[DesignUnit]:
    """Per design: its tracker, scene, properties (the monitor's for ``improved``) and the
    window of the model they need (:func:`check_designs`)."""
    from lesmc.unfold import bind_scene

    out = []
    for d in designs:
        tracker = "single" if d == "single" else "joint"
        sc = scene.with_tracker(design=tracker)
        sp = [with_monitor(s) for s in specs] if d == "improved" else specs
        out.append((d, tracker, sc, sp, window_of(_selected(bind_scene(sc, sp), only))))
    return out


def _selected(
    bound: list[BoundProperty], only: Callable[[str], bool] | None
) -> list[BoundProperty]:
    """The properties ``only`` keeps (all when None)."""
    return [bp for bp in bound if only is None or only(bp.name)]


def hideable(
    units: list[DesignUnit],
    on_batch: Callable[[GrowingModel], None] | None = None,
) -> dict[int, np.ndarray]:
    """Per frame, the detections the models of ``units`` (:func:`design_windows`) can hide
    (a superset): the only ones whose certified lower payoffs a check reads
    (:func:`lesmc.unfold.priced_detections`)."""
    from lesmc.unfold import merged_detections, priced_detections

    models = {(tracker, win): (sc, win) for _, tracker, sc, _, win in units}.values()
    return merged_detections(priced_detections(sc, win, on_batch=on_batch) for sc, win in models)


def _check(
    models: dict[tuple[str, tuple[int, int]], tuple[ArrayModel, LTS]],
    tracker: str,
    win: tuple[int, int],
    bp: BoundProperty,
    low_bound: list[BoundProperty],
    i: int,
    payoffs: str,
    engine: str,
    b: Budget,
    cert_notes: list[str],
) -> CheckResult:
    """One property in payoff mode ``payoffs`` (the certified model checked first, then
    given ``cert_notes``)."""
    from dataclasses import replace

    from lesmc.engines.interval import combine
    from lesmc.unfold import payoff_monotone

    def run(m: ArrayModel, p: BoundProperty) -> CheckResult:
        limits = (b.max_states or DEFAULT_MAX_STATES, b.seconds_left(), b.max_memory)
        return check_bound(m, p, engine, *limits)  # type: ignore[arg-type]

    if payoffs == "attack":
        return run(models[(tracker, win)][0], bp)
    cert = run(models[(tracker + "/certified", win)][0], low_bound[i])
    cert = replace(cert, notes=[*cert.notes, *cert_notes])
    if payoffs == "certified":
        return replace(cert, payoffs="certified")
    return combine(cert, run(models[(tracker, win)][0], bp), payoff_monotone(bp))


def scene_frames(scene: Scene) -> FrameSet | None:
    """The frames of the video a scene came from (its ``meta.source``), when still there.

    Only the first frame is decoded here: the report reads a frame or two.
    """
    src = scene.meta.get("source")
    if not (isinstance(src, str) and Path(src).is_dir()):
        return None
    try:
        return open_frames(src, 1, check=False)
    except LesmcError:
        return None


def frame_reader(frames: FrameSet | None) -> Callable[[int], np.ndarray | None] | None:
    """``index -> grey frame`` for the report's images (None past the video's end)."""
    if frames is None:
        return None
    fs = frames

    def read(index: int) -> np.ndarray | None:
        return fs.read(index) if 0 <= index < len(fs) else None

    return read


def check_window(scene: Scene, window: tuple[int, int]) -> None:
    """``--window`` against the unattacked track's length, before any model is built."""
    from lesmc.unfold import original_end

    e = original_end(scene)
    if not 1 <= window[0] <= window[1] <= e:
        raise UsageError(
            f"--window {window[0]}..{window[1]} must satisfy 1 <= L <= U <= {e}, the last step "
            f"of the unattacked track from frame {scene.target.step}"
        )


def default_video_ready(video: Path) -> bool:
    """Whether ``video`` already holds exactly the embedded default video."""
    truth = video / "truth.json"
    if not truth.is_file():
        return False
    try:
        same = json.loads(truth.read_text()).get("config") == asdict(SynthConfig(**DEFAULT_VIDEO))
    except ValueError:
        return False
    return same and len(list(video.glob("frame_*.png"))) == DEFAULT_VIDEO["frames"]


def write_default_video(video: Path, progress: Callable[[], None] | None = None) -> None:
    """Generate the embedded default video (``lesmc synth`` with ``DEFAULT_VIDEO``)."""
    write_video(SynthConfig(**DEFAULT_VIDEO), video, progress=progress)


def auto_target(
    run: PerceiveRun,
    frames: FrameSet,
    truth: Truth,
    spec_files: list[SpecFile],
    dt: float,
    meta: dict[str, Any],
) -> Scene:
    """The scene of the best-ranked vehicle (``rank_targets``) whose unattacked track follows it."""
    first = run.detections[0].index
    tfs = [truth.frames[p.name] for p in frames.paths[first:] if p.name in truth.frames]
    window = (
        min(p.window[0] for s in spec_files for p in s.properties),
        max(p.window[1] or len(tfs) - 1 for s in spec_files for p in s.properties),
    )
    cands = rank_targets(tfs, (frames.width, frames.height), window)
    for rank, c in enumerate(cands[:40]):
        scene = make_scene(run.detections, run.payoffs, dt, c.spec, tfs[0], meta=dict(meta))
        if follows(scene, c.truth_track):
            scene.meta["target_choice"] = (
                f"vehicle {c.vid} of the truth: rank {rank + 1} of {len(cands)} by neighbouring "
                f"traffic ({c.crowd} vehicle-frames within 40 px in the window), the first whose "
                "unattacked track follows it"
            )
            return scene
    raise UsageError(
        "no vehicle with neighbouring traffic is tracked correctly unattacked; give --target"
    )
