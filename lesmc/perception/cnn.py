"""The two CNNs of the detector (paper sections 6.4-6.5), small enough for a CPU.

- ``DetectNet`` (N_dr): 21x21x(m+1) window -> two logits (no vehicle, vehicle).
- ``LocateNet`` (N_lp): 45x45x(m+1) window -> 15x15 map; pixels above delta_lp
  that are local maxima are vehicles (one map cell = 3x3 input pixels).

Weights are stored as safetensors (plain tensors, no code is executed on
loading) with a JSON header of settings; the package ships a trained pair.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from lesmc.common.errors import InputError, Location, Problems
from lesmc.common.fields import header
from lesmc.common.files import read_json
from lesmc.perception.threads import fit_torch_threads
from lesmc.perception.windows import M_PREVIOUS

DR_SIZE = 21
LP_SIZE = 45
LP_OUT = 15
LP_STRIDE = LP_SIZE // LP_OUT


class DetectNet(nn.Module):
    """N_dr: is there a moving vehicle in the window? Two logits, index 1 = vehicle."""

    def __init__(self, channels: int = M_PREVIOUS + 1) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(channels, 16, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(16, 32, 3, stride=2, padding=1),
            nn.ReLU(),  # 11x11
            nn.Conv2d(32, 32, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1),
            nn.ReLU(),  # 6x6
        )
        self.head = nn.Sequential(
            nn.Flatten(), nn.Linear(32 * 6 * 6, 64), nn.ReLU(), nn.Linear(64, 2)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # brightness invariance: remove each window's mean grey level
        x = x - x.mean(dim=(1, 2, 3), keepdim=True)
        # channels last: oneDNN's convolutions on these 21x21 windows run 1.3-1.4x faster
        # forward, 1.2-1.25x with DeepFool's gradients (benchmarks/bench_layout.py); the
        # weights keep their layout (saved files, exports and certify.py read them as is)
        x = x.contiguous(memory_format=torch.channels_last)
        out: torch.Tensor = self.head(self.features(x))
        return out


class LocateNet(nn.Module):
    """N_lp: a 15x15 map of vehicle centres for a 45x45 window (values in [0, 1])."""

    def __init__(self, channels: int = M_PREVIOUS + 1) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(channels, 8, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(8, 16, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(16, 32, LP_STRIDE, stride=LP_STRIDE),
            nn.ReLU(),  # 15x15
            nn.Conv2d(32, 32, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 1, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x - x.mean(dim=(1, 2, 3), keepdim=True)
        x = x.contiguous(memory_format=torch.channels_last)  # 1.3x faster (see DetectNet)
        out: torch.Tensor = torch.sigmoid(self.body(x)[:, 0])
        return out


@dataclass(frozen=True)
class NetSettings:
    """Thresholds that travel with a trained pair of networks."""

    m: int = M_PREVIOUS
    delta_dr: float = 0.5  #: N_dr accepts a window when P(vehicle) > delta_dr
    delta_lp: float = 0.5  #: N_lp map threshold
    trained_on: str = ""


@dataclass
class Nets:
    """A trained N_dr and N_lp and their settings, in eval mode.

    ``dr`` and ``lp`` are the shipped modules, or a user's networks loaded from
    files (``dr_file``, ``lp_file``: lesmc/perception/graphs.py)."""

    dr: nn.Module
    lp: nn.Module
    settings: NetSettings
    dr_file: Any = None  # graphs.UserNet of --detector
    lp_file: Any = None  # graphs.UserNet of --locator
    #: where the pair (``dr`` and ``lp`` before any file replaced them) came from, in words
    origin: str = ""


DEFAULT_WEIGHTS = "wami"  #: the pair shipped in lesmc/perception/weights/


def save_nets(nets: Nets, directory: str | Path) -> None:
    """Write ``dr.safetensors``, ``lp.safetensors`` and ``nets.json``."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    save_file(
        {k: v.contiguous() for k, v in nets.dr.state_dict().items()}, str(d / "dr.safetensors")
    )
    save_file(
        {k: v.contiguous() for k, v in nets.lp.state_dict().items()}, str(d / "lp.safetensors")
    )
    (d / "nets.json").write_text(
        json.dumps(
            {"format": "lesmc-nets", "version": 1, "settings": asdict(nets.settings)}, indent=1
        )
        + "\n"
    )


def nets_settings(meta: Any, path: str) -> NetSettings:
    """The settings of a ``nets.json`` document, checked strictly.

    ``format`` must be ``"lesmc-nets"`` (weights in safetensors files beside it:
    nothing is ever unpickled), ``version`` 1, ``settings.m`` an integer in 1..16,
    the thresholds numbers in [0, 1], ``trained_on`` a string.
    """
    pr = Problems()
    if not isinstance(meta, dict):
        raise InputError.many(path, [("", "the top level must be a JSON object")])
    header(meta, "lesmc-nets", 1, pr)
    raw = meta.get("settings")
    if not isinstance(raw, dict):
        pr.add("settings", "must be an object")
        raise InputError.many(path, pr.items)
    for key in sorted(set(raw) - {f.name for f in fields(NetSettings)}):
        pr.add("settings", f"unknown key '{key}'")
    m = raw.get("m", M_PREVIOUS)
    if not (type(m) is int and 1 <= m <= 16):
        pr.add("settings", f"m must be an integer in 1..16, got {m!r}")
    for key in ("delta_dr", "delta_lp"):
        x = raw.get(key, 0.5)
        if not (type(x) in (int, float) and 0.0 <= x <= 1.0):
            pr.add("settings", f"{key} must be a number in [0, 1], got {x!r}")
    if not isinstance(raw.get("trained_on", ""), str):
        pr.add("settings", "trained_on must be a string")
    if pr.items:
        raise InputError.many(path, pr.items)
    return NetSettings(**raw)


def load_nets(
    directory: str | Path | None = None, detector: str | None = None, locator: str | None = None
) -> Nets:
    """Load a pair written by ``save_nets`` (default: the shipped weights); ``detector`` and
    ``locator`` (``.pt2``/``.onnx`` files) replace N_dr and N_lp, keeping the settings.

    ``settings.trained_on`` then names where each network came from (:func:`networks_text`):
    what the scene's ``meta.detector`` and the results' ``perception.nets`` record."""
    nets = _load_pair(directory)
    if detector is None and locator is None:
        return nets
    from lesmc.perception.graphs import check_network
    from lesmc.perception.network_file import load_network

    channels = nets.settings.m + 1
    if detector is not None:
        nets.dr_file = load_network(detector)
        check_network(nets.dr_file, "detector", channels, DR_SIZE, (2,))
        nets.dr = nets.dr_file.module
    if locator is not None:
        nets.lp_file = load_network(locator)
        check_network(nets.lp_file, "locator", channels, LP_SIZE, (LP_OUT, LP_OUT))
        nets.lp = nets.lp_file.module
    text = networks_text(detector, locator, nets.origin)
    nets.settings = replace(nets.settings, trained_on=text)
    return nets


def _pair_text(directory: str | Path | None, trained_on: str) -> str:
    """Where the pair of ``save_nets`` came from, in words."""
    where = f"shipped ({DEFAULT_WEIGHTS})" if directory is None else f"of --nets {directory}"
    return f"{where}, trained on {trained_on}" if trained_on else where


def networks_text(detector: str | None, locator: str | None, pair: str) -> str:
    """Which N_dr and N_lp ran: each the user's file or the pair's network, never one's
    history given to the other (``pair``: :func:`_pair_text`)."""
    dr = f"the user's file {detector}" if detector is not None else pair
    lp = f"the user's file {locator}" if locator is not None else pair
    return f"detector (N_dr): {dr}; locator (N_lp): {lp}"


def describe_nets(nets: Nets) -> str:
    """Which networks ran, for a log line: :func:`networks_text` for a user's file, the
    pair's origin otherwise."""
    if nets.dr_file is None and nets.lp_file is None:
        return f"detector (N_dr) and locator (N_lp): {nets.origin}"
    return nets.settings.trained_on


def _load_pair(directory: str | Path | None) -> Nets:
    """The pair of ``save_nets`` in ``directory`` (default: the shipped weights)."""
    if directory is None:
        d = Path(str(resources.files("lesmc.perception") / "weights" / DEFAULT_WEIGHTS))
    else:
        d = Path(directory)
    meta_path = d / "nets.json"
    if not meta_path.is_file():
        raise InputError("not a lesmc network directory (no nets.json)", Location(str(d)))
    settings = nets_settings(read_json(meta_path, InputError), str(meta_path))
    fit_torch_threads()  # threads that fit the free cores (lesmc/perception/threads.py)
    dr, lp = DetectNet(settings.m + 1), LocateNet(settings.m + 1)
    for net, name in ((dr, "dr.safetensors"), (lp, "lp.safetensors")):
        try:
            net.load_state_dict(load_file(str(d / name)))
        except Exception as exc:  # safetensors raises its own error type for bad headers
            raise InputError(f"cannot load weights ({exc})", Location(str(d / name))) from None
        net.eval()
    return Nets(dr, lp, settings, origin=_pair_text(directory, settings.trained_on))
