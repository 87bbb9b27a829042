"""The results stage: a verification's typed results as one versioned document.

``results.json`` (format ``lesmc-results``, lesmc/schemas/results.json) holds
everything the report draws and the replay needs, computed once here from the
pipeline's :class:`~lesmc.results.record.Results`: per design run the check
results (verdict, optimum, bounds, the comparisons as data, counterexample and
witness with their per-step deviations), the attacked tracks with their Table 3
measures and how each property judges them (lesmc/results/tracks.py), the
states on those tracks (estimate, τ, position in the figures' frame), the
detections near them, the hidden detections of each counterexample, and the
provenance. The report (lesmc/report) and the replay (lesmc/replay) read this
document alone; they compute no measure of their own.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np

from lesmc.designs import registry
from lesmc.engines.result import PathInfo, status_word
from lesmc.engines.space import build_space
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.model import kernel
from lesmc.model.arrays import ArrayModel
from lesmc.model.lts_format import lts_to_dict
from lesmc.results import tracks
from lesmc.results.record import DesignRun, Results
from lesmc.results.tracks import Track
from lesmc.scene import Scene
from lesmc.scene.frames import warp

FORMAT = "lesmc-results"
VERSION = 2

#: Paths listed in a results file at most (the report says how many exist in all).
MAX_PATHS = 20000
#: Detections kept per step: those within this many pixels of a listed track.
NEAR_PX = 160.0


def num(x: float | None) -> float | str | None:
    """JSON has no infinity: "inf"/"-inf" as strings (docs/cli.md, "Numbers")."""
    if x is None or math.isnan(x):
        return None
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return float(x)


def model_hash(cm: ArrayModel) -> str:
    """sha256 of the model as its ``.lts`` file holds it (canonical JSON of
    :func:`~lesmc.model.lts_format.lts_to_dict`): the same for a model built and
    for that model written and read back, whatever the order of its rows."""
    text = json.dumps(lts_to_dict(cm), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def provenance(
    specs: Sequence[SpecFile],
    argv: Sequence[str] | None = None,
    seeds: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Who made a results file, how and when: tool version, command line, date, specs."""

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


def property_json(bp: BoundProperty, components: tuple[str, ...]) -> dict[str, Any]:
    """A bound property as data: its window, measures, comparisons and monitor; the
    attacker's actions when not hide only (``allow hide, inject``: the replay reads them)."""
    c = bp.constraint
    monitor = None
    if bp.monitor_components is not None:
        monitor = {
            "components": [components[i] for i in bp.monitor_components],
            "tolerance": bp.monitor_parameter,
            "except_original": bp.monitor_except_original,
            "kind": bp.monitor_kind,
            "parameter": bp.monitor_parameter,
            "window": bp.monitor_window,
        }
    return (
        {
            "name": bp.name,
            "spec": bp.spec,
            "window": [bp.l, bp.u],
            "end": bp.end,
            "objective": bp.objective.text,
            "objective_source": bp.objective.source,
            "constraint": f"{c.text} {bp.op} {bp.bound:g}",
            "constraint_source": c.source,
            "constraint_aggregate": c.aggregate,
            "constraint_range": [c.lo, c.hi],
            "constraint_op": bp.op,
            "bound": bp.bound,
            "holds_op": bp.prop.holds_op,
            "threshold": bp.prop.threshold,
            "components": [components[i] for i in bp.components],
            "norm": num(bp.norm),
            "monitor": monitor,
        }
        | ({} if bp.prop.actions == ("hide",) else {"actions": list(bp.prop.actions)})
        | _grid_json(bp)
    )


def _grid_json(bp: BoundProperty) -> dict[str, Any]:
    """``inject grid D within R payoff P`` as data (a replay skips such a property: its
    grid points are a modelling device, not places on the frames)."""
    g = bp.prop.grid
    if g is None:
        return {}
    return {"inject_grid": {"spacing": g.spacing, "radius": g.radius, "payoff": g.payoff}}


def _path_no(cm: ArrayModel, number: dict[tuple[int, ...], int], p: PathInfo | None) -> int | None:
    """The row of Table 3 that a result's path (extended to the model's end) is."""
    if p is None:
        return None
    return number.get(tracks.complete(cm, tuple(cm.index(s) for s in p.states)))


def _track_json(
    cm: ArrayModel, no: int, tr: Track, window: tuple[int, int], judged: list[tracks.Judged]
) -> dict[str, Any]:
    """One row of Table 3: the track, its measures, and how each property judges it."""
    dist = tracks.deviations(cm, tr)
    obs = [cm.obs_of(t) for t in tr.transitions]
    return {
        "no": no,
        "states": [cm.state_id(q) for q in tr.states],
        "labels": ["0-start", *(f"{k}-{_short(o)}" for k, o in enumerate(obs, start=1))],
        "obs": obs,
        "payoff": num(tracks.payoff(cm, tr, window)),
        "dist_sum": num(kernel.exact_sum(dist.tolist())),
        "dist_max": num(float(dist.max())),
        "dist_end": num(float(dist[-1])),
        "halted": len(tr.states) < cm.end + 1,
        "judged": [
            {
                "objective": num(j.objective),
                "constraint": num(j.constraint),
                "violates": j.violates,
                "admissible": j.admissible,
                "alarms": list(j.alarms),
            }
            for j in judged
        ],
    }


def _short(obs: str | None) -> str:
    return "none" if obs is None else obs.split(":")[-1]


def _hidden(
    cm: ArrayModel,
    tr: Track,
    scene: Scene | None,
    window: tuple[int, int],
    attack_of: Callable[[int, int, int], tuple[list[str], list[str]]] | None = None,
) -> list[dict[str, Any]]:
    """The detections the attacker hides on a track: at each attacked step, the observations
    of the transitions ranked before the one taken (Eq. 5), with positions and payoffs.
    Under inject the ranks are ordered by cost, not by distance (docs/semantics.md): the
    tracker says what the cheapest way hides (``attack_of``), else nothing is listed."""
    if "inject" in cm.meta.get("actions", ()):
        return [] if attack_of is None else _hidden_by(cm, tr, scene, window, attack_of)
    out: list[dict[str, Any]] = []
    first = int(cm.meta.get("first_frame", 0))
    for k, t in enumerate(tr.transitions, start=1):
        if not window[0] <= k <= window[1]:
            continue
        src = tr.states[k - 1]
        for o in cm.out(src):
            if cm.rank[o] >= cm.rank[t] or cm.obs_of(o) is None:
                continue
            item: dict[str, Any] = {
                "step": k,
                "frame": first + k,
                "obs": cm.obs_of(o),
                "payoff": num(float(cm.payoff[o])),
            }
            item |= _detection_facts(scene, first + k, str(cm.obs_of(o)))
            out.append(item)
    return out


def _hidden_by(
    cm: ArrayModel,
    tr: Track,
    scene: Scene | None,
    window: tuple[int, int],
    attack_of: Callable[[int, int, int], tuple[list[str], list[str]]],
) -> list[dict[str, Any]]:
    """:func:`_hidden` under inject: the detections ``attack_of`` says the cheapest way to
    each attacked step's outcome hides, with their own payoffs from the scene."""
    return _attacked(cm, tr, scene, window, attack_of, 0)


def _injected(
    cm: ArrayModel,
    tr: Track,
    scene: Scene | None,
    window: tuple[int, int],
    attack_of: Callable[[int, int, int], tuple[list[str], list[str]]] | None,
) -> list[dict[str, Any]]:
    """The candidates the attacker injects on a track (``attack_of``: the cheapest way to
    each attacked step's outcome), with positions and payoffs; none without inject."""
    if attack_of is None or "inject" not in cm.meta.get("actions", ()):
        return []
    return _attacked(cm, tr, scene, window, attack_of, 1)


def _attacked(
    cm: ArrayModel,
    tr: Track,
    scene: Scene | None,
    window: tuple[int, int],
    attack_of: Callable[[int, int, int], tuple[list[str], list[str]]],
    which: int,
) -> list[dict[str, Any]]:
    """The detections hidden (``which`` 0) or the candidates injected (1) at each attacked
    step of a track, by ``attack_of``, with their payoffs and positions from the scene."""
    out: list[dict[str, Any]] = []
    first = int(cm.meta.get("first_frame", 0))
    for k, t in enumerate(tr.transitions, start=1):
        if not window[0] <= k <= window[1]:
            continue
        ids = attack_of(int(tr.states[k - 1]), k, int(cm.rank[t]))[which]
        items = () if scene is None else scene.frame(first + k).detections
        if which and scene is not None:
            items = scene.frame(first + k).candidates
        pay = {d.id: d.payoff for d in items}
        if which and "inject_grid" in cm.meta:  # a grid point (single): the grid's payoff
            pay |= {o: float(cm.meta["inject_grid"]["payoff"]) for o in ids if ":grid" in o}
        for obs in ids:
            item: dict[str, Any] = {"step": k, "frame": first + k, "obs": obs}
            item["payoff"] = num(float(pay.get(obs, math.nan)))
            out.append(item | _detection_facts(scene, first + k, obs, which == 1))
    return out


def _detection_facts(
    scene: Scene | None, frame: int, obs: str, candidate: bool = False
) -> dict[str, Any]:
    """Where a detection (``candidate``: an injection candidate) of the scene is and its
    certified lower payoff, if known."""
    if scene is None or frame > scene.last_step:
        return {}
    f = scene.frame(frame)
    for d in f.candidates if candidate else f.detections:
        if d.id == obs:
            out: dict[str, Any] = {"x": d.x, "y": d.y}
            if d.payoff_lower is not None:
                out["payoff_lower"] = num(d.payoff_lower)
            return out
    return {}


def _to_ref(scene: Scene, first: int, end: int, ref: int) -> list[np.ndarray]:
    """Per step 0..end, the homography carrying that step's pixels into step ``ref``'s."""
    nxt = []
    for k in range(end):
        m = scene.frame(first + k).to_next
        nxt.append(np.eye(3) if m is None else np.asarray(m, float))
    to_ref = [np.eye(3)] * (end + 1)
    for k in range(ref - 1, -1, -1):  # earlier steps: forward through to_next
        to_ref[k] = to_ref[k + 1] @ nxt[k]
    for k in range(ref + 1, end + 1):  # later steps: backward
        to_ref[k] = to_ref[k - 1] @ np.linalg.inv(nxt[k - 1])
    return to_ref


def _scene_part(
    cm: ArrayModel,
    scene: Scene,
    listed: list[Track],
    ref: int,
    truth: list[list[float]] | None,
    loc: tuple[int, int],
) -> tuple[dict[str, Any], list[np.ndarray]] | None:
    """Detections near the listed tracks per step (with their position in the pixels of step
    ``ref``), the target's true track there, and each step's homography to step ``ref``."""
    first, end = int(cm.meta.get("first_frame", 0)), cm.end
    if first + end > scene.last_step or first < scene.frames[0].step:
        return None
    to_ref = _to_ref(scene, first, end, ref)
    dets = []
    for k in range(end + 1):
        here = np.array([cm.S[t.states[k]][list(loc)] for t in listed if k < len(t.states)])
        frame = scene.frame(first + k)
        pos = frame.positions()
        keep: list[int] = []
        if len(pos) and len(here):
            d = np.min(np.linalg.norm(pos[:, None, :] - here[None, :, :], axis=-1), axis=1)
            keep = np.nonzero(d <= NEAR_PX)[0].tolist()
        ref_xy = warp(to_ref[k], pos[keep]) if keep else np.zeros((0, 2))
        dets.append(
            [
                [
                    float(pos[j, 0]),
                    float(pos[j, 1]),
                    frame.detections[j].id,
                    num(frame.detections[j].payoff),
                    float(rx),
                    float(ry),
                ]
                for j, (rx, ry) in zip(keep, ref_xy.tolist(), strict=True)
            ]
        )
    truth_ref = None
    if truth:
        truth_ref = [
            None if p is None else [float(v) for v in warp(to_ref[k], np.array(p, float))]
            for k, p in enumerate(truth[: end + 1])
        ]
    return {
        "first_frame": first,
        "ref_step": ref,
        "detections": dets,
        "truth_ref": truth_ref,
    }, to_ref


def _states_json(
    cm: ArrayModel,
    listed: list[Track],
    to_ref: list[np.ndarray] | None,
    loc: tuple[int, int],
) -> dict[str, Any]:
    """The states on the listed tracks: step, estimate, τ (Eq. 12, over the location
    components ``loc``) and, when the scene says where step k's pixels lie in the figures'
    frame, the position there."""
    on_paths = sorted({q for t in listed for q in t.states})
    taus = (
        kernel.tau(cm.P_table, loc)[cm.cov]
        if cm.cov is not None and cm.P_table is not None and cm.S.shape[1] >= 2
        else np.full(cm.n_states, np.nan)
    )
    out = {}
    for q in on_paths:
        k = int(cm.step[q])
        item: dict[str, Any] = {
            "step": k,
            "s": [float(v) for v in cm.S[q]],
            "tau": num(float(taus[q])),
        }
        if to_ref is not None:
            item["ref"] = [float(v) for v in warp(to_ref[k], cm.S[q][list(loc)])]
        out[cm.state_id(q)] = item
    return out


def run_json(
    run: DesignRun, truth: list[list[float]] | None = None, limit: int = MAX_PATHS
) -> dict[str, Any]:
    """One design run as the results document holds it (its whole model must be built)."""
    cm = run.model
    assert cm is not None, "the results document draws the whole model: build it (full_models)"
    win = (min(bp.l for bp in run.bound), max(bp.u for bp in run.bound))
    wanted = [tuple(int(q) for q in cm.original)]
    for r in run.results:
        for info in (r.cheapest, r.witness):
            if info is not None:
                wanted.append(tracks.complete(cm, tuple(cm.index(s) for s in info.states)))
    listed = tracks.enumerate_tracks(cm, limit, wanted)
    number = {t.states: i + 1 for i, t in enumerate(listed)}
    spaces = [build_space(cm, bp) for bp in run.bound]
    judged = [[tracks.judge(sp, t) for sp in spaces] for t in listed]
    cex = [_path_no(cm, number, r.cheapest) for r in run.results]
    scene_part, to_ref = None, None
    loc: tuple[int, int] = kernel.LOCATION
    if run.scene is not None and cm.components == run.scene.tracker.state_names:
        loc = run.scene.tracker.measured
        got = _scene_part(cm, run.scene, listed, win[1], truth, loc)
        if got is not None:
            scene_part, to_ref = got
    return {
        "design": run.design,
        "label": run.label,
        "tracker": None if run.scene is None else run.scene.tracker.design,
        "model": {
            "states": cm.n_states,
            "transitions": cm.n_transitions,
            "end": cm.end,
            "components": list(cm.components),
            "first_frame": int(cm.meta.get("first_frame", 0)),
            "built_window": cm.meta.get("window"),
            "sha256": model_hash(cm),
        },
        "window": list(win),
        "properties": [property_json(bp, cm.components) for bp in run.bound],
        "results": [r.to_dict() for r in run.results],
        "faults": [
            {"property": property_json(bp, cm.components), "result": r.to_dict()}
            for bp, r in zip(run.fault_bound, run.fault_results, strict=True)
        ],
        "roles": {
            "original": number.get(wanted[0]),
            "counterexample": cex,
            "witness": [_path_no(cm, number, r.witness) for r in run.results],
        },
        "paths_total": tracks.count_paths(cm),
        "paths": [_track_json(cm, i + 1, t, win, judged[i]) for i, t in enumerate(listed)],
        "states": _states_json(cm, listed, to_ref, loc),
        **_attacks_json(run, cm, listed, cex),
        "scene": scene_part,
        "replay_inputs": None if run.scene is None else replay_inputs(run.scene),
    }


def _attacks_json(
    run: DesignRun, cm: ArrayModel, listed: list[Track], cex: list[int | None]
) -> dict[str, Any]:
    """Per property with a counterexample (path ``cex`` of ``listed``): the detections it
    hides (``hidden``) and, under inject, the candidates it injects (``injected``)."""
    with_cex = [(bp, listed[n - 1]) for bp, n in zip(run.bound, cex, strict=True) if n]
    return {
        "hidden": {
            bp.name: _hidden(cm, tr, run.scene, (bp.l, bp.u), run.attack_of) for bp, tr in with_cex
        },
        "injected": {
            bp.name: _injected(cm, tr, run.scene, (bp.l, bp.u), run.attack_of)
            for bp, tr in with_cex
            if "inject" in bp.prop.actions
        },
    }


def replay_inputs(scene: Scene) -> dict[str, Any]:
    """What ``lesmc replay`` needs of a run's scene besides the frames (lesmc/replay)."""
    t = scene.target
    off = scene.meta.get("frames_offset", 0)
    return {
        "tracker": scene.tracker.to_json(),
        "dt": scene.dt,
        "target": {"step": t.step, "start": list(t.start), "velocity": list(t.velocity)},
    } | ({"frames_offset": off} if isinstance(off, int) and off else {})


#: What a payoff made by perception is (docs/cnn.md).
#: A full-frame detector's payoffs (a detector file: lesmc/perception/heatmap_attack.py).
FRAME_ATTACK_PAYOFF = (
    "the size of the perturbation the attack found that makes the detector file's network "
    "lose the detection in the decoded frame (an upper bound on the cheapest one)"
)
ATTACK_PAYOFF = (
    "the size of the perturbation the attack found that makes N_dr miss the detection (an "
    "upper bound on the cheapest one)"
)


def payoff_source(runs: Sequence[DesignRun]) -> str:
    """Where the detections' payoffs came from, as the scene's ``meta`` says: an attack on
    N_dr (a scene made by perception), or what ``lesmc import mot`` read (``meta.payoffs``:
    a column of the det.txt or a constant)."""
    scenes = [r.scene for r in runs if r.scene is not None]
    if not scenes:
        return "as in the model file (a .lts model does not say where they came from)"
    meta = scenes[0].meta
    given = meta.get("payoffs")
    if isinstance(given, str) and given:
        where = meta.get("source")
        return (
            given
            + (f", {where}" if isinstance(where, str) and where else "")
            + (
                "; not the cost of an attack on a detector"
                if meta.get("format") == "MOTChallenge"
                else ""
            )
        )
    attack = meta.get("attack")
    if isinstance(attack, dict) and isinstance(meta.get("detector_file"), dict):
        method = attack.get("method")
        return FRAME_ATTACK_PAYOFF + (f", by {method}" if isinstance(method, str) else "")
    if isinstance(attack, dict) or meta.get("detector"):
        method = attack.get("method") if isinstance(attack, dict) else None
        return ATTACK_PAYOFF + (f", by {method}" if isinstance(method, str) else "")
    return "as in the scene file (its meta does not say where they came from)"


def payoff_unit(runs: Sequence[DesignRun]) -> str:
    """What one unit of payoff is, as far as the scene says (docs/cnn.md)."""
    scenes = [r.scene for r in runs if r.scene is not None]
    if not scenes:
        return "as in the model file (a .lts model does not say)"
    if isinstance(scenes[0].meta.get("payoffs"), str):  # lesmc import mot's
        return "as the payoff source gives them (not an attack's perturbation size)"
    attack = scenes[0].meta.get("attack")
    if isinstance(scenes[0].meta.get("detector_file"), dict):
        return "L2 norm of the perturbation of the detector file's network input, in its units"
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
    """The whole results file (``lesmc-results``; lesmc/schemas/results.json)."""
    meta = dict(meta)
    meta.setdefault("payoff unit", payoff_unit(runs))
    meta.setdefault("payoff source", payoff_source(runs))
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "provenance": prov,
        "meta": {k: str(v) for k, v in meta.items()},
        "timings": {k: round(float(v), 3) for k, v in (timings or {}).items()},
        "designs": {d: registry.label(d) for d in dict.fromkeys(r.design for r in runs)},
        "runs": [run_json(r, truth) for r in runs],
    }
    doc["provenance"]["model_sha256"] = {r["design"]: r["model"]["sha256"] for r in doc["runs"]}
    doc.update(extra or {})
    return doc


def record_replays(
    doc: dict[str, Any],
    replays: Mapping[tuple[int, int], dict[str, Any]],
    seconds: float,
    results: Results | None = None,
) -> None:
    """Record each replay object (lesmc/replay/run.py) of result ``(run, result)`` in the
    document (and in the typed ``results`` it was written from, if given): the status, and
    for a diverged counterexample (no proof) the verdict ``unknown`` with a note, unless its
    replayed run violates the property all the same (``on_frames``: ``violated``, with a
    note); the model's optimum stays in the bounds."""
    for (i, j), obj in replays.items():
        res = doc["runs"][i]["results"][j]
        res["replay"] = obj
        if obj["status"] == "diverged" and res["verdict"] == "violated":
            on = obj.get("on_frames") or {}
            if on.get("violated"):  # another path, real and costed: lesmc/replay/on_frames.py
                res["notes"].append(f"{on['why']} (the path diverges at step {obj['step']})")
            else:
                res["verdict"] = "unknown"
                res["notes"].append(diverged_note(res["optimum"], obj))
        res["status"] = status_word(res["verdict"], res["vacuous"], obj["status"])
        if results is not None:
            run = results.runs[i]
            run.results[j] = replace(
                run.results[j],
                verdict=res["verdict"],
                notes=list(res["notes"]),
                replay=obj["status"],
            )
    doc["replay"] = {"replayed": len(replays), "seconds": round(seconds, 3)}


def diverged_note(optimum: Any, obj: Mapping[str, Any]) -> str:
    """The note of a result whose counterexample did not replay (and what its replayed run
    says of the property, when judged: ``on_frames``)."""
    on = obj.get("on_frames")
    return (
        f"unknown: the model's counterexample (optimum {optimum}) did not replay through the "
        f"detector and tracker; it diverges at step {obj['step']} ({obj['reason']}); "
        "not a proof of violation" + ("" if on is None else f"; {on['why']}")
    )
