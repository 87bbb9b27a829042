"""The attack a ``joint``/``improved`` injection counterexample stands for (issue 61).

Under ``allow hide, inject`` the results list no hidden detections (the ranks are
ordered by cost), and a step of ``joint``'s path is an outcome for the whole joint
state (every track, the pending detections), of which the results keep only the
primary's estimate. The replay therefore walks the path on the scene the model was
built from: from the design's initial state, at each step, the outcomes of the joint
states reached so far (:meth:`~lesmc.tracking.joint.JointDesign.forcing` at an
attacked step, the unattacked outcome elsewhere) whose primary estimate is the
path's next state and whose primary takes the path's measurement; each with the
cost of forcing it (Eq. 5: the own payoffs of the lower ranks) and the option the
model kept for it (hide the j detections nearest the primary, inject a subset of the
candidates: docs/semantics.md, "Injection on the joint design"). Outcomes that agree
with the path on the primary but not elsewhere are all followed; at the end the
cheapest way along the whole path is the attack the replay applies.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.model.kernel import combined_payoffs
from lesmc.replay.case import Case
from lesmc.replay.scene_match import ResultsMismatch, check_scene
from lesmc.scene import Scene, tracker_from_dict

if TYPE_CHECKING:
    from lesmc.tracking.design import Successors

#: Per step, the ids of the detections hidden and of the candidates injected.
Forced = dict[int, tuple[list[str], list[str]]]

#: The joint states followed along a path at most (those agreeing with it on the primary).
MAX_FOLLOWED = 256


def derive_joint(meta: Mapping[str, Any], todo: list[Case], scene: Scene | None = None) -> None:
    """Each ``joint`` injection case's attack along its path into ``case.forced``, on
    ``scene`` (None: the file the results name, ``meta.scene``)."""
    for c in todo:
        if c.injects and c.tracker_kind == "joint":
            c.forced, c.derived = joint_forcing(c, scene_of(meta, c, scene))


def check_joint_cases(meta: Mapping[str, Any], todo: list[Case]) -> None:
    """Refuse results whose ``joint`` injection cases do not fit the scene ``meta.scene``
    names (:func:`scene_of`): before the frames are read and the networks loaded."""
    for c in todo:
        if c.injects and c.tracker_kind == "joint":
            scene_of(meta, c)


def scene_of(meta: Mapping[str, Any], case: Case, scene: Scene | None = None) -> Scene:
    """The scene the results' model was built from (``scene``, else the file ``meta.scene``),
    with the case's target and tracker (the run's design and configuration)."""
    from dataclasses import replace

    from lesmc.scene.io import load_scene

    path = meta.get("scene")
    if scene is None and (not isinstance(path, str) or not Path(path).is_file()):
        raise UsageError(
            f"replaying {case.design}'s injection counterexample of {case.prop} walks its path "
            "on the scene the model was built from, and the results name none that exists "
            f"(meta.scene: {path!r}); run the replay where lesmc check or verify was run"
        )
    if scene is None:
        scene = load_scene(str(path))
    where = path if isinstance(path, str) else "the checked scene"
    _within(case, scene, where)
    check_scene(case, scene, where)
    cfg = tracker_from_dict(case.tracker, "results: replay_inputs.tracker")
    return replace(scene.footage.with_target(case.target, scene.meta), tracker=cfg)


def _within(case: Case, scene: Scene, path: str) -> None:
    """An input error unless ``case``'s target and steps are frames of ``scene`` (read from
    ``path``): results edited by hand, or made from another scene."""
    first, last = case.target.step, case.first_frame + len(case.positions) - 1
    lo, hi = scene.frames[0].step, scene.last_step
    if not (lo <= first <= hi and lo <= case.first_frame and last <= hi):
        why = (
            f"the target (step {first}) and the counterexample of {case.prop} (steps "
            f"{case.first_frame}..{last}) are not within the frames {lo}..{hi} of {path} "
            "(meta.scene): the results were not made from this scene"
        )
        raise ResultsMismatch([(f"runs[{case.run}].replay_inputs.target", why)])


def joint_forcing(case: Case, scene: Scene) -> tuple[Forced, bool]:
    """The cheapest way to force ``case``'s path on ``scene`` with the joint design: per
    attacked step, the ids hidden and injected (see the module docstring). Where no
    outcome agrees with the path (not the scene the results were made from, or a path
    edited) the attack is derived up to the step before, and the flag returned is False."""
    from lesmc.tracking.joint import JointDesign
    from lesmc.tracking.trackers import make_tracker

    design = make_tracker(scene, True, "hide" in case.actions)
    assert isinstance(design, JointDesign)
    batch = design.initial()
    cost = np.zeros(1)
    how: list[Forced] = [{}]
    for k in range(1, len(case.positions)):
        frame = case.first_frame + k
        attacked = case.window[0] <= k <= case.window[1]
        if attacked:
            succ, ways = design.forcing(batch, frame)
        else:
            succ = design.successors(batch, frame, False)
            ways = [([], [])] * len(succ.src)
        idx = np.flatnonzero(_on_path(case, k, succ, scene))
        if not idx.size:  # the path leaves the design here: derived up to the step before
            return how[int(np.argmin(cost))], False  # (the replay diverges by step k)
        idx = idx[np.argsort((cost[succ.src] + forcing_costs(succ))[idx], kind="stable")]
        idx = idx[:MAX_FOLLOWED]
        cost = cost[succ.src[idx]] + forcing_costs(succ)[idx]
        how = [how[int(succ.src[i])] | ({k: ways[i]} if attacked else {}) for i in idx]
        batch = succ.states.take(idx)
    return how[int(np.argmin(cost))], True


def forcing_costs(succ: Successors) -> np.ndarray:
    """Each outcome's cost of forcing it from its source: the sum of the own payoffs of the
    same source's lower ranks (Eq. 5, :func:`lesmc.model.kernel.combined_payoffs`)."""
    order = np.lexsort((succ.rank, succ.src))
    src = succ.src[order]
    n = int(src.max()) + 1 if src.size else 0
    ptr = np.r_[0, np.cumsum(np.bincount(src, minlength=n))]
    out = np.empty(src.size)
    out[order] = combined_payoffs(ptr, succ.payoff[order], succ.rank[order])
    return out


def _on_path(case: Case, k: int, succ: Successors, scene: Scene) -> np.ndarray:
    """Which outcomes agree with the path at step ``k``: the primary's estimate, the
    measurement it takes, whether it halts."""
    frame = scene.frame(case.first_frame + k)
    names = [d.id for d in frame.detections] + [c.id for c in frame.candidates]
    obs = [None if d < 0 else names[d] for d in succ.det.tolist()]
    want = case.states[k]
    X = succ.states.X
    close = np.all(np.abs(X - want) <= 1e-6 + 1e-9 * np.abs(want), axis=1)
    same = np.array([o == case.obs[k - 1] for o in obs], dtype=bool)
    halts = case.halted and k == len(case.positions) - 1
    ok: np.ndarray = close & same & (succ.states.halted == halts)
    return ok
