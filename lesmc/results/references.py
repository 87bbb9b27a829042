"""What the results schema cannot say: that a results file's ids refer to each other.

The schema (lesmc/schemas/results.json) checks each value on its own; the report and
the replay also follow references between them: a path's state ids into the run's
``states``, ``roles`` into the numbered ``paths``, a result's property into the run's
``properties``, the hidden detections into the scene's. A file edited or cut by hand
could break one of them; :func:`check_references` reports every broken reference as
``FILE:LINE:COL: item: message``, so that nothing downstream meets a missing key.
"""

from __future__ import annotations

import math
from typing import Any

from lesmc.common.errors import Problems, clipped
from lesmc.common.fields import within
from lesmc.common.locations import error_in_file
from lesmc.scene.io import MAX_COORD, MAX_DT
from lesmc.scene.tracker_file import tracker_block

#: |coordinate| of a drawn box or position: detections lie within MAX_COORD, a track
#: coasting past them a little beyond; far beyond, the report's view overflows
MAX_DRAWN = 100 * MAX_COORD


def check_references(doc: dict[str, Any], path: str, text: str | None = None) -> None:
    """Raise one :class:`InputError` listing every broken reference of ``doc`` (given the
    JSON ``text`` it was read from, each at its ``FILE:LINE:COL``)."""
    pr = Problems()
    seen: dict[str, int] = {}
    for i, run in enumerate(doc["runs"]):
        at = f"runs[{i}]"
        if run["design"] in seen:
            pr.add(f"{at}.design", f"'{run['design']}' is also runs[{seen[run['design']]}]")
        seen.setdefault(run["design"], i)
        _run(run, at, pr)
    if pr.items:
        raise error_in_file(path, pr.items, text)


def _run(run: dict[str, Any], at: str, pr: Problems) -> None:
    states, names = run["states"], [p["name"] for p in run["properties"]]
    if len(run["results"]) != len(names):
        pr.add(f"{at}.results", f"{len(run['results'])} results for {len(names)} properties")
    for j, res in enumerate(run["results"]):
        if res["property"] not in names:
            pr.add(f"{at}.results[{j}].property", f"'{res['property']}' is not a property")
        for kind in ("counterexample", "witness"):
            if res.get(kind) is not None:
                _path(res[kind], f"{at}.results[{j}].{kind}", states, pr)
    for k, p in enumerate(run["paths"]):
        if p["no"] != k + 1:
            pr.add(f"{at}.paths[{k}].no", f"must be {k + 1} (paths are numbered in order)")
        _ids(p["states"], f"{at}.paths[{k}].states", states, pr)
        _drawable(p, f"{at}.paths[{k}]", states, pr)
    _roles(run["roles"], f"{at}.roles", len(run["paths"]), len(run["results"]), pr)
    if not pr.items:
        _steps_follow_paths(run, at, pr)
    for key in ("hidden", "injected"):
        for name in run.get(key) or {}:
            if name not in names:
                pr.add(f"{at}.{key}.{name}", "is not a property of the run")
    _replay_inputs(run, at, pr)


def _path(info: dict[str, Any], at: str, states: dict[str, Any], pr: Problems) -> None:
    """A counterexample or witness: its states known, one step per state, a deviation for
    each state (and +inf for each later step, after a halt: engines/result.py)."""
    _ids(info["states"], f"{at}.states", states, pr)
    n = len(info["states"])
    if "steps" in info and len(info["steps"]) != n:
        pr.add(f"{at}.steps", f"has {len(info['steps'])} entries for {n} states")
    if "deviation" in info and len(info["deviation"]) < n:
        pr.add(f"{at}.deviation", f"has {len(info['deviation'])} entries for {n} states")


def _ids(ids: list[str], at: str, states: dict[str, Any], pr: Problems) -> None:
    unknown = [q for q in ids if q not in states]
    if unknown:
        pr.add(at, f"state '{unknown[0]}' is not in the run's states")


def _drawable(p: dict[str, Any], at: str, states: dict[str, Any], pr: Problems) -> None:
    """A listed path as the report draws it: a label per state, and a position in the
    reference frame (``ref``) for every state or for none."""
    if len(p["labels"]) != len(p["states"]):
        pr.add(f"{at}.labels", f"has {len(p['labels'])} entries for {len(p['states'])} states")
    if any(q not in states for q in p["states"]):
        return  # an unknown state: said by _ids
    placed = [states[q].get("ref") is not None for q in p["states"]]
    if any(placed) and not all(placed):
        m = placed.index(False)
        pr.add(
            f"{at}.states[{m}]",
            f"state '{clipped(str(p['states'][m]))}' has no ref (its position in the "
            "reference frame), but other states of the path have one",
        )


def _roles(roles: dict[str, Any], at: str, n_paths: int, n_results: int, pr: Problems) -> None:
    """Path numbers in 1..n_paths; one counterexample and one witness per result."""
    numbers = [("original", roles["original"])]
    for kind in ("counterexample", "witness"):
        if len(roles[kind]) != n_results:
            pr.add(f"{at}.{kind}", f"has {len(roles[kind])} entries for {n_results} results")
        numbers += [(f"{kind}[{j}]", no) for j, no in enumerate(roles[kind])]
    for item, no in numbers:
        if no is not None and not 1 <= no <= n_paths:
            pr.add(f"{at}.{item}", f"path {no} is not one of the run's {n_paths} paths")


def _steps_follow_paths(run: dict[str, Any], at: str, pr: Problems) -> None:
    """Each result's counterexample and witness steps take the measurements (``obs``) of the
    listed path its role names (the replay and the report read the path, a table the
    steps: a step edited alone would show one attack and replay another)."""
    for kind in ("counterexample", "witness"):
        for j, no in enumerate(run["roles"][kind]):
            info = run["results"][j].get(kind)
            if no is None or info is None or "steps" not in info:
                continue
            obs = [None, *run["paths"][no - 1]["obs"]]
            for k, step in enumerate(info["steps"][: len(obs)]):
                if step.get("obs") != obs[k]:
                    pr.add(
                        f"{at}.results[{j}].{kind}.steps[{k}].obs",
                        f"is {_shown(step.get('obs'))}, but the {kind}'s path "
                        f"(paths[{no - 1}].obs[{k - 1}]) takes {_shown(obs[k])}",
                    )
                    break


def _shown(obs: Any) -> str:
    """A step's measurement as an error names it: ``'2:c0'``, or ``none`` (no update)."""
    return "none" if obs is None else f"'{clipped(str(obs))}'"


def _replay_inputs(run: dict[str, Any], at: str, pr: Problems) -> None:
    """The replay's time step as a scene's (0 < dt <= MAX_DT); the scene part's detections
    as [x, y, id, payoff, x_ref, y_ref]; the tracker as a scene's ``tracker`` block
    (lesmc/scene/tracker_file.py, which the replay reads it with after perceiving).
    (A hidden detection may lie outside the scene part, which keeps only the detections
    near a listed track.)"""
    rp, scene = run.get("replay_inputs"), run.get("scene")
    if rp is not None and not (_number(rp["dt"]) and 0 < rp["dt"] <= MAX_DT):
        pr.add(f"{at}.replay_inputs.dt", f"must be a number in (0, {MAX_DT:g}]")
    if rp is not None and "tracker" in rp:
        tracker_block(rp["tracker"], pr, f"{at}.replay_inputs.tracker")
    if scene is None:
        return
    for k, step in enumerate(scene["detections"]):
        for m, d in enumerate(step):
            if not (isinstance(d[2], str) and all(_number(d[c]) for c in (0, 1, 4, 5))):
                pr.add(
                    f"{at}.scene.detections[{k}][{m}]", "must be [x, y, id, payoff, x_ref, y_ref]"
                )
            elif not (d[3] is None or _number(d[3]) or isinstance(d[3], str)):
                pr.add(f"{at}.scene.detections[{k}][{m}]", "its payoff must be a number or null")


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_multi_steps(doc: dict[str, Any], path: str, text: str | None = None) -> None:
    """What the multi-check schema cannot say, for the report that draws a
    ``lesmc-multi-check`` document's counterexamples (lesmc/report/multi.py): each
    counterexample's steps in increasing order on frames >= 0; each track and attacked
    detection with a ``box`` [x1, y1, x2, y2] or a ``position`` [x, y], each reference a
    box, every coordinate finite and within :data:`MAX_DRAWN`. One :class:`InputError`
    listing every problem (given the JSON ``text``, each at its ``FILE:LINE:COL``)."""
    pr = Problems()
    for i, res in enumerate(doc["results"]):
        last = -1
        steps = res["counterexample"] or []
        drawn = bool(steps) and "tracks" in steps[0]  # the report then draws every step
        for k, s in enumerate(steps):
            at = f"results[{i}].counterexample[{k}]"
            for key in ("tracks", "attacked"):
                if drawn and key not in s:
                    pr.add(at, f"needs {key!r}, as the counterexample's first step has 'tracks'")
            if s["step"] <= last:
                pr.add(f"{at}.step", f"must exceed the step before, {last} (steps in order)")
            last = max(last, s["step"])
            if s["frame"] < 0:
                pr.add(f"{at}.frame", f"must be at least 0, got {s['frame']}")
            if s.get("reference") is not None:
                _place(s["reference"], f"{at}.reference", (4,), pr)
            for key in ("tracks", "attacked"):
                for j, item in enumerate(s.get(key) or []):
                    _drawn(item, f"{at}.{key}[{j}]", pr)
    if pr.items:
        raise error_in_file(path, pr.items, text)


def _drawn(item: dict[str, Any], at: str, pr: Problems) -> None:
    """A track or an attacked detection: its box (4 numbers) or position (2), drawn as is."""
    if "box" not in item and "position" not in item:
        pr.add(at, "needs a box [x1, y1, x2, y2] or a position [x, y]")
    if "box" in item:
        _place(item["box"], f"{at}.box", (4,), pr)
    if "position" in item:
        _place(item["position"], f"{at}.position", (2,), pr)


def _place(row: list[Any], at: str, sizes: tuple[int, ...], pr: Problems) -> None:
    """A box or a position: ``sizes`` numbers, each finite with |v| <= MAX_DRAWN."""
    if len(row) not in sizes:
        pr.add(at, f"must hold {' or '.join(map(str, sizes))} numbers, got {len(row)}")
    elif not all(within(v, MAX_DRAWN) for v in row):
        pr.add(at, f"every coordinate must be finite with |v| <= {MAX_DRAWN:g} (pixels)")
