"""``perceive``: a directory of frames -> detections, payoffs and quality, frame by frame.

The Python API behind ``lesmc perceive``; the CLI only parses options and prints.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import closing, nullcontext
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.common.memory import release
from lesmc.perception import HISTORY, ON_DEMAND_STEPS
from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.attacks import payoffs
from lesmc.perception.blobs import BlobConfig
from lesmc.perception.certify import CertifyConfig
from lesmc.perception.cnn import DR_SIZE, Nets
from lesmc.perception.detector import Detector, DetectorConfig, FrameDetections
from lesmc.perception.frontend import (
    FrontEnd,
    FrontEndConfig,
    FrontEndOutput,
    registered_ahead,
)
from lesmc.perception.quality import Score, Truth, TruthFrame, care_mask, score
from lesmc.perception.registration import Registration, RegistrationError
from lesmc.perception.threads import torch_lanes
from lesmc.perception.windows import compact, expand
from lesmc.video.reader import FrameSet

ZERO = Score(0, 0, 0, 0, 0.0)


@dataclass(frozen=True)
class PerceiveOptions:
    """What to run: front end only (``nets`` None) or the whole detector, attack or not."""

    history: int = HISTORY
    delta_bc: int = 12
    nets: Nets | None = None
    attack: AttackConfig | None = None
    certify: CertifyConfig | None = None  #: also certified lower bounds (with ``attack``)
    radius: float = 4.0
    min_speed: float = 1.5
    #: keep each frame's N_dr windows after its payoffs (certification on demand reads
    #: them; without ``attack``, pricing on demand, and they are kept compact, as uint8:
    #: windows.expand); False frees them frame by frame
    keep_windows: bool = True
    #: record every hidden unit's largest value on the windows scored (``unit_max``:
    #: what a stuck-at-max neuron fault needs); reading each activation once more makes
    #: the networks' scoring 1.3-1.9x as long (benchmarks/bench_maxima.py)
    record_maxima: bool = False
    #: injection candidates (issue 61): the candidates N_dr rejects within this many px of
    #: one of the frame's detections (at most ``DetectorConfig.inject_cap`` a frame), each
    #: priced by the attack towards "vehicle" (``attack``'s settings, else the defaults);
    #: None: none
    inject_within: float | None = None
    inject_cap: int = 32  #: at most this many injection candidates a frame


@dataclass
class PerceiveRun:
    """Everything a run produced."""

    detections: list[FrameDetections] = field(default_factory=list)
    payoffs: list[np.ndarray] = field(default_factory=list)
    payoffs_lower: list[np.ndarray] = field(default_factory=list)  #: with --certify
    rows: list[dict[str, Any]] = field(default_factory=list)
    frontend_total: Score = ZERO
    detector_total: Score = ZERO
    unattackable: int = 0
    #: per network ("detector", "locator"), per hidden layer, each unit's largest value
    #: on the windows scored (lesmc/perception/neurons.py; empty without the CNNs or
    #: without ``record_maxima``)
    unit_max: dict[str, list[np.ndarray]] = field(default_factory=dict)
    #: frame index -> its registration from the previous frame (a replay reuses them)
    registrations: dict[int, Registration] = field(default_factory=dict)
    #: per frame of ``detections``, the price of injecting each of its injection candidates
    #: (``FrameDetections.rejected``; inf: the attack did not make N_dr accept it)
    inject_payoffs: list[np.ndarray] = field(default_factory=list)
    inject_seconds: float = 0.0  #: time spent pricing injection candidates
    #: the side (px) of the window N_dr classifies: each detection's box in the scene is
    #: this square centred on it (lesmc/perception/to_scene.py)
    box_px: int = DR_SIZE


def perceive(
    frames: FrameSet,
    opts: PerceiveOptions,
    truth: Truth | None = None,
    on_frame: Callable[[], None] | None = None,
) -> PerceiveRun:
    """Run the detector over every frame; score against ``truth`` when given."""
    return perceive_all(frames, [opts], truth, on_frame)[0]


def perceive_all(
    frames: FrameSet,
    runs: Sequence[PerceiveOptions],
    truth: Truth | None = None,
    on_frame: Callable[[], None] | None = None,
) -> list[PerceiveRun]:
    """:func:`perceive` with several detectors (say, networks with different stuck units)
    over one front end: each frame is registered and its candidates found once. Every
    option set must have the same front-end settings (``history``, ``delta_bc``)."""
    first = runs[0]
    if any((o.history, o.delta_bc) != (first.history, first.delta_bc) for o in runs):
        raise ValueError("perceive_all needs one front end: equal history and delta_bc")
    fe_cfg = FrontEndConfig(history=first.history, blobs=BlobConfig(delta_bc=first.delta_bc))
    dets = [
        Detector(
            o.nets,
            DetectorConfig(frontend=fe_cfg, inject_within=o.inject_within, inject_cap=o.inject_cap),
            record_maxima=o.record_maxima,
        )
        if o.nets
        else None
        for o in runs
    ]
    fe = FrontEnd(fe_cfg)
    out_runs = [PerceiveRun() for _ in runs]
    # the next frame is read and registered on a second thread while this one's CNNs run;
    # the CNNs' batches run side by side, torch on one thread each (perception/threads.py)
    lanes = torch_lanes() if any(d is not None for d in dets) else nullcontext()
    with lanes, closing(registered_ahead(frames, fe_cfg.registration)) as ahead:
        for i in range(len(frames)):
            try:
                img, reg = next(ahead)
            except RegistrationError as exc:
                raise InputError(
                    f"cannot register with the previous frame: {exc}",
                    Location(str(frames.paths[i])),
                ) from None
            out = fe.push(img, reg)
            if on_frame:
                on_frame()
            if out is None:
                continue
            tf = truth.frames[frames.paths[i].name] if truth is not None else None
            for run, det, opts in zip(out_runs, dets, runs, strict=True):
                _frame(run, det, opts, out, frames.paths[i].name, tf)
            # not held while the next frame is made: its aligned history and background
            # are six frame-sized arrays (25 MB at 2048 x 2048)
            del out
            release()  # what this frame freed goes back to the system (common/memory.py)
    for run, det in zip(out_runs, dets, strict=True):
        run.registrations = dict(fe.registrations)  # one front end served every run
        if det is not None and det.maxima is not None:
            run.unit_max = det.maxima.maxima
    return out_runs


def nothing_detected(run: PerceiveRun) -> str | None:
    """A warning when N_dr accepted none of the candidates the front end found in the whole
    video (a detector fed windows it was not made for, or answering "vehicle" at another
    index, finds nothing without failing); None otherwise, or without the CNNs."""
    if not run.detections:
        return None
    found = sum(int(r["candidates"]) for r in run.rows)
    if found == 0 or any(fd.n_accepted for fd in run.detections):
        return None
    return (
        f"the detector accepted none of the {found} candidates the front end found in "
        f"{len(run.rows)} frames: the scene has no detections. Check that it takes lesmc's "
        "windows (docs/own-system.md: channels oldest frame first, grey levels in [0, 1]) "
        "and that its logit 1 means vehicle"
    )


def _frame(
    run: PerceiveRun,
    det: Detector | None,
    opts: PerceiveOptions,
    out: FrontEndOutput,
    name: str,
    tf: TruthFrame | None,
) -> None:
    """One frame's candidates through ``det`` into ``run``: detections, payoffs, scores."""
    row: dict[str, Any] = {
        "frame": name,
        "candidates": len(out.candidates),
        "reg_rms_px": out.registration.rms_px,
    }
    fd = det.detect(out) if det else None
    if fd is not None:
        row |= {
            "accepted": fd.n_accepted,
            "detections": len(fd.positions),
            "via_lp": int(fd.via_lp.sum()),
        }
        if opts.attack is not None and opts.nets is not None:
            upper, lower = _payoffs(opts.nets, fd, opts.attack, opts.certify)
            run.payoffs.append(upper)
            if lower is not None:
                run.payoffs_lower.append(lower)
            run.unattackable += int(np.isinf(run.payoffs[-1]).sum())
        elif opts.nets is not None:  # no attack: every payoff unpriced (price_detections)
            run.payoffs.append(np.full(len(fd.positions), np.nan))
        if opts.nets is not None:
            fd = _price_injections(run, opts.nets, fd, opts.attack or AttackConfig())
        if not opts.keep_windows:  # a copy: a view would keep the whole array alive
            fd = replace(fd, windows=np.empty((0, *fd.windows.shape[1:]), np.float32))
        elif opts.attack is None and opts.nets is not None:  # kept for price_detections
            fd = replace(fd, windows=compact(fd.windows))
        run.detections.append(fd)
    if tf is not None:
        care = care_mask(tf, out.aligned.valid, opts.min_speed)
        s_fe = score(out.candidates.centroid, tf.positions, care, opts.radius)
        run.frontend_total = run.frontend_total + s_fe
        row["frontend"] = s_fe.to_json()
        if fd is not None:
            s_det = score(fd.positions, tf.positions, care, opts.radius)
            run.detector_total = run.detector_total + s_det
            row["detector"] = s_det.to_json()
    run.rows.append(row)


def _price_injections(
    run: PerceiveRun, nets: Nets, fd: FrameDetections, cfg: AttackConfig
) -> FrameDetections:
    """The price of each injection candidate of ``fd`` (the attack towards "vehicle" on its
    N_dr window) into ``run.inject_payoffs``; ``fd`` without the candidates' windows."""
    t0 = time.perf_counter()
    if len(fd.rejected):
        res = payoffs(nets.dr, fd.rejected_windows, nets.settings.delta_dr, cfg, "inject")
        run.inject_payoffs.append(res.payoff)
    else:
        run.inject_payoffs.append(np.zeros(0))
    run.inject_seconds += time.perf_counter() - t0
    return replace(fd, rejected_windows=fd.rejected_windows[:0].copy())


def _payoffs(
    nets: Nets, fd: FrameDetections, cfg: AttackConfig, cert: CertifyConfig | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """One attack per Q_dr blob that produced detections; each detection gets its blob's payoff.

    With ``cert``, also every blob's certified lower bound (:func:`certified_lower`).
    """
    used = np.unique(fd.source)
    res = payoffs(nets.dr, fd.windows[used], nets.settings.delta_dr, cfg)
    per_blob = np.full(len(fd.windows), np.inf)
    per_blob[used] = res.payoff
    out: np.ndarray = per_blob[fd.source]
    if cert is None:
        return out, None
    lower = np.zeros(len(fd.windows))
    lower[used] = certified_lower(nets, fd.windows[used], res.payoff, cfg, cert)
    return out, lower[fd.source]


def certified_lower(
    nets: Nets,
    windows: np.ndarray,
    upper: np.ndarray,
    cfg: AttackConfig,
    cert: CertifyConfig,
    on_batch: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Certified lower bounds (certify.py) of N_dr ``windows`` whose attack payoffs are ``upper``.

    In the attack's norm (``per-pixel`` divides by the window's pixel count too),
    and never above the attack's payoff. ``on_batch(done)`` after each batch of
    ``cert.batch`` windows (progress, budgets).
    """
    from lesmc.perception.attack_settings import threshold_logit
    from lesmc.perception.certify import certified_radius

    scale = DR_SIZE * DR_SIZE if cfg.norm == "per-pixel" else 1.0
    chain = detector_chain(nets, threshold_logit(nets.settings.delta_dr))
    radius = certified_radius(chain, windows, upper * scale, cert, on_batch) / scale
    bounded: np.ndarray = np.minimum(radius, upper)
    return bounded


def detector_chain(nets: Nets, t: float) -> Any:
    """N_dr as the bound propagation sees it, margin threshold ``t``: the shipped network's,
    or a detector file's (an unsupported node is an InputError naming it)."""
    from lesmc.perception.certify import detect_chain

    if nets.dr_file is None:
        return detect_chain(nets.dr, t)
    return nets.dr_file.chain(t)


def certify_on_demand(
    nets: Nets,
    run: PerceiveRun,
    wanted: dict[int, np.ndarray],
    on_batch: Callable[[int, int], None] | None = None,
) -> dict[int, np.ndarray]:
    """:func:`certify_detections` as ``verify`` and ``campaign`` run it: the default
    attack settings and :data:`ON_DEMAND_STEPS` bisection steps, each window grown
    whatever its slack."""
    cert = CertifyConfig(steps=ON_DEMAND_STEPS, grow_slack=0.0, model_slack=0.0)  # every step
    return certify_detections(nets, run, wanted, AttackConfig(), cert, on_batch)


def certify_detections(
    nets: Nets,
    run: PerceiveRun,
    wanted: dict[int, np.ndarray],
    cfg: AttackConfig,
    cert: CertifyConfig,
    on_batch: Callable[[int, int], None] | None = None,
) -> dict[int, np.ndarray]:
    """Certified lower bounds of the ``wanted`` detections of a perceive ``run`` only.

    ``wanted``: per frame index, detection indices (what a model can hide,
    :func:`lesmc.unfold.unfold.priced_detections`). Detections of one Q_dr blob share
    its window, so each blob is certified once. Returns, per frame index, the
    bound of every detection of that frame, ``nan`` where not certified.
    ``on_batch(done, total)`` counts blobs.
    """
    jobs = _wanted_blobs(run, wanted)
    total = sum(len(b) for _, b in jobs)
    low = (
        certified_lower(
            nets,
            _blob_windows(run, jobs),
            np.concatenate([_blob_payoffs(run.detections[i], run.payoffs[i])[b] for i, b in jobs]),
            cfg,
            cert,
            None if on_batch is None else (lambda done: on_batch(done, total)),
        )
        if total
        else np.zeros(0)
    )
    return _per_detection(run, jobs, low)


def price_detections(
    nets: Nets, run: PerceiveRun, wanted: Mapping[int, np.ndarray], cfg: AttackConfig
) -> dict[int, np.ndarray]:
    """Attack payoffs of the ``wanted`` detections of a perceive ``run`` made without an
    attack (its payoffs unpriced, ``nan``): per frame index, detection indices.

    Detections of one Q_dr blob share its window, so each blob is attacked once, all
    frames' blobs in one batched attack; every detection of an attacked blob gets its
    payoff, in the returned arrays (per frame index, one value per detection of the
    frame, ``nan`` where not priced) and in ``run.payoffs``.
    """
    jobs = _wanted_blobs(run, wanted)
    if not jobs:
        return {}
    res = payoffs(nets.dr, _blob_windows(run, jobs), nets.settings.delta_dr, cfg)
    out = _per_detection(run, jobs, res.payoff)
    for i, _ in jobs:
        got = out[run.detections[i].index]
        run.payoffs[i] = np.where(np.isnan(got), run.payoffs[i], got)
    return out


def _wanted_blobs(
    run: PerceiveRun, wanted: Mapping[int, np.ndarray]
) -> list[tuple[int, np.ndarray]]:
    """Per frame index of ``wanted`` (in order) that ``run`` perceived: the row of
    ``run.detections`` and the Q_dr blobs its wanted detections came from, each once."""
    row_of = {fd.index: i for i, fd in enumerate(run.detections)}
    return [
        (row_of[k], np.unique(run.detections[row_of[k]].source[dets]))
        for k, dets in sorted(wanted.items())
        if k in row_of and len(dets)
    ]


def _blob_windows(run: PerceiveRun, jobs: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """The N_dr windows of the blobs of ``jobs`` (:func:`_wanted_blobs`), in order, float32."""
    return np.concatenate([expand(run.detections[i].windows[blobs]) for i, blobs in jobs])


def _per_detection(
    run: PerceiveRun, jobs: list[tuple[int, np.ndarray]], values: np.ndarray
) -> dict[int, np.ndarray]:
    """One value per blob of ``jobs`` (in order) given to each of the blob's detections:
    per frame index, one value per detection of the frame, ``nan`` for the others."""
    out: dict[int, np.ndarray] = {}
    at = 0
    for i, blobs in jobs:
        fd = run.detections[i]
        per_blob = np.full(len(fd.windows), np.nan)
        per_blob[blobs] = values[at : at + len(blobs)]
        at += len(blobs)
        out[fd.index] = per_blob[fd.source]
    return out


def _blob_payoffs(fd: FrameDetections, pay: np.ndarray) -> np.ndarray:
    """Each blob's payoff, from its detections' (every detection of a blob carries it)."""
    per_blob = np.full(len(fd.windows), np.inf)
    per_blob[fd.source] = pay
    return per_blob
