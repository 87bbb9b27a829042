"""The counterexamples of a ``lesmc-multi-check`` document, read for their replay
(lesmc/replay/multi.py): each violated property's steps, the detections it hides and the
candidates it injects, checked against the scene the results name (every problem at its
``FILE:LINE:COL`` in the results file).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from lesmc.common.errors import UsageError
from lesmc.common.locations import error_in_file
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.scene import Scene


@dataclass(frozen=True)
class MultiCase:
    """One violated property's counterexample in a ``lesmc-multi-check`` document: its index
    among the document's ``results``, the bound property, the steps as the document holds
    them, and the detections hidden (with their positions and payoffs from the scene)."""

    result: int
    prop: Any  #: a BoundProperty (language/semantics.py), bound by the layers above
    steps: tuple[dict[str, Any], ...]
    hidden: tuple[Hidden, ...]
    path: str = "<results>"  #: the results file, for errors
    #: the candidates injected: (step, frame, id ``FRAME:cROW``, (x, y) as the scene gives it)
    injected: tuple[tuple[int, int, str, tuple[float, float]], ...] = ()

    def injects_at(self, frame: int) -> list[tuple[int, str, tuple[float, float]]]:
        """The candidates injected at ``frame``: (step, id, scene position)."""
        return [(k, cid, at) for k, f, cid, at in self.injected if f == frame]

    @property
    def end(self) -> int:
        """The counterexample's last step."""
        return len(self.steps) - 1


def multi_cases(
    doc: Mapping[str, Any],
    scene: Scene,
    bound: Mapping[str, Any],
    prop: str | None = None,
    path: str = "<results>",
    where: str = "the scene",
) -> list[MultiCase]:
    """The counterexamples of ``doc`` (read from ``path``) to replay: each violated result's
    (or ``prop``'s), with the detections it hides and the candidates it injects;
    ``bound``: the document's properties, bound to ``scene`` (read from ``where``). A
    step's ``attacked`` entry whose detection or candidate ``scene`` lacks or has
    elsewhere is an input error at that entry: the results were made from another
    scene."""
    results = list(doc.get("results", []))
    known_property(doc, prop)
    out = []
    for j, res in enumerate(results):
        steps = res.get("counterexample")
        if prop not in (None, res["property"]) or res.get("verdict") != "violated" or not steps:
            continue
        b = bound.get(res["property"])
        if b is None:
            raise UsageError(
                f"property {res['property']} of the results is in none of the property files "
                "the results name (meta.properties): give the files they were checked with"
            )
        _check_steps(scene, steps, path, j)
        _check_attacked(scene, steps, (path, where), j)
        hidden, injected = _hidden(scene, steps, path, j), _injected(scene, steps, path, j)
        out.append(MultiCase(j, b, tuple(steps), hidden, path, injected))
    return out


def _check_steps(scene: Scene, steps: list[dict[str, Any]], path: str, j: int) -> None:
    """A counterexample is a path from the scene's first frame: its step ``i`` is the
    ``i``-th, on the scene's ``i``-th frame (pipeline/multi.py writes them so); a step
    cut, renumbered or moved to another frame by hand is an input error, located."""
    problems = []
    for i, s in enumerate(steps):
        at = f"results[{j}].counterexample[{i}]"
        if s["step"] != i:
            problems.append((f"{at}.step", f"must be {i} (the steps are 0, 1, 2, ... in order)"))
        elif i >= len(scene.frames):
            problems.append(
                (f"{at}.step", f"the scene the results were made from has {len(scene.frames)} "
                 "frames only")
            )  # fmt: skip
        elif s["frame"] != scene.frames[i].step:
            problems.append(
                (f"{at}.frame", f"must be {scene.frames[i].step}, the scene's frame at step {i}")
            )
        if problems:
            raise error_in_file(path, problems)


def _check_attacked(
    scene: Scene, steps: list[dict[str, Any]], paths: tuple[str, str], j: int
) -> None:
    """Each step's ``attacked`` entries (the detections hidden and candidates injected,
    with their boxes or positions, as the check wrote them) must be in the scene (read
    from ``paths[1]``) where they say, as :func:`~lesmc.replay.scene_match.first_misplaced`
    checks a point design's recorded detections; else an input error at the entry's
    ``FILE:LINE:COL`` in the results file ``paths[0]``."""
    from lesmc.replay.scene_match import first_misplaced

    def records() -> Iterator[tuple[str, str, int, str, tuple[float, float]]]:
        for i, s in enumerate(steps):
            for m, a in enumerate(s.get("attacked") or ()):
                v = a.get("box", a.get("position"))
                if v is None or len(v) not in (2, 4):
                    continue
                at = ((v[0] + v[2]) / 2, (v[1] + v[3]) / 2) if len(v) == 4 else (v[0], v[1])
                what = "detection" if a["action"] == "hidden" else "injection candidate"
                item = f"results[{j}].counterexample[{i}].attacked[{m}]"
                yield item, what, int(s["frame"]), str(a["id"]), at

    problem = first_misplaced(records(), {f.step: f for f in scene.frames}, paths[1])
    if problem is not None:
        raise error_in_file(paths[0], [problem])


def known_property(doc: Mapping[str, Any], prop: str | None) -> None:
    """A UsageError unless ``prop`` (None: every property) is a result of ``doc``."""
    names = {str(r.get("property")) for r in doc.get("results", [])}
    if prop is not None and prop not in names:
        raise UsageError(
            f"no property named {prop}; the results hold {', '.join(sorted(names)) or 'none'}"
        )


def _hidden(scene: Scene, steps: list[dict[str, Any]], path: str, j: int) -> tuple[Hidden, ...]:
    """The detections the steps of result ``j`` hide, each with its step, frame, position
    and payoff as the scene gives them (a hidden id the scene's frame lacks: an input
    error at its ``FILE:LINE:COL`` in the results file ``path``)."""
    out = []
    for i, s in enumerate(steps):
        k = int(s["step"])
        frame = scene.frames[k] if 0 <= k < len(scene.frames) else None
        by_id = {} if frame is None else {d.id: d for d in frame.detections}
        for m, obs in enumerate(s["hidden"]):
            d = by_id.get(obs)
            if d is None or frame is None:
                item = f"results[{j}].counterexample[{i}].hidden[{m}]"
                msg = (
                    f"detection '{obs}' is not in the scene's frame {s['frame']}: the results "
                    "were not made from this scene"
                )
                raise error_in_file(path, [(item, msg)])
            out.append(Hidden(k, frame.step, obs, d.x, d.y, d.payoff))
    return tuple(out)


def _injected(
    scene: Scene, steps: list[dict[str, Any]], path: str, j: int
) -> tuple[tuple[int, int, str, tuple[float, float]], ...]:
    """The candidates the steps of result ``j`` inject: (step, frame, id, the scene's
    position); an id that is none of the scene frame's candidates is an input error at its
    ``FILE:LINE:COL`` in the results file ``path``."""
    out = []
    for i, s in enumerate(steps):
        frame = scene.frames[i]  # _check_steps: step i is the scene's i-th frame
        by_id = {d.id: d for d in frame.candidates}
        for m, cid in enumerate(s.get("injected") or ()):
            d = by_id.get(cid)
            if d is None:
                item = f"results[{j}].counterexample[{i}].injected[{m}]"
                msg = (
                    f"'{cid}' is not an injection candidate of the scene's frame {frame.step}: "
                    "the results were not made from this scene"
                )
                raise error_in_file(path, [(item, msg)])
            out.append((i, frame.step, cid, (d.x, d.y)))
    return tuple(out)
