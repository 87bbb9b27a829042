"""Stuck neurons (issue 30, paper section 9.2): a faulty network against one whose ReLU
output is overwritten by a hook, the unit maxima against a plain layer-by-layer pass, the
certified radius of a faulty network below an exhaustive search on the hooked one, bad
declarations as located errors through the CLI, and ``verify --faults`` end to end."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_run import lesmc
from test_certify import Small, ray_search
from torch import nn

from lesmc.perception.certify import CertifyConfig, certified_radius, chain_of
from lesmc.perception.cnn import load_nets
from lesmc.perception.detector import dr_probability, lp_maps
from lesmc.perception.neurons import (
    StuckUnit,
    UnitMaxima,
    hidden_layers,
    layer_sizes,
    stick,
    with_stuck_units,
)
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

SCENES = Path(__file__).parent / "scenes"


def overwritten(net: nn.Module, units: list[tuple[int, int, float]]) -> nn.Module:
    """The oracle: a copy of ``net`` whose k-th ReLU's output has channel ``unit`` replaced
    by ``value`` (the ReLUs found by walking the modules, not by lesmc's layer list)."""
    oracle = copy.deepcopy(net)
    relus = [m for m in oracle.modules() if isinstance(m, nn.ReLU)]
    for layer, unit, value in units:

        def hook(_m: nn.Module, _i: Any, out: torch.Tensor, u: int = unit, v: float = value) -> Any:
            out = out.clone()
            out[:, u] = v
            return out

        relus[layer].register_forward_hook(hook)
    return oracle


@pytest.fixture(scope="module")
def nets() -> Any:
    return load_nets()


def test_a_stuck_unit_equals_its_relu_output_overwritten(nets: Any) -> None:
    """40 random faults (one or two units, detector or locator, conv or dense layers, stuck
    at 0 or at a positive value): the faulty networks' outputs equal the hooked ones'."""
    rng = np.random.default_rng(11)
    for name, net, size in (("detector", nets.dr, 21), ("locator", nets.lp, 45)):
        sizes = layer_sizes(net)
        assert len(sizes) == sum(isinstance(m, nn.ReLU) for m in net.modules())
        x = torch.from_numpy(
            rng.uniform(0, 1, (6, nets.settings.m + 1, size, size)).astype(np.float32)
        )
        changed = 0
        for _ in range(20):
            units = []
            for _ in range(int(rng.integers(1, 3))):
                layer = int(rng.integers(0, len(sizes)))
                value = 0.0 if rng.random() < 0.4 else float(rng.uniform(0.1, 5.0))
                units.append((layer, int(rng.integers(0, sizes[layer])), value))
            faulty = with_stuck_units(nets, [StuckUnit(name, *u) for u in units])  # type: ignore[arg-type]
            got = (faulty.dr if name == "detector" else faulty.lp)(x)
            want = overwritten(net, units)(x)
            torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
            changed += not torch.equal(net(x), got)
        assert changed >= 10, (name, changed)  # the faults matter (a few units do not)


def _plain_maxima(net: nn.Module, x: torch.Tensor) -> list[np.ndarray]:
    """Each hidden unit's largest value, by running the layers one by one."""
    out = []
    h = x - x.mean(dim=(1, 2, 3), keepdim=True)
    mods = [m for part in ("features", "head", "body") for m in getattr(net, part, [])]
    for m in mods:
        h = m(h)
        if isinstance(m, nn.ReLU):
            dims = [0, 2, 3] if h.dim() == 4 else [0]
            out.append(h.amax(dim=dims).numpy())
    return out


def test_unit_maxima_are_the_largest_values_over_the_windows_scored(nets: Any) -> None:
    rng = np.random.default_rng(2)
    c = nets.settings.m + 1
    dr_win = rng.uniform(0, 1, (30, c, 21, 21)).astype(np.float32)
    lp_win = rng.uniform(0, 1, (7, c, 45, 45)).astype(np.float32)
    maxima = UnitMaxima(nets)
    with maxima.recording():
        dr_probability(nets, dr_win[:20], batch=8)
        dr_probability(nets, dr_win[20:])
        lp_maps(nets, lp_win)
    dr_probability(nets, np.ones_like(dr_win[:3]))  # not recorded
    with torch.no_grad():
        want_dr = _plain_maxima(nets.dr, torch.from_numpy(dr_win))
        want_lp = _plain_maxima(nets.lp, torch.from_numpy(lp_win))
    for got, want in ((maxima.maxima["detector"], want_dr), (maxima.maxima["locator"], want_lp)):
        assert len(got) == len(want)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-6)
    for _, relu in hidden_layers(nets.dr):  # the hooks are gone
        assert not relu._forward_hooks


@pytest.mark.parametrize("seed", range(4))
def test_certified_radius_of_a_faulty_network_is_below_the_search_on_it(seed: int) -> None:
    """A conv unit stuck at a positive value and a dense unit at 0: the certified radius
    of the faulty network's chain is at most the smallest flip that an exhaustive ray
    search finds on the hooked network."""
    torch.manual_seed(seed)
    net = Small((2, 1, 1), [(6, 1, 1, 0)], 8)
    net.subtract_mean = False
    rng = np.random.default_rng(seed)
    units = [(0, int(rng.integers(0, 6)), float(rng.uniform(0.2, 1.5))), (1, 3, 0.0)]
    faulty = copy.deepcopy(net)
    for u in units:
        stick(faulty, *u)
    oracle = overwritten(net, units)
    x = rng.uniform(-1, 1, (60, 2, 1, 1)).astype(np.float32)
    with torch.no_grad():
        logits = oracle(torch.from_numpy(x))
    f = (logits[:, 1] - logits[:, 0]).numpy()
    t = float(np.median(f))
    x = x[f > t][:6]
    cert = certified_radius(chain_of(faulty, t, False), x, cfg=CertifyConfig(steps=12))
    truth = np.array([ray_search(oracle, xi, t, 6.0) for xi in x])
    assert (cert <= truth + 1e-6).all(), (cert, truth)
    assert (cert > 0).all()


def _faults(tmp_path: Path, line: str) -> Path:
    path = tmp_path / "faults.spec"
    path.write_text(f"faults {{\n  budget 1\n  {line}\n}}\n")
    return path


@pytest.mark.parametrize(
    ("line", "where", "message"),
    [
        ("fault n: neuron detector[5, 0] = 0", "3:9",
         "the detector has 5 hidden layers (0..4): layer 5 is out of range"),
        ("fault n: neuron detector[4, 64] = max", "3:9",
         "layer 4 of the detector has 64 units (0..63): unit 64 is out of range"),
        ("fault n: neuron locator[1, 16] = 1", "3:9",
         "layer 1 of the locator has 16 units (0..15): unit 16 is out of range"),
        ("fault n: neuron detector[1, 2] = -0.5", "3:36",
         "a stuck unit's value must be at least 0 (its ReLU never outputs less), got -0.5"),
        ("fault n: neuron camera[1, 2] = 0", "3:19",
         "unexpected 'camera'; expected a network (detector or locator)"),
    ],
)  # fmt: skip
def test_a_bad_neuron_fault_stops_verify_before_any_work(
    tmp_path: Path, line: str, where: str, message: str
) -> None:
    path = _faults(tmp_path, line)
    out = tmp_path / "out"
    res = lesmc("verify", "--faults", str(path), "--out", str(out))
    assert res.returncode == 2, res.stderr
    assert f"{path}:{where}: {message}" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()  # nothing rendered, perceived or written


def test_a_neuron_fault_needs_the_video(tmp_path: Path) -> None:
    """A scene holds one network's detections: check refuses a neuron fault, located."""
    path = _faults(tmp_path, "fault n: neuron detector[1, 2] = 0")
    res = lesmc(
        "check", str(SCENES / "rq1_platoon.json"), "specs/robustness.spec", "--faults", str(path)
    )
    assert res.returncode == 2, res.stderr
    assert f"{path}:3:9: fault 'n' makes a detector neuron fail" in res.stderr
    assert "Traceback" not in res.stderr


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("neuron") / "tiny"
    write_video(SynthConfig(frames=12, width=448, height=448, seed=4, density=3.0), out)
    return out


def test_verify_checks_each_design_with_the_unit_stuck(video: Path, tmp_path: Path) -> None:
    """A unit of N_dr's dense layer stuck at its largest value: verify perceives the video
    with the faulty network, reports ``NAME+FAULT`` per property with the activation, and
    a rerun reads that perception from the cache."""
    path = _faults(tmp_path, "fault hot: neuron detector[4, 10] = max")
    out = tmp_path / "out"
    args = ("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
            "--design", "single", "--window", "3..4", "--faults", str(path))  # fmt: skip
    res = lesmc(*args)
    assert res.returncode in (0, 1), res.stderr
    assert "Traceback" not in res.stderr and "perceiving with hot" in res.stderr
    doc = json.loads((out / "results.json").read_text())
    faults = {f["property"]["name"]: f["result"] for f in doc["runs"][0]["faults"]}
    assert set(faults) == {"robustness+hot", "resilience+hot"}
    for r in faults.values():
        assert r["notes"][0].startswith("worst activation: hot (neuron detector[4,10] = max from")
    entries = [p.name for p in (out / "cache").iterdir() if p.name.startswith("neuron-fault-")]
    assert len(entries) == 1
    stored = json.loads((out / "cache" / entries[0]).read_text())["value"]
    clean = json.loads((out / "scene.json").read_text())
    assert stored["footage"]["frames"] != clean["frames"]  # the fault changes what is seen
    again = lesmc(*args)
    assert again.returncode == res.returncode and "reusing the perception with hot" in again.stderr
    doc2 = json.loads((out / "results.json").read_text())
    assert [f["result"]["optimum"] for f in doc2["runs"][0]["faults"]] == [
        f["result"]["optimum"] for f in doc["runs"][0]["faults"]
    ]
    # a perception entry whose unit maxima were cut short by hand: a located error, exit 2
    (entry,) = (out / "cache").glob("perception-*.json")
    kept = json.loads(entry.read_text())
    kept["value"]["unit_max"]["detector"][4] = kept["value"]["unit_max"]["detector"][4][:3]
    entry.write_text(json.dumps(kept))
    for p in (out / "cache").glob("neuron-fault-*.json"):
        p.unlink()
    broken = lesmc(*args)
    assert broken.returncode == 2, broken.stderr
    assert "Traceback" not in broken.stderr and "internal error" not in broken.stderr
    assert f"{entry}: unit_max.detector:" in broken.stderr


def test_unit_maxima_are_recorded_only_when_a_fault_needs_them(video: Path, tmp_path: Path) -> None:
    """A verify without neuron faults does not record the unit maxima (they cost about a
    third of the networks' scoring); a later verify with a stuck-at-max fault in the same
    OUT perceives the video again, recording them, and finds what a fresh run finds."""
    path = _faults(tmp_path, "fault hot: neuron detector[4, 10] = max")
    out = tmp_path / "out"
    common = (str(video), "--truth", str(video / "truth.json"), "--design", "single",
              "--window", "3..4")  # fmt: skip
    plain = lesmc("verify", *common, "--out", str(out))
    assert plain.returncode in (0, 1), plain.stderr
    (entry,) = (out / "cache").glob("perception-*.json")
    assert json.loads(entry.read_text())["value"]["unit_max"] == {}
    later = lesmc("verify", *common, "--out", str(out), "--faults", str(path))
    assert later.returncode in (0, 1), later.stderr
    assert "perceiving the video again: its cached perception has no unit maxima" in later.stderr
    assert json.loads(entry.read_text())["value"]["unit_max"]["detector"]
    fresh = lesmc("verify", *common, "--out", str(tmp_path / "fresh"), "--faults", str(path))
    assert fresh.returncode == later.returncode, fresh.stderr

    def faults(d: Path) -> list[Any]:
        doc = json.loads((d / "results.json").read_text())
        return [(f["property"]["name"], f["result"]["optimum"], f["result"]["notes"])
                for f in doc["runs"][0]["faults"]]  # fmt: skip

    assert faults(out) == faults(tmp_path / "fresh") and faults(out)


def test_certified_verify_certifies_on_the_faulty_network(video: Path, tmp_path: Path) -> None:
    """``--payoffs certified``: the fault variants' hideable detections are certified on
    the faulty N_dr, and every result under the fault is a certified one."""
    path = _faults(tmp_path, "fault dead: neuron detector[3, 5] = 0")
    out = tmp_path / "out"
    res = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
                "--design", "single", "--window", "3..4", "--faults", str(path),
                "--payoffs", "certified")  # fmt: skip
    assert res.returncode in (0, 1, 3), res.stderr
    assert "Traceback" not in res.stderr and "certifying with dead" in res.stderr
    doc = json.loads((out / "results.json").read_text())
    faults = [f["result"] for f in doc["runs"][0]["faults"]]
    assert len(faults) == 2 and all(r["payoffs"] == "certified" for r in faults)
