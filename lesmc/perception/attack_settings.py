"""The attack's settings, apart from the attack (attacks.py, which needs torch).

A scene records the settings its payoffs were computed with (``meta.attack``);
a cached verify reads them to key its cache without loading torch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

from lesmc.common.errors import InputError, Problems
from lesmc.scene.located import scene_error
from lesmc.scene.meta_attack import recorded_attack, recorded_frontend

Method = Literal["deepfool", "pgd"]
Norm = Literal["l2", "per-pixel"]


@dataclass(frozen=True)
class AttackConfig:
    """Attack settings (docs/cnn.md, "Attack settings")."""

    method: Method = "deepfool"
    overshoot: float = 0.02  #: DeepFool's eta
    max_iter: int = 50
    norm: Norm = "l2"  #: "per-pixel": ||delta||_2 / 441, the paper's code's scale
    #: DeepFool stops a window whose margin f has fallen to this fraction of its start:
    #: float32 logits of 10-20 carry rounding of about 1e-6 of f(x0), so further steps
    #: cannot tell the boundary from noise. Without it, 15% of the default video's windows
    #: hovered within 1e-6 of the boundary until ``max_iter`` (84% of the attack's time);
    #: with it their payoffs moved by at most 9e-7 relative (docs/performance.md)
    converged: float = 1e-6
    pgd_steps: int = 25
    bisections: int = 12
    eps_start: float = 0.25  #: first L2 budget of the PGD search (doubled until it flips)
    eps_max: float = 32.0  #: largest L2 budget the PGD search tries
    #: windows per attack batch: autograd keeps each batch's activations (about 130 kB a
    #: window), so 128 peaks 110 MB lower than 512 in the same time. Every window's
    #: iterations are its own; only oneDNN's kernel for a batch shape may round
    #: differently (payoffs then differ in the 8th digit; docs/performance.md, "The main job")
    batch: int = 128


def threshold_logit(delta_dr: float) -> float:
    """N_dr says "vehicle" iff softmax P(vehicle) > delta_dr iff margin > logit(delta_dr)."""
    return math.log(delta_dr / (1.0 - delta_dr))


def attack_of(meta: dict[str, Any], where: str = "<scene>") -> AttackConfig:
    """The attack settings a scene's meta records (lesmc perceive -o), defaults for those
    it does not; a recorded value out of range (``lesmc.scene.meta_attack.ATTACK_SETTINGS``) is an
    InputError naming its field in ``where`` (the scene file)."""
    pr = Problems()
    got = recorded_attack(meta, pr)
    if pr.items:
        raise InputError.many(where, pr.items)
    return AttackConfig(**got)


def frontend_of(meta: dict[str, Any], where: str = "<scene>") -> dict[str, int]:
    """The front end's settings a scene's meta records (``meta.frontend``: ``history`` and
    ``delta_bc``, as ``lesmc perceive -o`` writes them); {} for a scene that records none
    (made before they were recorded, or not by the window pipeline). A bad one
    (lesmc.scene.meta_attack ``recorded_frontend``, which the scene's reader runs too) is
    an InputError at its field (``meta.frontend.history``) in ``where``, the scene file."""
    pr = Problems()
    got = recorded_frontend(meta, pr)
    if pr.items:
        raise scene_error(where, None, pr.items)
    return got


def scene_perception(meta: dict[str, Any], where: str = "<scene>") -> dict[str, Any]:
    """The part of a results document's ``perception`` that a scene's meta gives, the
    settings a replay reruns the front end and the attack with: the front end's
    ``history`` and ``delta_bc`` as ``meta.frontend`` records them (:func:`frontend_of`;
    none for a scene that records none, and the replay then says it uses the defaults)
    and the ``attack`` settings (:func:`attack_of`, defaults for those not recorded).
    ``lesmc verify``'s results (lesmc/experiment/verify_results.py ``perception_facts``,
    which adds the networks and the frames) and ``lesmc check --report``'s
    (lesmc/cli/check.py) both record it. ``where``: the scene file, for a recorded
    setting out of range (an InputError at its field)."""
    return {**frontend_of(meta, where), "attack": asdict(attack_of(meta, where))}
