"""Attack payoffs: the smallest perturbation of a detection's N_dr input that hides it,
or of a rejected candidate's that makes N_dr accept it (injection, issue 61).

The payoff of hiding a detection (paper section 3.1, Eq. 4) is the L2 norm of
a perturbation ``delta`` of its N_dr input (all m+1 channels, pixel scale
[0, 1]) such that N_dr no longer answers "vehicle" on ``x + delta``. The payoff
of injecting one (``towards="inject"``) is the same norm for a window N_dr
rejects, perturbed until N_dr answers "vehicle": the same attacks on the
margin's negation ``-f`` (:data:`SIGN`), flipped when ``f > 0`` (N_dr accepts
P(vehicle) > delta_dr strictly).

- ``deepfool``: DeepFool (Moosavi-Dezfooli et al. 2016) for our two-logit
  detector. With ``f(x) = logit_vehicle - logit_none - t`` (``t`` the logit of
  the acceptance threshold delta_dr), each step is the closed form
  ``r = -f(x) / ||grad f(x)||^2 * grad f(x)``, the projection onto the
  linearised boundary; iterate until ``f <= 0``, then scale the total by
  ``1 + overshoot`` (as ART does), clip to [0, 1]. Batched over detections.
  A window also stops once its margin is at float32's noise floor,
  ``f <= converged * f(x0)``, or its step changes no pixel: from there the
  iterates only hover over the boundary (``AttackConfig.converged``).
- ``pgd``: a minimum-norm search over the budget ``eps`` of an L2 projected
  gradient attack (doubling, then bisection); an independent upper bound to
  compare with.

A detection that is not flipped within the iteration cap (or after clipping)
is *unattackable*: its payoff is ``inf``, written ``"unattackable"`` in scenes.
The returned perturbation is exactly the one whose norm is reported, and the
attack checks that it flips N_dr.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import nn

from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.cnn import DR_SIZE
from lesmc.perception.threads import in_lanes

TOL = 1e-8

Towards = Literal["hide", "inject"]
#: The sign each direction gives the margin: the attacks drive ``SIGN * f`` to 0 or below.
SIGN: dict[str, float] = {"hide": 1.0, "inject": -1.0}


def flipped(f: torch.Tensor, sign: float) -> torch.Tensor:
    """Whether margins ``f`` (:func:`margin`, unsigned) have reached the direction's goal:
    not a vehicle (``f <= 0``) when hiding, a vehicle (``f > 0``) when injecting."""
    out: torch.Tensor = f <= 0 if sign > 0 else f > 0
    return out


@dataclass
class AttackResult:
    """Per detection: payoff (inf = unattackable), the perturbation applied, flipped or not."""

    payoff: np.ndarray
    perturbation: np.ndarray
    flipped: np.ndarray
    iterations: np.ndarray


def margin(net: nn.Module, x: torch.Tensor, t: float, sign: float = 1.0) -> torch.Tensor:
    """f(x) = logit_vehicle - logit_none - t (times ``sign``): positive while N_dr sees a
    vehicle (with ``sign`` -1: while it does not)."""
    logits: torch.Tensor = net(x)
    out: torch.Tensor = sign * (logits[:, 1] - logits[:, 0] - t)
    return out


def _grad(
    net: nn.Module, x: torch.Tensor, t: float, sign: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:
    x = x.detach().requires_grad_(True)
    f = margin(net, x, t, sign)
    (g,) = torch.autograd.grad(f.sum(), x)
    return f.detach(), g.detach()


def deepfool(
    net: nn.Module, x0: torch.Tensor, t: float, cfg: AttackConfig, sign: float = 1.0
) -> tuple[torch.Tensor, np.ndarray]:
    """Batched two-class DeepFool on ``sign`` * margin; returns (x_adv, iterations used)."""
    xi = x0.clone()
    iters = np.zeros(len(x0), np.int64)
    f, g = _grad(net, xi, t, sign)
    floor = cfg.converged * f  # f at float32's noise floor (AttackConfig.converged)
    active = f > 0
    for _ in range(cfg.max_iter):
        if not bool(active.any()):
            break
        a = active.nonzero().ravel()
        gn = g[a].flatten(1).pow(2).sum(1) + TOL
        r = -(f[a] / gn).view(-1, 1, 1, 1) * g[a]
        now = xi[a]
        step = (now + r).clamp(0.0, 1.0)
        moved = (step != now).flatten(1).any(1)
        xi[a] = step
        iters[a.numpy()] += 1
        f_a, g_a = _grad(net, xi[a], t, sign)
        f[a], g[a] = f_a, g_a
        active[a] = (f_a > floor[a]) & moved
    x_adv = (x0 + (1.0 + cfg.overshoot) * (xi - x0)).clamp(0.0, 1.0)
    return x_adv, iters


def pgd_min_norm(
    net: nn.Module, x0: torch.Tensor, t: float, cfg: AttackConfig, sign: float = 1.0
) -> tuple[torch.Tensor, np.ndarray]:
    """Smallest L2 budget at which PGD flips N_dr; returns (x_adv, PGD runs per sample).

    The budget doubles from ``eps_start`` until PGD flips (or ``eps_max`` fails),
    then ``bisections`` halvings narrow it; the best flipping input is kept.
    """
    n = len(x0)
    with torch.no_grad():
        start = flipped(margin(net, x0, t), sign)
    best = x0.clone()
    found = start.clone()
    lo = torch.zeros(n)
    hi = torch.full((n,), cfg.eps_max)
    eps = torch.full((n,), cfg.eps_start)
    runs = np.zeros(n, np.int64)
    searching = ~start
    while bool(searching.any()):  # doubling
        idx = searching.nonzero().ravel()
        x_adv, ok = _pgd(net, x0[idx], t, eps[idx], cfg, sign)
        runs[idx.numpy()] += 1
        best[idx[ok]] = x_adv[ok]
        found[idx[ok]] = True
        hi[idx[ok]] = eps[idx[ok]]
        lo[idx[~ok]] = eps[idx[~ok]]
        searching[idx[ok]] = False
        gave_up = idx[~ok][eps[idx[~ok]] >= cfg.eps_max]
        searching[gave_up] = False
        eps = torch.clamp(eps * 2, max=cfg.eps_max)
    todo = found & ~start
    for _ in range(cfg.bisections):
        if not bool(todo.any()):
            break
        idx = todo.nonzero().ravel()
        mid = (lo[idx] + hi[idx]) / 2
        x_adv, ok = _pgd(net, x0[idx], t, mid, cfg, sign)
        runs[idx.numpy()] += 1
        best[idx[ok]] = x_adv[ok]
        hi[idx[ok]] = mid[ok]
        lo[idx[~ok]] = mid[~ok]
    return best, runs


def _pgd(
    net: nn.Module,
    x0: torch.Tensor,
    t: float,
    eps: torch.Tensor,
    cfg: AttackConfig,
    sign: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """L2 PGD on ``sign`` * margin within ``eps`` per sample; keeps, per sample, the first
    flipping iterate."""
    delta = torch.zeros_like(x0)
    alpha = (2.5 * eps / cfg.pgd_steps).view(-1, 1, 1, 1)
    done = torch.zeros(len(x0), dtype=torch.bool)
    out = x0.clone()
    for _ in range(cfg.pgd_steps):
        f, g = _grad(net, (x0 + delta).clamp(0, 1), t, sign)
        newly = flipped(sign * f, sign) & ~done
        out[newly] = (x0 + delta).clamp(0, 1)[newly]
        done |= newly
        if bool(done.all()):
            break
        step = -g / (g.flatten(1).norm(dim=1).view(-1, 1, 1, 1) + TOL)
        delta = delta + alpha * step
        norm = delta.flatten(1).norm(dim=1).view(-1, 1, 1, 1)
        delta = delta * torch.clamp(eps.view(-1, 1, 1, 1) / (norm + TOL), max=1.0)
        delta = (x0 + delta).clamp(0, 1) - x0
    with torch.no_grad():
        last = (x0 + delta).clamp(0, 1)
        fl = flipped(margin(net, last, t), sign)
    late = fl & ~done
    out[late] = last[late]
    return out, done | fl


def payoffs(
    net: nn.Module,
    windows: np.ndarray,
    delta_dr: float,
    cfg: AttackConfig,
    towards: Towards = "hide",
) -> AttackResult:
    """Attack every (n, m+1, 21, 21) window; payoff = ||x_adv - x|| (inf when not flipped).

    ``towards``: "hide" flips N_dr's "vehicle" to "not vehicle" (the windows of
    detections), "inject" the other way (the windows of candidates N_dr rejects).

    Batches of ``cfg.batch`` windows are independent: they run side by side, one per
    free core (:func:`~lesmc.perception.threads.in_lanes`), each exactly as it would
    alone.
    """
    t = threshold_logit(delta_dr)
    attack = deepfool if cfg.method == "deepfool" else pgd_min_norm
    sign = SIGN[towards]

    def batch(a: int) -> AttackResult:
        x0 = torch.from_numpy(np.ascontiguousarray(windows[a : a + cfg.batch], np.float32))
        x_adv, it = attack(net, x0, t, cfg, sign)
        with torch.no_grad():
            ok = flipped(margin(net, x_adv, t), sign).numpy()
        d = (x_adv - x0).numpy()
        norms = np.sqrt((d.astype(np.float64) ** 2).reshape(len(d), -1).sum(axis=1))
        if cfg.norm == "per-pixel":
            norms /= DR_SIZE * DR_SIZE
        return AttackResult(np.where(ok, norms, np.inf), d, ok, it)

    none = AttackResult(
        np.zeros(0), np.zeros((0, *windows.shape[1:]), np.float32), np.zeros(0, bool),
        np.zeros(0, np.int64),
    )  # fmt: skip
    parts = [none, *in_lanes(batch, range(0, len(windows), cfg.batch))]
    return AttackResult(
        np.concatenate([p.payoff for p in parts]),
        np.concatenate([p.perturbation for p in parts]),
        np.concatenate([p.flipped for p in parts]),
        np.concatenate([p.iterations for p in parts]),
    )
