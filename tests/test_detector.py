"""The learning-enabled detector: shipped CNNs, the Figure 4 pipeline, scenes out, training."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from lesmc.cli.main import cli
from lesmc.common.errors import InputError, UsageError
from lesmc.perception.cnn import load_nets, save_nets
from lesmc.perception.detector import Detector, peaks
from lesmc.perception.quality import care_mask, score, truth_frame
from lesmc.perception.training import TrainConfig, train
from lesmc.scene import load_scene
from lesmc.tracking.targets import parse_target
from lesmc.video.synth import SynthConfig, frames
from lesmc.video.write import write_video

VIDEO = SynthConfig(frames=8, width=640, height=640, seed=21)


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("video")
    write_video(VIDEO, out)
    return out


def test_shipped_networks_load_from_safetensors() -> None:
    nets = load_nets()
    assert nets.settings.m == 3 and 0 < nets.settings.delta_dr < 1
    assert not nets.dr.training and not nets.lp.training


def test_the_networks_compute_their_layers_whatever_the_layout() -> None:
    """The forward passes hand oneDNN channels-last activations (cnn.py); the oracle runs
    the same layers one by one on plain channels-first tensors, as torch does by default."""
    import torch
    from torch.nn import functional as F

    nets = load_nets()
    rng = np.random.default_rng(3)

    def by_hand(layers: list[torch.nn.Module], x: torch.Tensor) -> torch.Tensor:
        h = x - x.mean(dim=(1, 2, 3), keepdim=True)
        for mod in layers:
            if isinstance(mod, torch.nn.Conv2d):
                h = F.conv2d(h, mod.weight, mod.bias, mod.stride, mod.padding)
            elif isinstance(mod, torch.nn.Linear):
                h = F.linear(h.flatten(1), mod.weight, mod.bias)
            elif isinstance(mod, torch.nn.ReLU):
                h = torch.relu(h)
        return h

    with torch.inference_mode():
        x = torch.from_numpy(rng.random((37, 4, 21, 21), dtype=np.float32))
        want = by_hand([*nets.dr.features, *nets.dr.head], x)
        got = nets.dr(x)
        assert got.shape == want.shape and x.is_contiguous()
        assert torch.allclose(got, want, rtol=1e-5, atol=1e-4)
        y = torch.from_numpy(rng.random((5, 4, 45, 45), dtype=np.float32))
        want_lp = torch.sigmoid(by_hand(list(nets.lp.body), y)[:, 0])
        assert torch.allclose(nets.lp(y), want_lp, rtol=1e-5, atol=1e-6)


def test_a_broken_network_directory_is_a_user_error(tmp_path: Path) -> None:
    save_nets(load_nets(), tmp_path)
    (tmp_path / "dr.safetensors").write_bytes(b"\x80\x04 pickle? no")
    with pytest.raises(InputError, match=r"dr\.safetensors"):
        load_nets(tmp_path)
    with pytest.raises(InputError, match=r"nets\.json"):
        load_nets(tmp_path / "missing")


def test_detector_finds_moving_vehicles_on_an_unseen_video() -> None:
    det = Detector(load_nets())
    total = None
    for img, ft in frames(VIDEO):
        res = det.push(img)
        if res is None:
            continue
        out, fd = res
        tf = truth_frame(ft.vehicles)
        s = score(fd.positions, tf.positions, care_mask(tf, out.aligned.valid, 1.5), 4.0)
        total = s if total is None else total + s
        assert len(fd.source) == len(fd.positions) and fd.source.max(initial=-1) < len(fd.windows)
    assert total is not None and total.tp + total.fn > 20
    assert total.recall >= 0.9 and total.precision >= 0.9


def test_map_peaks_are_local_maxima_above_threshold() -> None:
    m = np.zeros((1, 15, 15), np.float32)
    m[0, 4, 6] = 0.9  # cell (x=6, y=4) -> window pixel (19, 13)
    m[0, 4, 7] = 0.3  # a shoulder, not a peak
    m[0, 10, 2] = 0.4  # below threshold
    (pk,) = peaks(m, 0.5)
    assert pk.shape == (1, 3)
    assert pk[0, 0] == pytest.approx(6 * 3 + 1 + 3 * 0.3 / 1.2) and pk[0, 1] == pytest.approx(13)


def test_parse_target() -> None:
    t = parse_target("812.5, 96@4")
    assert (t.x, t.y, t.step) == (812.5, 96.0, 4)
    assert parse_target("1,2").step is None
    with pytest.raises(UsageError):
        parse_target("1;2")


def test_perceive_writes_a_scene_the_checker_takes(video: Path, tmp_path: Path) -> None:
    truth = json.loads((video / "truth.json").read_text())
    v = max(truth["frames"][4]["vehicles"], key=lambda v: v["speed_mps"])
    out = tmp_path / "scene.json"
    res = CliRunner().invoke(
        cli,
        [
            "perceive",
            str(video),
            "-o",
            str(out),
            "--target",
            f"{v['x']},{v['y']}@4",
            "--truth",
            str(video / "truth.json"),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    scene = load_scene(out)
    assert [f.step for f in scene.frames] == list(range(4, 8))
    assert scene.dt == pytest.approx(0.8)
    assert scene.target.step == 4
    assert np.allclose(scene.target.velocity, (v["vx"], v["vy"]))  # from the truth
    pays = np.concatenate([f.payoffs() for f in scene.frames])
    assert len(pays) > 20 and (pays[np.isfinite(pays)] > 0).all()
    assert np.isfinite(pays).mean() > 0.9
    # homographies agree with the generator's camera
    for a, b in zip(scene.frames, scene.frames[1:], strict=False):
        want = np.linalg.inv(np.array(truth["frames"][b.step]["to_prev"]))
        p = np.array([[100.0, 100.0, 1.0], [500.0, 300.0, 1.0]])
        got_p, want_p = p @ a.to_next.T, p @ want.T
        assert np.allclose(got_p[:, :2] / got_p[:, 2:], want_p[:, :2] / want_p[:, 2:], atol=0.3)
    chk = CliRunner().invoke(cli, ["check", str(out), "specs/robustness.spec", "--json"])
    assert chk.exit_code in (0, 1, 3), chk.output


def test_perceive_writes_a_scene_without_a_target(video: Path, tmp_path: Path) -> None:
    out = tmp_path / "scene.json"
    r = CliRunner().invoke(cli, ["perceive", str(video), "--target", "1,1@4"])
    assert isinstance(r.exception, UsageError) and "-o" in str(r.exception)  # no scene
    r = CliRunner().invoke(cli, ["perceive", str(video), "-o", str(out), "--target", "1,1@1"])
    assert r.exit_code != 0 and not out.exists()  # frame 1 only fills the background
    # few DeepFool iterations: this test is about the scene's shape, not the payoffs
    r = CliRunner().invoke(cli, ["perceive", str(video), "-o", str(out), "--max-iter", "2"])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert "target" not in doc and len(doc["frames"]) == 4
    spec = str(Path(__file__).parents[1] / "specs" / "robustness.spec")
    r = CliRunner().invoke(cli, ["check", str(out), spec])
    assert isinstance(r.exception, UsageError) and "has no target" in str(r.exception)
    z = doc["frames"][0]["detections"][0]
    # a target far from every detection is refused, one on a detection is checked
    r = CliRunner().invoke(cli, ["check", str(out), spec, "--target", "-500,-500@4"])
    assert isinstance(r.exception, UsageError) and "gate" in str(r.exception)
    r = CliRunner().invoke(cli, ["track", str(out), "--target", f"{z['x']},{z['y']}@4", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["track"][0]["s"][:2] == [z["x"], z["y"]]


def test_training_smoke_run_produces_loadable_networks(tmp_path: Path) -> None:
    cfg = TrainConfig(
        train_seeds=(5,), val_seed=6, frames=6, width=320, height=320, epochs_dr=1, epochs_lp=1
    )
    nets, val = train(cfg)
    assert 0.0 <= val.dr_accuracy <= 1.0 and val.samples_dr > 0 and val.samples_lp > 0
    save_nets(nets, tmp_path / "n")
    again = load_nets(tmp_path / "n")
    for a, b in zip(nets.dr.state_dict().values(), again.dr.state_dict().values(), strict=True):
        assert np.array_equal(a.numpy(), b.numpy())


def _first_detections(nets: Any) -> Any:
    """The detections of the first frame the detector scores on VIDEO."""
    det = Detector(nets)
    for img, _ in frames(VIDEO):
        res = det.push(img)
        if res is not None:
            assert len(res[1].windows) > 10
            return res[1]
    raise AssertionError("the detector scored no frame")


def test_payoffs_of_real_detections_flip_the_shipped_detector() -> None:
    """DeepFool on the shipped N_dr and real windows: the perturbation hides the vehicle."""
    import torch

    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.attacks import payoffs

    nets = load_nets()
    fd = _first_detections(nets)
    res = payoffs(nets.dr, fd.windows, nets.settings.delta_dr, AttackConfig())
    ok = res.flipped
    assert ok.mean() > 0.9
    with torch.no_grad():
        p_before = torch.softmax(nets.dr(torch.from_numpy(fd.windows)), 1)[:, 1].numpy()
        adv = torch.from_numpy(fd.windows + res.perturbation)
        p_after = torch.softmax(nets.dr(adv), 1)[:, 1].numpy()
    assert (p_before > nets.settings.delta_dr).all()  # every Q_dr window was accepted
    assert (p_after[ok] <= nets.settings.delta_dr).all()
    norms = np.linalg.norm(res.perturbation.reshape(len(ok), -1).astype(np.float64), axis=1)
    assert np.allclose(res.payoff[ok], norms[ok], rtol=1e-6)


def test_the_networks_answer_the_same_in_the_batches_the_detector_uses() -> None:
    """DR_BATCH and LP_BATCH were chosen for speed: a window's N_dr probability and N_lp
    map do not depend on the batch it went through beyond float32 rounding (a kernel
    chosen per batch shape), against the old batches and one window at a time."""
    from lesmc.perception.detector import DR_BATCH, LP_BATCH, dr_probability, lp_maps

    nets = load_nets()
    rng = np.random.default_rng(4)
    dr = rng.random((1000, 4, 21, 21), dtype=np.float32)
    lp = rng.random((150, 4, 45, 45), dtype=np.float32)
    p = dr_probability(nets, dr, DR_BATCH)
    np.testing.assert_allclose(p, dr_probability(nets, dr, 2048), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[:20], dr_probability(nets, dr[:20], 1), rtol=1e-5, atol=1e-6)
    maps = lp_maps(nets, lp, LP_BATCH)
    np.testing.assert_allclose(maps, lp_maps(nets, lp, 512), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(maps[:5], lp_maps(nets, lp[:5], 1), rtol=1e-5, atol=1e-6)


def test_deepfool_stops_at_the_noise_floor_with_the_payoffs_of_the_full_iteration() -> None:
    """AttackConfig.converged stops a window whose margin is within float32 rounding of the
    boundary. Against DeepFool written out here and run to the iteration cap (the rule
    before it): every window flips or not alike, payoffs agree to 1e-5 relative, and
    the stop saves iterations on real windows (many hover at f ~ 1e-7 until the cap)."""
    import torch

    from lesmc.perception.attack_settings import AttackConfig, threshold_logit
    from lesmc.perception.attacks import margin, payoffs

    nets = load_nets()
    fd = _first_detections(nets)
    cfg = AttackConfig()
    ours = payoffs(nets.dr, fd.windows, nets.settings.delta_dr, cfg)
    t = threshold_logit(nets.settings.delta_dr)
    x0 = torch.from_numpy(fd.windows.astype(np.float32))
    xi, steps = x0.clone(), 0
    for _ in range(cfg.max_iter):
        x = xi.detach().requires_grad_(True)
        f = margin(nets.dr, x, t)
        (g,) = torch.autograd.grad(f.sum(), x)
        live = f.detach() > 0
        steps += int(live.sum())
        r = -(f.detach() / (g.flatten(1).pow(2).sum(1) + 1e-8)).view(-1, 1, 1, 1) * g
        xi = torch.where(live.view(-1, 1, 1, 1), (xi + r).clamp(0, 1), xi)
    adv = (x0 + (1 + cfg.overshoot) * (xi - x0)).clamp(0, 1)
    with torch.no_grad():
        flipped = (margin(nets.dr, adv, t) <= 0).numpy()
    d = (adv - x0).numpy().astype(np.float64).reshape(len(adv), -1)
    full = np.where(flipped, np.sqrt((d**2).sum(1)), np.inf)
    assert np.array_equal(ours.flipped, flipped)
    np.testing.assert_allclose(ours.payoff[flipped], full[flipped], rtol=1e-5)
    assert ours.iterations.sum() < steps
