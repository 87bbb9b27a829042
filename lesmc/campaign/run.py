"""A campaign from videos to ``results.jsonl``: perceive once, choose targets, run the groups.

Per video: the frames are perceived once into a scene without a target, saved
as ``DIR/scenes/<video>.json`` (reused by a rerun when the frames are the same);
targets are read from a file or found automatically; every (target, tracker)
becomes a :class:`~lesmc.campaign.plan.Group` of the units not yet in
``results.jsonl``. Groups run in this process (``workers=0``), on a Dask
``LocalCluster`` of worker processes, or on a cluster the user started; each
row is appended by this process as soon as its group returns.
"""

from __future__ import annotations

import hashlib
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from lesmc.campaign.plan import Group, plan_units, scene_key
from lesmc.campaign.work import run_group, scene_doc
from lesmc.common.budget import Budget
from lesmc.common.errors import InputError, UsageError
from lesmc.common.files import read_json
from lesmc.common.progress import progress_bar
from lesmc.designs import registry
from lesmc.language.properties import SpecFile
from lesmc.perception import HISTORY, NetFiles
from lesmc.perception.quality import load_truth
from lesmc.pipeline import certify
from lesmc.pipeline.job import Certifier
from lesmc.scene import Footage, TrackerConfig, footage_from_dict, save_scene, scene_to_dict
from lesmc.scene.located import scene_error
from lesmc.tracking.targets import (
    TargetSpec,
    place_target,
)
from lesmc.unfold.probe import merged_detections
from lesmc.video import FPS

#: Retries of a group whose worker died (Dask's ``retries``).
RETRIES = 3


@dataclass(frozen=True)
class Video:
    """One input video: its name in the results, its frames and (optional) truth."""

    name: str
    frames_dir: Path
    truth: Path | None
    origin: str


@dataclass
class Prepared:
    """A perceived video: its scene (no target), the scene's JSON and content keys.

    ``key`` (units) leaves certified bounds out, ``doc_key`` (the document the workers
    parse) does not: :func:`certify_scenes` adds bounds without changing the units.
    ``run``: the perception run, when this process perceived the video.
    """

    video: Video
    footage: Footage
    doc: dict[str, Any]
    key: str
    scene_path: Path
    targets: list[TargetSpec] = field(default_factory=list)
    origins: list[str] = field(default_factory=list)
    run: Any = None
    doc_key: str = ""

    def __post_init__(self) -> None:
        self.doc_key = self.doc_key or scene_key(self.doc, bounds=True)

    def set_footage(self, footage: Footage) -> None:
        """Replace the scene (with bounds added): its document and document key follow."""

        self.footage = footage
        self.doc = scene_to_dict(footage)
        self.doc_key = scene_key(self.doc, bounds=True)


def fingerprint(paths: Iterable[Path]) -> str:
    """The frames' names and contents, hashed: a rerun reuses a scene only for the same video."""
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode() + b"\0")
        with open(p, "rb") as fh:
            while chunk := fh.read(1 << 20):
                h.update(chunk)
    return h.hexdigest()[:20]


def prepare(
    video: Video,
    out: Path,
    files: NetFiles = (None, None, None),
    tracker: TrackerConfig | None = None,
    certified: bool = False,
) -> Prepared:
    """The video's scene: ``DIR/scenes/<name>.json`` if made from these frames, else perceived;
    with ``tracker`` (``--tracker``) as its scene's tracker (the file is rewritten if it had
    another). A detector file (``files[1]``, docs/detectors.md) perceives the whole frames,
    every detection priced; ``certified`` (--payoffs certified|interval): a detector file
    that gives no certified bounds is refused first (:func:`certify_scenes` bounds the
    detections the models can hide)."""
    p = _prepare(video, out, files, certified)
    if tracker is not None and p.footage.tracker != tracker:
        p.set_footage(replace(p.footage, tracker=tracker))
        p.key = scene_key(p.doc)
        save_scene(p.footage, p.scene_path)
    return p


def least_frames(files_or_meta: NetFiles | dict[str, Any]) -> int:
    """The fewest frames a video needs: L + 1 for the window pipeline (its background), one
    for a detector file (given as the networks' files, or a scene's meta recording it)."""
    from lesmc.experiment.detector_verify import detector_file_of

    if isinstance(files_or_meta, dict):
        return 1 if isinstance(files_or_meta.get("detector_file"), dict) else HISTORY + 1
    return 1 if detector_file_of(files_or_meta) is not None else HISTORY + 1


def _prepare(video: Video, out: Path, files: NetFiles, certified: bool) -> Prepared:
    from lesmc.experiment.detector_verify import detector_file_of
    from lesmc.perception.to_scene import footage_from_run
    from lesmc.video.reader import open_frames

    path = out / "scenes" / f"{video.name}.json"
    by_file = detector_file_of(files)
    frames = open_frames(video.frames_dir, least_frames(files), check=not path.exists())
    fp = fingerprint(frames.paths)
    if by_file is not None and certified:
        from lesmc.experiment.detector_verify import refuse_uncertifiable

        refuse_uncertifiable(by_file, "--payoffs certified|interval")
    kept = _kept_scene(video, path, fp, by_file)
    if kept is not None:
        return kept
    truth = load_truth(str(video.truth)) if video.truth else None
    dt = (truth.dt if truth else None) or 1 / FPS
    meta = {
        "source": str(video.frames_dir),
        "video": video.origin,
        "fingerprint": fp,
        "size": [frames.width, frames.height],
    }
    run = None
    if by_file is not None:
        footage = _perceive_file(video, frames, by_file, dt, meta)
    else:
        run, nets = perceive_video(video, frames, files)
        footage = footage_from_run(run, dt, meta | {"detector": nets.settings.trained_on})
    path.parent.mkdir(parents=True, exist_ok=True)
    save_scene(footage, path)
    doc = scene_to_dict(footage)
    return Prepared(video, footage, doc, scene_key(doc), path, run=run)


def _kept_scene(video: Video, path: Path, fp: str, by_file: str | None) -> Prepared | None:
    """The scene an earlier run perceived from these frames (None: none yet); made from
    other frames, or by other networks than ``by_file`` (a detector file) says, is an error."""
    if not path.exists():
        return None
    doc = read_json(path, InputError)
    meta = doc.get("meta") if isinstance(doc, dict) else None
    again = "use another --out (or remove that scene to perceive again)"
    if not (isinstance(meta, dict) and meta.get("fingerprint") == fp):
        why = f"the scene was perceived from other frames than {video.frames_dir}: {again}"
        raise scene_error(str(path), None, [("meta.fingerprint", why)])
    item, why = _other_detector(meta.get("detector_file"), by_file)
    if why:
        raise scene_error(str(path), None, [(item, f"the scene was perceived {why}: {again}")])
    footage, _ = footage_from_dict(doc, str(path))
    return Prepared(video, footage, doc, scene_key(doc), path)


def _other_detector(recorded: Any, by_file: str | None) -> tuple[str, str]:
    """How a scene's ``meta.detector_file`` differs from this run's detector file
    ``by_file`` (None: the window pipeline): the scene's field that says so and how (empty
    when the same files made it)."""
    from lesmc.common.files import file_sha256

    at = "meta.detector_file"
    if not isinstance(recorded, dict):
        return at, "" if by_file is None else f"by the window pipeline, not by {by_file}"
    if by_file is None:
        return at, f"with the detector file {recorded.get('path')}: give it as --detector"
    net = Path(str(recorded.get("network")))
    if recorded.get("sha256") != file_sha256(by_file):
        why = f"with another detector file than {by_file} ({recorded.get('path')})"
        return f"{at}.sha256", why
    if not net.is_file() or recorded.get("network_sha256") != file_sha256(net):
        return f"{at}.network_sha256", f"with another network than {net} holds now"
    return at, ""


def _perceive_file(
    video: Video, frames: Any, path: str, dt: float, meta: dict[str, Any]
) -> Footage:
    """The video perceived through the detector file ``path`` as ``lesmc verify --detector
    --price-all`` perceives it (lesmc/experiment/detector_verify.py): every detection
    priced (none certified: :func:`certify_scenes`); ``meta`` and the detections' facts
    added to its meta."""
    from lesmc.common.progress import Reporter
    from lesmc.experiment import detector_verify

    truth = str(video.truth) if video.truth else None
    truths = load_truth(truth) if truth else None
    with Reporter("campaign") as rep:
        footage, facts = detector_verify.perceive_video(
            str(video.frames_dir), frames, path, truth, truths, False, dt, rep,
            lambda _stage: None,
        )  # fmt: skip
    meta = footage.meta | meta | {"detections": detector_verify.describe(facts)}
    return replace(footage, meta=meta)


def perceive_video(video: Video, frames: Any, files: NetFiles) -> tuple[Any, Any]:
    """The perception run of a video's frames (detections, payoffs, N_dr windows) and the nets."""
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.run import PerceiveOptions, perceive

    nets = load_nets(*files)
    opts = PerceiveOptions(history=HISTORY, nets=nets, attack=AttackConfig())
    with progress_bar("campaign", f"perceiving {video.name}", len(frames)) as bar:
        run = perceive(frames, opts, None, bar.advance)
    return run, nets


# ------------------------------------------------------------------ certified payoffs


def same_detections(p: Prepared, run: Any, nets: Any) -> None:
    """A video perceived again must give its scene's detections and payoffs, with the
    networks its meta names, else the certified bounds would be of another network."""

    from lesmc.perception.to_scene import footage_from_run

    def where(frame: Any) -> np.ndarray:
        return np.array([(d.x, d.y) for d in frame.detections], dtype=float).reshape(-1, 2)

    def pay(frame: Any) -> np.ndarray:
        return np.array([d.payoff for d in frame.detections], dtype=float)

    again = footage_from_run(run, p.footage.dt, {})
    ok = len(again.frames) == len(p.footage.frames) and all(
        f.step == g.step
        and len(f.detections) == len(g.detections)
        and np.allclose(where(f), where(g), rtol=0, atol=1e-3)
        and np.allclose(pay(f), pay(g), rtol=1e-4, atol=1e-6, equal_nan=True)
        for f, g in zip(again.frames, p.footage.frames, strict=True)
    )
    recorded = p.footage.meta.get("detector")
    ok = ok and (recorded is None or recorded == nets.settings.trained_on)
    if not ok:
        raise UsageError(
            f"{p.scene_path} was perceived with other networks than this run's "
            f"(detector: {p.footage.meta.get('detector', 'unknown')}): certifying its "
            "detections needs the same --nets (or another --out)"
        )


def certify_scenes(prepared: list[Prepared], groups: list[Group], files: NetFiles) -> list[Group]:
    """Certified lower payoffs for every detection the groups' models can hide.

    Per video: the probes of every group (target, tracker) over its units' widest
    windows (lesmc/pipeline/certify.py), each within a unit's budget; what they
    found and the scene does not bound yet is certified (the video is perceived
    again when this process did not perceive it). The scene file gets the bounds;
    the groups get its new key and, per probed window, how many of the detections
    its model can hide still lack a bound (normally none).
    """
    out: list[Group] = []
    for p in prepared:
        mine = [g for g in groups if g.video == p.video.name]
        if not mine:
            continue
        probes = _probes(p, mine)
        found = [pr for prs in probes.values() for pr in prs]
        todo = certify.without_bound(p.footage, merged_detections(pr.found for pr in found))
        if todo or "certified" not in p.footage.meta:
            low = certify.certify(
                p.footage,
                found,
                _certifier(p, files, sum(len(v) for v in todo.values())),
                "the detections the campaign's models can hide; the others have no bound",
            )
            p.set_footage(replace(p.footage, frames=low.frames, meta=low.meta))
            save_scene(p.footage, p.scene_path)
        for g in mine:
            counts = tuple(
                (pr.window, certify.unbounded(p.footage, [pr], pr.window)) for pr in probes[g]
            )
            out.append(replace(g, scene_key=p.doc_key, unbounded=counts))
        p.run = None  # its windows are no longer needed
    out.sort(key=group_order)
    return out


def _probes(p: Prepared, groups: list[Group]) -> dict[Group, list[certify.Probed]]:
    """Per group, the probes of its units' widest windows, each within a unit's budget."""
    out: dict[Group, list[certify.Probed]] = {}
    n = sum(len(certify.widest({u.window for u in g.units})) for g in groups)
    with progress_bar("campaign", f"what {p.video.name}'s models can hide", n) as bar:
        for g in groups:
            scene = place_target(p.footage, g.target).with_tracker(design=g.tracker)
            budget = Budget(max_states=g.max_states, check_timeout=g.timeout)
            out[g] = []
            for w in certify.widest({u.window for u in g.units}):
                out[g].append(certify.probe(scene, w, budget))
                bar.advance()
    return out


def _certifier(p: Prepared, files: NetFiles, n: int) -> Certifier:
    """Perception's certification of the video's detections (perceived again if need be);
    through a detector file, its crop bounds on the detections asked for
    (lesmc/experiment/detector_verify.py ``file_certifier``)."""
    from lesmc.experiment.detector_verify import detector_file_of

    by_file = detector_file_of(files)
    if by_file is not None:
        return _file_certifier(p, files, by_file, n)

    def run(wanted: Any) -> dict[int, Any]:
        from lesmc.perception.cnn import load_nets
        from lesmc.perception.run import certify_on_demand
        from lesmc.video.reader import open_frames

        if p.run is None:
            frames = open_frames(p.video.frames_dir, HISTORY + 1, check=False)
            p.run, nets = perceive_video(p.video, frames, files)
            same_detections(p, p.run, nets)
        else:
            nets = load_nets(*files)
        Console(stderr=True).print(
            f"{p.video.name}: certifying {n} detections (those the models can hide and the "
            "scene does not yet bound), counted by window: the detections of a blob share one"
        )
        with progress_bar("campaign", f"certifying {p.video.name}'s windows", None) as bar:
            return certify_on_demand(
                nets, p.run, wanted, lambda done, total: bar.update(total=total, completed=done)
            )

    return run


def _file_certifier(p: Prepared, files: NetFiles, path: str, n: int) -> Certifier:
    """The crop bounds of the detector file ``path`` on the detections of ``p`` asked for
    (lesmc/experiment/detector_verify.py ``file_certifier``), saying how many first."""
    from lesmc.experiment.detector_verify import file_certifier
    from lesmc.video.reader import open_frames

    frames = open_frames(p.video.frames_dir, least_frames(files), check=False)
    bound = file_certifier(path, frames, p.footage)

    def run(wanted: Any) -> dict[int, Any]:
        of = sum(len(f.detections) for f in p.footage.frames)
        Console(stderr=True).print(
            f"{p.video.name}: certifying {n} of {of} detections through {path} (those the "
            "models can hide and the scene does not yet bound)"
        )
        return bound(wanted)

    return run


# ------------------------------------------------------------------ groups


def make_groups(
    prepared: list[Prepared],
    specs: list[SpecFile],
    windows: list[tuple[int, int]],
    designs: tuple[str, ...],
    done: set[str],
    timeout: float | None,
    max_states: int | None,
    payoffs: str = "attack",
) -> tuple[list[Group], int]:
    """The groups still to run (finished units left out) and the number of units in all."""
    texts = tuple((s.path, s.text) for s in specs)
    groups = []
    total = 0
    for p in prepared:
        for t in p.targets:
            for tracker, units in plan_units(p.key, t, specs, windows, designs, payoffs).items():
                total += len(units)
                todo = tuple(u for u in units if u.key not in done)
                if todo:
                    groups.append(
                        Group(
                            p.video.name,
                            p.doc_key,
                            t,
                            tracker,
                            todo,
                            texts,
                            timeout,
                            max_states,
                            payoffs,
                            scene_file=str(p.scene_path),
                        )
                    )
    groups.sort(key=group_order)
    return groups, total


def group_order(g: Group) -> tuple[float, int]:
    """Costly trackers' groups (the registry's ``cost``) and large groups start first:
    longest first balances the workers."""
    return (-registry.get(g.tracker).cost, -len(g.units))


RowsHandler = Callable[[list[dict[str, Any]]], None]


def dask_client(workers: int, scheduler: str | None) -> tuple[Any, Any]:
    """A Dask client of a new local cluster of ``workers`` single-threaded processes (and
    that cluster), or of the cluster at ``scheduler`` (and None)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:  # pragma: no cover - a runtime dependency
        raise UsageError(
            "the campaign's parallel mode needs dask distributed: pip install 'dask[distributed]'"
            " (or run with --workers 0)"
        ) from None
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise UsageError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    with _sigint_ignored():  # the worker processes start with Ctrl-C ignored
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            # a group's failure reaches the client as its future's exception; what the
            # workers log at ERROR is connection noise when a Ctrl-C tears the cluster
            # down mid-transfer (a "failed during get data" traceback)
            silence_logs=50,
            preload=["lesmc.campaign.quiet_worker"],  # and restarted ones too
        )
    return Client(cluster), cluster


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while the local cluster spawns its workers: they inherit it, so
    a Ctrl-C (sent by the terminal to every process of the job) reaches only this
    process, which stops the cluster; no worker prints a traceback."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)


def execute(
    groups: list[Group],
    docs: dict[str, dict[str, Any]],
    on_rows: RowsHandler,
    workers: int,
    scheduler: str | None,
) -> None:
    """Run every group; ``on_rows`` gets each group's rows as soon as it is done.

    ``workers == 0`` and no scheduler: in this process, one group after the
    other (debugging). Otherwise Dask distributed: a ``LocalCluster`` of
    ``workers`` single-threaded processes, or the cluster at ``scheduler``. A
    group whose worker dies is run again (``retries``).
    """
    if not groups:
        return  # all done: no cluster to start
    if scheduler is None and workers == 0:
        for g in groups:
            on_rows(run_group(g, docs[g.scene_key]))
        return
    from distributed import as_completed

    client, cluster = dask_client(workers, scheduler)
    try:
        shared = {k: client.submit(scene_doc, doc, pure=False) for k, doc in docs.items()}
        futures = [
            client.submit(run_group, g, shared[g.scene_key], retries=RETRIES, pure=False)
            for g in groups
        ]
        # as_completed must wait on this client's loop: by default it takes the
        # caller's current client, whose loop differs, and a future reset by a
        # lost worker then fails with "bound to a different event loop".
        for fut in as_completed(futures, loop=client.loop):
            on_rows(fut.result())
            fut.release()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
