"""The results stage: check results of each design run, as one versioned document.

``results.json`` (format ``lesmc-results``) holds everything the report draws
and nothing it would have to recompute from a model or a scene: per design
run the check results, the attacked tracks with their Table 3 measures and
how each property judges them, the states on those tracks (estimate and τ),
the detections near them, the homographies to the frame the track figures
are drawn in, and the provenance (tool version, command line, date, seeds,
spec texts, model hash). :mod:`lesmc.report.html` draws the report from this
document alone (``lesmc report RESULTS.json``); frames, when wanted, come from
a directory named on the command line.
"""

from __future__ import annotations

import hashlib
import math
import platform
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from lesmc.engines.result import CheckResult, PathInfo
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.model import kernel
from lesmc.model.lts import LTS, to_arrays
from lesmc.report.paths import (
    PathSet,
    TrackPath,
    enumerate_tracks,
    judge,
    position,
    tau_series,
)
from lesmc.tracking.scene import Scene

FORMAT = "lesmc-results"
VERSION = 1

#: Paths listed in a results file at most (the report says how many exist in all).
MAX_PATHS = 20000
#: Detections kept per step: those within this many pixels of a listed track.
NEAR_PX = 160.0


@dataclass
class DesignRun:
    """One design's model, its bound properties and their results (same order)."""

    name: str
    model: LTS
    bound: list[BoundProperty]
    results: list[CheckResult]
    scene: Scene | None = None


def window_of(bound: list[BoundProperty]) -> tuple[int, int]:
    """The union of the properties' attack windows."""
    return min(bp.l for bp in bound), max(bp.u for bp in bound)


def complete(model: LTS, states: tuple[str, ...]) -> tuple[str, ...]:
    """Extend a path that stops at a property's end with unattacked steps to the model's end."""
    out = list(states)
    while True:
        nxt = model.out(out[-1])
        if not nxt:
            return tuple(out)
        out.append(nxt[0].dst)


def num(x: float | None) -> float | str | None:
    """JSON has no infinity: "inf"/"-inf" as strings (as in ``--json``)."""
    if x is None:
        return None
    if math.isnan(x):
        return None
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return float(x)


def model_hash(model: LTS) -> str:
    """sha256 over the model's arrays (states, estimates, covariances, transitions)."""
    cm = to_arrays(model)
    h = hashlib.sha256()
    for arr in (cm.step, cm.S, cm.halted, cm.ptr, cm.dst, cm.payoff, cm.rank, cm.original):
        h.update(np.ascontiguousarray(arr).tobytes())
    if cm.cov is not None and cm.P_table is not None:
        h.update(np.ascontiguousarray(cm.cov).tobytes())
        h.update(np.ascontiguousarray(cm.P_table).tobytes())
    h.update("\0".join(cm.obs_names).encode())
    return h.hexdigest()


def provenance(
    specs: Sequence[SpecFile],
    argv: Sequence[str] | None = None,
    seeds: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Who made a results file, how and when: tool version, command line, date, specs."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        tool = version("lesmc")
    except PackageNotFoundError:  # pragma: no cover - a bare checkout
        tool = "unknown"
    return {
        "tool": "lesmc",
        "tool_version": tool,
        "python": platform.python_version(),
        "command": list(sys.argv if argv is None else argv),
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "seeds": dict(seeds or {}),
        "specs": [{"path": s.path, "text": s.text} for s in specs],
    }


def _property_json(bp: BoundProperty, components: tuple[str, ...]) -> dict[str, Any]:
    c = bp.constraint
    monitor = None
    if bp.monitor_components is not None:
        monitor = {
            "components": [components[i] for i in bp.monitor_components],
            "tolerance": bp.monitor_tolerance,
            "except_original": bp.monitor_except_original,
        }
    return {
        "name": bp.name,
        "window": [bp.l, bp.u],
        "end": bp.end,
        "objective": bp.objective.text,
        "objective_source": bp.objective.source,
        "constraint": f"{c.text} {bp.op} {bp.bound:g}",
        "constraint_source": c.source,
        "constraint_aggregate": c.aggregate,
        "constraint_range": [c.lo, c.hi],
        "bound": bp.bound,
        "components": [components[i] for i in bp.components],
        "norm": num(bp.norm),
        "monitor": monitor,
    }


def _alarm_steps(model: LTS, path: TrackPath, bp: BoundProperty) -> list[int]:
    """Steps l..end where the property's monitor counts an alarm on this path (Eq. 13)."""
    if bp.monitor_components is None:
        return []
    taus = tau_series(model, path, bp.monitor_components)
    orig = np.array([tau_of(model, q, bp.monitor_components) for q in model.original])
    excused = (
        kernel.original_alarms(orig, bp.monitor_tolerance)
        if bp.monitor_except_original
        else np.zeros(len(orig), dtype=bool)
    )
    ks = np.arange(max(bp.l, 1), min(len(taus), bp.end + 1))
    fired = kernel.alarm(taus[ks - 1], taus[ks], bp.monitor_tolerance)
    return [int(k) for k, f in zip(ks, fired, strict=True) if f and not excused[k]]


def tau_of(model: LTS, sid: str, components: tuple[int, ...]) -> float:
    """τ (Eq. 12) of one state over ``components``; nan without a covariance."""
    P = model.state(sid).P
    if P is None:
        return math.nan
    idx = [c for c in components if c < len(P)]
    return float(kernel.tau(np.asarray(P), idx))


def _hidden(
    model: LTS, path: TrackPath, scene: Scene | None, window: tuple[int, int]
) -> list[dict[str, Any]]:
    """The detections the attacker hides on a path: at each attacked step, the observations of
    the transitions ranked before the one taken (Eq. 5), with their positions and payoffs."""
    out: list[dict[str, Any]] = []
    first = int(model.meta.get("first_frame", 0))
    for k, t in enumerate(path.transitions, start=1):
        if not window[0] <= k <= window[1]:
            continue
        for o in model.out(t.src):
            if o.rank >= t.rank or o.obs is None:
                continue
            item: dict[str, Any] = {"step": k, "frame": first + k, "obs": o.obs, "payoff": o.payoff}
            if scene is not None and first + k <= scene.last_step:
                for d in scene.frame(first + k).detections:
                    if d.id == o.obs:
                        item["x"], item["y"] = d.x, d.y
                        if d.payoff_lower is not None:
                            item["payoff_lower"] = num(d.payoff_lower)
            out.append(item)
    return out


def _scene_part(
    model: LTS, scene: Scene, paths: list[TrackPath], ref: int
) -> dict[str, Any] | None:
    """Detections near the listed tracks per step and each step's homography to step ``ref``."""
    first = int(model.meta.get("first_frame", 0))
    end = model.end
    if first + end > scene.last_step or first < scene.frames[0].step:
        return None
    nxt = []
    for k in range(end):
        m = scene.frame(first + k).to_next
        nxt.append(np.eye(3) if m is None else np.asarray(m, float))
    to_ref = [np.eye(3)] * (end + 1)
    for k in range(ref - 1, -1, -1):  # earlier steps: forward through to_next
        to_ref[k] = to_ref[k + 1] @ nxt[k]
    for k in range(ref + 1, end + 1):  # later steps: backward
        to_ref[k] = to_ref[k - 1] @ np.linalg.inv(nxt[k - 1])
    dets = []
    for k in range(end + 1):
        here = np.array([position(model, p.states[k]) for p in paths if k < len(p.states)])
        frame = scene.frame(first + k)
        pos = frame.positions()
        keep = []
        if len(pos) and len(here):
            d = np.min(np.linalg.norm(pos[:, None, :] - here[None, :, :], axis=-1), axis=1)
            keep = np.nonzero(d <= NEAR_PX)[0].tolist()
        dets.append(
            [
                [
                    float(pos[j, 0]),
                    float(pos[j, 1]),
                    frame.detections[j].id,
                    num(frame.detections[j].payoff),
                ]
                for j in keep
            ]
        )
    return {
        "first_frame": first,
        "ref_step": ref,
        "to_ref": [np.round(h, 12).tolist() for h in to_ref],
        "detections": dets,
    }


def run_json(
    run: DesignRun, truth: list[list[float]] | None = None, limit: int = MAX_PATHS
) -> dict[str, Any]:
    """One design run as the results document holds it."""
    model = run.model
    win = window_of(run.bound)
    wanted: list[tuple[str, ...]] = [tuple(model.original)]
    for r in run.results:
        for info in (r.counterexample, r.witness):
            if info is not None:
                wanted.append(complete(model, info.states))
    ps: PathSet = enumerate_tracks(model, win, limit, first=wanted)
    number = {p.states: i + 1 for i, p in enumerate(ps.paths)}

    def find(p: PathInfo | None) -> int | None:
        return None if p is None else number.get(complete(model, p.states))

    judged = [[judge(model, p, bp) for p in ps.paths] for bp in run.bound]
    paths = []
    for i, p in enumerate(ps.paths):
        paths.append(
            {
                "no": i + 1,
                "states": list(p.states),
                "labels": p.labels(),
                "obs": [t.obs for t in p.transitions],
                "payoff": num(p.payoff),
                "dist_sum": num(p.dist_sum),
                "dist_max": num(p.dist_max),
                "dist_end": num(p.dist_end),
                "halted": len(p.states) < model.end + 1,
                "judged": [
                    {
                        "objective": num(js[i].objective),
                        "constraint": num(js[i].constraint),
                        "violates": js[i].violates,
                        "admissible": js[i].admissible,
                        "alarms": _alarm_steps(model, p, bp),
                    }
                    for js, bp in zip(judged, run.bound, strict=True)
                ],
            }
        )
    on_paths = sorted({q for p in ps.paths for q in p.states})
    states = {
        q: {
            "step": model.state(q).step,
            "s": [float(v) for v in np.asarray(model.state(q).s, float)],
            "tau": num(tau_of(model, q, kernel.LOCATION)),
        }
        for q in on_paths
    }
    adversarial, recomputed = {}, {}
    for bp, js in zip(run.bound, judged, strict=True):
        bad = [j for j in js if j.admissible and j.violates and not j.alarmed]
        adversarial[bp.name] = len(bad)
        recomputed[bp.name] = num(min((j.objective for j in bad), default=math.inf))
    cex = [find(r.counterexample) for r in run.results]
    by_no = {i + 1: p for i, p in enumerate(ps.paths)}
    hidden = {
        bp.name: _hidden(model, by_no[n], run.scene, (bp.l, bp.u))
        for bp, n in zip(run.bound, cex, strict=True)
        if n is not None
    }
    scene = None
    if run.scene is not None and model.components[:2] == ("x", "y"):
        scene = _scene_part(model, run.scene, ps.paths, win[1])
    return {
        "design": run.name,
        "tracker": None if run.scene is None else run.scene.tracker.design,
        "model": {
            "states": model.graph.number_of_nodes(),
            "transitions": model.graph.number_of_edges(),
            "end": model.end,
            "components": list(model.components),
            "first_frame": int(model.meta.get("first_frame", 0)),
            "built_window": model.meta.get("window"),
            "sha256": model_hash(model),
        },
        "window": list(win),
        "properties": [_property_json(bp, model.components) for bp in run.bound],
        "results": [r.to_json() for r in run.results],
        "roles": {
            "original": number.get(tuple(model.original)),
            "counterexample": cex,
            "witness": [find(r.witness) for r in run.results],
        },
        "adversarial_tracks": adversarial,
        "recomputed_optimum": recomputed,
        "paths_total": ps.total,
        "paths": paths,
        "states": states,
        "hidden": hidden,
        "scene": scene,
        "truth": truth,
        "replay_inputs": None if run.scene is None else replay_inputs(run.scene),
    }


def replay_inputs(scene: Scene) -> dict[str, Any]:
    """What ``lesmc replay`` needs of a run's scene besides the frames (lesmc/replay.py)."""
    t = scene.target
    return {
        "tracker": scene.tracker.to_json(),
        "dt": scene.dt,
        "target": {"step": t.step, "start": list(t.start), "velocity": list(t.velocity)},
    }


def payoff_unit(runs: Sequence[DesignRun]) -> str:
    """What one unit of payoff is, as far as the scene says (docs/cnn.md)."""
    scenes = [r.scene for r in runs if r.scene is not None]
    if not scenes:
        return "as in the model file (a .lts model does not say)"
    attack = scenes[0].meta.get("attack")
    norm = attack.get("norm") if isinstance(attack, dict) else None
    if norm == "per-pixel":
        return "L2 norm of the perturbation of N_dr's input, pixels in [0, 1], divided by 441"
    if norm in (None, "l2") and ("detector" in scenes[0].meta or norm == "l2"):
        return "L2 norm of the perturbation of N_dr's input window, pixels in [0, 1]"
    return "as in the scene file (its meta does not say)"


def results_document(
    runs: Sequence[DesignRun],
    meta: dict[str, Any],
    prov: dict[str, Any],
    timings: dict[str, float] | None = None,
    truth: list[list[float]] | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole results file (``lesmc-results``, version 1; lesmc/schemas/results.json)."""
    meta = dict(meta)
    meta.setdefault("payoff unit", payoff_unit(runs))
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "provenance": prov,
        "meta": {k: str(v) for k, v in meta.items()},
        "timings": {k: round(float(v), 3) for k, v in (timings or {}).items()},
        "runs": [run_json(r, truth) for r in runs],
    }
    doc["provenance"]["model_sha256"] = {r["design"]: r["model"]["sha256"] for r in doc["runs"]}
    doc.update(extra or {})
    return doc
