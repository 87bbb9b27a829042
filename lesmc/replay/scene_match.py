"""Whether a results file was made from the scene its ``meta.scene`` names, before a replay
walks a counterexample on that scene (``joint``'s injections: replay/joint_forcing.py).

The results record no hash of the scene; they record the detections near every listed
path (``runs[].scene.detections``: id and position per step) and, per step of each path,
the detection or injection candidate taken (``runs[].paths[].obs``). A scene that lacks
one of them, or has it elsewhere, is not the scene the results were made from (or the
results were edited): :class:`ResultsMismatch`, an input error at the results field,
located in the results file by the command that read it (:meth:`ResultsMismatch.at`).
A ``lesmc-multi-check`` document records, per counterexample step, the detections hidden
and candidates injected with their boxes (``attacked``): lesmc/replay/multi.py checks them
with :func:`first_misplaced`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from lesmc.common.errors import InputError, clipped
from lesmc.common.locations import error_in_file

if TYPE_CHECKING:
    from lesmc.replay.case import Case
    from lesmc.scene import Frame, Scene

#: A recorded detection is where the scene has it when within this many pixels (the
#: results write the scene's numbers: only a different scene moves them).
SAME_PX = 1e-3


class ResultsMismatch(InputError):
    """Results fields that disagree with the scene they name: ``(item, message)`` pairs,
    each item a JSON path of the results document (``runs[0].paths[46].obs[1]``)."""

    def __init__(self, problems: list[tuple[str, str]]) -> None:
        self.problems = problems
        whole = InputError.many("results", problems)
        super().__init__(whole.message, whole.location)
        self.preformatted = True

    def at(self, path: str) -> InputError:
        """The same problems, each at its ``FILE:LINE:COL`` in the results file ``path``."""
        return error_in_file(path, self.problems)


def check_scene(case: Case, scene: Scene, path: str) -> None:
    """Raise :class:`ResultsMismatch` unless ``scene`` (read from ``path``) holds every
    detection the results record near ``case``'s run's paths, where they record it, and
    every detection or candidate ``case``'s path takes."""
    by_step = {f.step: f for f in scene.frames}
    problem = _recorded_elsewhere(case, by_step, path) or _obs_absent(case, by_step, path)
    if problem is not None:
        raise ResultsMismatch([problem])


def _recorded_elsewhere(case: Case, by_step: dict[int, Frame], path: str) -> tuple[str, str] | None:
    """The first detection of ``runs[].scene.detections`` that ``path``'s scene lacks or
    has elsewhere: its item and what differs."""
    if case.recorded is None:
        return None
    first = case.recorded.first_frame
    return first_misplaced(
        (
            (
                f"runs[{case.run}].scene.detections[{s}][{m}]",
                "detection",
                first + s,
                d.id,
                (d.x, d.y),
            )
            for s, dets in enumerate(case.recorded.detections)
            for m, d in enumerate(dets)
        ),
        by_step,
        path,
    )


#: One place a results document records: its item (a JSON path of the document), what
#: it is (``detection``, ``injection candidate``), its frame, its id and (x, y).
Recorded = tuple[str, str, int, str, tuple[float, float]]


def first_misplaced(
    records: Iterable[Recorded], by_step: dict[int, Frame], path: str
) -> tuple[str, str] | None:
    """The first of ``records`` that ``path``'s scene (its frames ``by_step``) lacks or
    has elsewhere (farther than :data:`SAME_PX`): its item and what differs (the point
    designs' ``runs[].scene.detections``; a ``lesmc-multi-check`` document's ``attacked``
    entries, lesmc/replay/multi.py)."""
    for item, what, step, did, (x, y) in records:
        frame = by_step.get(step)
        got = None if frame is None else _named(frame, did)
        if got is None:
            return item, (
                f"{what} '{clipped(did)}' of frame {step} is not in {path} "
                "(meta.scene): the results were not made from this scene"
            )
        if max(abs(got[0] - x), abs(got[1] - y)) > SAME_PX:
            return item, (
                f"{what} '{clipped(did)}' of frame {step} is at ({x:g}, {y:g}) "
                f"in the results, at ({got[0]:g}, {got[1]:g}) in {path} (meta.scene): the "
                "results were not made from this scene"
            )
    return None


def _obs_absent(case: Case, by_step: dict[int, Frame], path: str) -> tuple[str, str] | None:
    """The first step of ``case``'s path taking an id that its frame of ``path``'s scene
    has neither as a detection nor as an injection candidate."""
    for k, obs in enumerate(case.obs, start=1):
        frame = by_step.get(case.first_frame + k)
        if obs is None or (frame is not None and _named(frame, obs) is not None):
            continue
        return f"runs[{case.run}].paths[{case.path_no - 1}].obs[{k - 1}]", (
            f"step {k} of {case.prop}'s counterexample takes '{clipped(obs)}', which frame "
            f"{case.first_frame + k} of {path} (meta.scene) has neither as a detection nor "
            "as an injection candidate"
        )
    return None


def _named(frame: Frame, did: str) -> tuple[float, float] | None:
    """Where ``frame``'s detection or injection candidate ``did`` is (None: it has none)."""
    for d in (*frame.detections, *frame.candidates):
        if d.id == did:
            return d.x, d.y
    return None
