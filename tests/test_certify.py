"""Certified payoff lower bounds (CROWN on our layer types) against search, sampling and attacks."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from torch import nn

from lesmc.perception import certify, crown, relaxations
from lesmc.perception.certify import (
    Ball,
    CertifyConfig,
    certified_radius,
    chain_of,
    detect_chain,
    flip_distances,
    interval_margin,
    layer_bounds,
    margin_form,
)
from lesmc.perception.chain import Chain, Conv


class Small(nn.Module):
    """An N_dr-shaped network of any size: [mean subtraction], convs + ReLUs, dense head."""

    def __init__(
        self, in_shape: tuple[int, int, int], convs: list[tuple[int, int, int, int]], hidden: int
    ) -> None:
        super().__init__()
        self.in_shape = in_shape
        mods: list[nn.Module] = []
        c, hw = in_shape[0], in_shape[1]
        for out, k, s, p in convs:
            mods += [nn.Conv2d(c, out, k, stride=s, padding=p), nn.ReLU()]
            c, hw = out, (hw + 2 * p - k) // s + 1
        self.features = nn.Sequential(*mods)
        self.head = nn.Sequential(
            nn.Flatten(), nn.Linear(c * hw * hw, hidden), nn.ReLU(), nn.Linear(hidden, 2)
        )
        self.subtract_mean = True

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.subtract_mean:
            x = x - x.mean(dim=(1, 2, 3), keepdim=True)
        out: torch.Tensor = self.head(self.features(x))
        return out


def margins(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    with torch.no_grad():
        logits = net(x)
    return logits[:, 1] - logits[:, 0]


def ray_search(net: nn.Module, x0: np.ndarray, t: float, r_max: float) -> float:
    """Smallest flipping radius on 7200 rays in the plane (steps of r_max/4000): >= the true one."""
    theta = np.linspace(0, 2 * math.pi, 7200, endpoint=False)
    dirs = np.stack([np.cos(theta), np.sin(theta)], 1)
    radii = np.linspace(0, r_max, 4001)[1:]
    best = math.inf
    for chunk in np.array_split(radii, 40):
        pts = x0.reshape(1, 1, 2) + chunk[None, :, None] * dirs[:, None, :]
        f = margins(net, torch.from_numpy(pts.reshape(-1, 2, 1, 1).astype(np.float32)))
        flip = (f <= t).numpy().reshape(len(dirs), len(chunk))
        if flip.any():
            best = min(best, float(chunk[flip.any(0).argmax()]))
            break
    return best


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("subtract_mean", [False, True])
def test_bound_is_below_the_smallest_flip_found_by_exhaustive_rays(
    seed: int, subtract_mean: bool
) -> None:
    torch.manual_seed(seed)
    net = Small((2, 1, 1), [(6, 1, 1, 0)], 8)
    net.subtract_mean = subtract_mean
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (40, 2, 1, 1)).astype(np.float32)
    f = margins(net, torch.from_numpy(x)).numpy()
    t = float(np.median(f))  # half the points are "vehicle"
    chain = chain_of(net, t, subtract_mean)
    x = x[f > t][:8]
    cert = certified_radius(chain, x, cfg=CertifyConfig(steps=12))
    truth = np.array([ray_search(net, xi, t, 6.0) for xi in x])
    resolution = 6.0 / 4000 + 6.0 * 2 * math.pi / 7200
    assert (cert <= truth + 1e-6).all(), (cert, truth)
    assert (cert > 0).all()
    finite = np.isfinite(truth)
    # a useful bound: CROWN on a 2-input network is close to the truth
    assert np.median(cert[finite] / (truth[finite] + resolution)) >= 0.3


def test_layer_bounds_contain_every_sampled_activation() -> None:
    """Strides, padding and the flatten, checked against the network's own forward pass."""
    torch.manual_seed(3)
    net = Small((2, 9, 9), [(4, 3, 1, 1), (5, 3, 2, 1), (3, 3, 2, 0)], 6)
    chain = chain_of(net, 0.3)
    x0 = torch.rand(3, 2, 9, 9)
    eps = torch.tensor([0.05, 0.2, 0.5])
    z0 = x0 - x0.mean(dim=(1, 2, 3), keepdim=True)
    ball = Ball(z0, eps, 2 * 81, True)
    with torch.no_grad():
        bounds, relaxes = layer_bounds(chain, ball)
        value, norm = margin_form(chain, ball, relaxes)
    f_low = value - eps * norm
    # random points of the sphere (the extreme ones) and of the ball
    n = 400
    d = torch.randn(3, n, 2 * 81)
    d = d / d.norm(dim=2, keepdim=True) * eps.view(3, 1, 1)
    d[:, n // 2 :] *= torch.rand(3, n // 2, 1)
    xs = (x0[:, None] + d.view(3, n, 2, 9, 9)).view(-1, 2, 9, 9)
    h = xs - xs.mean(dim=(1, 2, 3), keepdim=True)
    layers = list(net.features) + list(net.head)
    k = 0
    with torch.no_grad():
        for mod in layers:
            h = mod(h)
            if isinstance(mod, (nn.Conv2d, nn.Linear)) and k < len(bounds):
                lo, hi = bounds[k]
                lo_s = lo.repeat_interleave(n, 0)
                hi_s = hi.repeat_interleave(n, 0)
                assert (h >= lo_s - 1e-4).all() and (h <= hi_s + 1e-4).all(), k
                k += 1
        f = (h[:, 1] - h[:, 0] - 0.3).view(3, n)
    assert k == len(bounds) == 4
    assert (f >= f_low[:, None] - 1e-4).all()
    # the bounds are not vacuous: the smallest ball keeps most neurons stable
    lo, hi = bounds[0]
    assert float(((lo[0] < 0) & (hi[0] > 0)).float().mean()) < 0.5


def test_interval_margin_is_below_every_sampled_margin_and_trains() -> None:
    """The IBP bound of certified training: sound on sampled points, and differentiable."""
    torch.manual_seed(4)
    net = Small((2, 9, 9), [(4, 3, 1, 1), (5, 3, 2, 1), (3, 3, 2, 0)], 6)
    x0 = torch.rand(3, 2, 9, 9)
    eps = torch.tensor([0.02, 0.1, 0.4])
    z0 = x0 - x0.mean(dim=(1, 2, 3), keepdim=True)
    chain = chain_of(net, 0.3, detach=False)
    low = interval_margin(chain, Ball(z0, eps, 2 * 81, True))
    low.sum().backward()
    grads = [p.grad for p in net.parameters()]
    assert all(g is not None and bool(g.abs().sum() > 0) for g in grads)
    assert not any(layer.weight.requires_grad for layer in chain_of(net, 0.3).layers)
    n = 500
    d = torch.randn(3, n, 2 * 81)
    d = d / d.norm(dim=2, keepdim=True) * eps.view(3, 1, 1)
    d[:, n // 2 :] *= torch.rand(3, n // 2, 1)
    f = margins(net, (x0[:, None] + d.view(3, n, 2, 9, 9)).view(-1, 2, 9, 9)).view(3, n) - 0.3
    assert (f >= low.detach()[:, None] - 1e-4).all()
    # tight at radius 0 (the network's own margin), and looser as the ball grows
    with torch.no_grad():
        zero = interval_margin(chain, Ball(z0, torch.zeros(3), 2 * 81, True))
        gaps = [
            margins(net, x0)
            - 0.3
            - interval_margin(chain, Ball(z0, torch.full((3,), e), 162, True))
            for e in (0.01, 0.05, 0.2)
        ]
    assert torch.allclose(zero, margins(net, x0) - 0.3, atol=1e-4)
    assert ((gaps[0] <= gaps[1] + 1e-5) & (gaps[1] <= gaps[2] + 1e-5)).all()


def strided_case() -> tuple[nn.Module, Chain, np.ndarray]:
    torch.manual_seed(5)
    net = Small((2, 9, 9), [(4, 3, 1, 1), (5, 3, 2, 1), (3, 3, 2, 0)], 6)
    x = torch.rand(5, 2, 9, 9).numpy()
    f = margins(net, torch.from_numpy(x)).numpy()
    return net, chain_of(net, float(f.min()) - 0.5), x


def test_local_patches_equal_whole_level_propagation() -> None:
    """A conv neuron's CROWN bound in local form (patch + offset) equals the same row
    propagated as whole layers (transposed convolutions with padding)."""
    _, chain, x = strided_case()
    xt = torch.from_numpy(x)
    z0 = xt - xt.mean(dim=(1, 2, 3), keepdim=True)
    ball = Ball(z0, torch.full((len(x),), 0.3), 2 * 81, True)
    with torch.no_grad():
        _, relaxes = layer_bounds(chain, ball)
        for i in (1, 2):
            layer = chain.layers[i]
            assert isinstance(layer, Conv)
            n = layer.weight.shape[0] * layer.out_hw**2
            win = torch.arange(len(x)).repeat_interleave(n)
            neuron = torch.arange(n).repeat(len(x))
            views = crown._conv_views(chain, i, relaxes, ball)
            low, up = crown._crown_conv(chain, i, views, ball, win, neuron)
            # the same rows as whole maps: W^T applied to a one-hot of the neuron
            below = crown._shape(chain, i - 1)
            onehot = torch.eye(n).view(n, *crown._shape(chain, i))
            size = (layer.out_hw - 1) * layer.stride - 2 * layer.padding + 3
            rows = torch.nn.functional.conv_transpose2d(
                onehot,
                layer.weight,
                stride=layer.stride,
                padding=layer.padding,
                output_padding=below[1] - size,
            ).repeat(len(x), 1, 1, 1)
            bias = layer.bias.repeat_interleave(layer.out_hw**2).repeat(len(x))
            value, norm = crown._crown_full(
                chain, i, relaxes, ball, win, torch.stack([rows, -rows]), torch.stack([bias, -bias])
            )
            assert torch.allclose(low, value[0] - 0.3 * norm[0], atol=1e-4)
            assert torch.allclose(up, -(value[1] - 0.3 * norm[1]), atol=1e-4)
            # by position, every channel at once: the same bounds
            cells, c_out = layer.out_hw**2, layer.weight.shape[0]
            g_low, g_up = crown._crown_conv_at(
                chain,
                i,
                views,
                ball,
                torch.arange(len(x)).repeat_interleave(cells),
                torch.arange(cells).repeat(len(x)),
            )
            by_neuron = (len(x), c_out, cells)
            assert torch.allclose(g_low.view(c_out, len(x), cells).transpose(0, 1),
                                  low.view(by_neuron), atol=1e-5)  # fmt: skip
            assert torch.allclose(g_up.view(c_out, len(x), cells).transpose(0, 1),
                                  up.view(by_neuron), atol=1e-5)  # fmt: skip


@pytest.mark.parametrize("n", [1, 3, 4, 9, 16])
@pytest.mark.parametrize("c_out", [2, 4, 9])
@pytest.mark.parametrize("stride", [1, 2])
def test_stacked_transposed_convolution_equals_torchs(n: int, c_out: int, stride: int) -> None:
    """Patches stacked on the channel axis through a block-diagonal weight (few output
    channels) give torch's own transposed convolution, whatever the count of patches."""
    gen = torch.Generator().manual_seed(n * 100 + c_out * 10 + stride)
    x = torch.randn(n, 5, 5, 6, generator=gen)
    weight = torch.randn(6, c_out, 3, 3, generator=gen)
    want = torch.nn.functional.conv_transpose2d(x.permute(0, 3, 1, 2), weight, stride=stride)
    got = relaxations._transpose_conv(x, weight, stride)
    assert got.shape == (n, *want.shape[2:], c_out)
    torch.testing.assert_close(got, want.permute(0, 2, 3, 1), rtol=1e-5, atol=1e-5)


def test_batched_and_chunked_runs_equal_one_window_at_a_time(monkeypatch) -> None:
    _, chain, x = strided_case()
    together = certified_radius(chain, x, cfg=CertifyConfig(steps=3, batch=5))
    monkeypatch.setattr(crown, "CHUNK_FLOATS", 1)  # one row per propagation chunk
    alone = np.concatenate(
        [certified_radius(chain, x[k : k + 1], cfg=CertifyConfig(steps=3)) for k in range(5)]
    )
    assert (together > 0).any()
    np.testing.assert_allclose(together, alone, rtol=1e-4, atol=1e-7)


def test_a_ball_without_slack_is_not_grown() -> None:
    """``grow_slack``: a window whose first ball certified with r*(R) < grow_slack * R keeps
    R; with the rule off, the same windows grow past it (the rule, not the bound, stops them)."""
    _, chain, x = strided_case()
    xt = torch.from_numpy(x)
    first = certify._start(chain, certify.centred(chain, xt), None, CertifyConfig())[0].numpy()
    kept = certified_radius(chain, x, cfg=CertifyConfig(steps=4, grow_slack=math.inf))
    grown = certified_radius(chain, x, cfg=CertifyConfig(steps=4, grow_slack=0.0))
    assert (kept <= first * (1 - certify.SAFETY) * (1 + 1e-6)).all()
    assert (grown > first * (1 + 1e-3)).any()
    assert (kept > 0).any()


def test_payoff_model_places_the_first_ball_of_windows_with_a_payoff() -> None:
    """``start_model``: a window with a payoff starts at r0 exp(c . features), at most
    ``seed`` x payoff, stepped by ``model_step``; one without keeps the quantile rule
    (recomputed here with numpy from the flip distances)."""
    _, chain, x = strided_case()
    xt = torch.from_numpy(x)
    z0 = certify.centred(chain, xt)
    dist = flip_distances(chain, z0).double().numpy()
    pay = np.array([0.5, np.inf, 3.0, 0.02, 1.0])
    coef = (-0.3, -0.25, 0.3, 0.1)
    cfg = CertifyConfig(start_model=coef, model_step=1.3, model_slack=30.0)
    r, grow, shrink, _, slack = (t.numpy() for t in certify._start(chain, z0, pay, cfg))
    near, mid, far = np.maximum(np.quantile(dist, [0.17, 0.25, 0.33], axis=1), 1e-6)
    r0 = np.minimum(mid, cfg.seed * pay)
    with np.errstate(divide="ignore"):  # no payoff: log 0, a value the test does not read
        feats = [np.log(r0 / pay), np.log(near / r0), np.log(far / r0)]
    guess = r0 * np.exp(coef[0] + sum(c * f for c, f in zip(coef[1:], feats, strict=True)))
    paid = np.isfinite(pay)
    np.testing.assert_allclose(r[paid], np.minimum(guess, cfg.seed * pay)[paid], rtol=1e-9)
    np.testing.assert_allclose(r[~paid], mid[~paid], rtol=1e-9)
    assert (grow[paid] == 1.3).all() and (shrink[paid] == 1.3).all()
    assert (slack[paid] == 30.0).all() and (slack[~paid] == cfg.grow_slack).all()
    np.testing.assert_allclose(grow[~paid], np.maximum(far / mid, 1.05)[~paid], rtol=1e-9)
    np.testing.assert_allclose(shrink[~paid], np.maximum(mid / near, 1.5)[~paid], rtol=1e-9)
    assert r[3] == pytest.approx(cfg.seed * 0.02)  # the cap binds
    quantile = certify._start(chain, z0, pay, CertifyConfig())[0].numpy()
    np.testing.assert_allclose(quantile, r0, rtol=1e-9)


def test_the_payoff_model_starts_only_the_network_it_was_fitted_on(monkeypatch) -> None:
    """START_MODEL was fitted on the shipped N_dr, recognised by its weights whatever the
    threshold: other weights start from the quantile rule; coefficients of one's own
    apply to any network."""
    from lesmc.perception.cnn import load_nets

    chain = detect_chain(load_nets().dr, 0.0)
    refit = "the shipped N_dr changed: refit START_MODEL with benchmarks/exp_certify_start.py"
    assert certify.weights_digest(chain) == certify.START_MODEL_NET, refit
    assert certify.weights_digest(detect_chain(load_nets().dr, 1.5)) == certify.START_MODEL_NET
    first = chain.layers[0]
    other = Chain(
        chain.in_shape,
        chain.subtract_mean,
        (replace(first, weight=first.weight * 1.001), *chain.layers[1:]),
    )
    assert certify.weights_digest(other) != certify.START_MODEL_NET
    seen: list[object] = []

    def spy(chain, x, upper, cfg):  # type: ignore[no-untyped-def]
        seen.append(cfg.start_model)
        return np.zeros(len(x))

    monkeypatch.setattr(certify, "_search", spy)
    w, up = np.zeros((1, *chain.in_shape), np.float32), np.ones(1)
    certified_radius(chain, w, up)
    certified_radius(other, w, up)
    certified_radius(other, w, up, CertifyConfig(start_model=(0.0, 0.0, 0.0, 0.0)))
    certified_radius(chain, w, up, CertifyConfig(start="quantile"))
    certified_radius(chain, w, up, CertifyConfig(level=0.3))  # not the features it was fitted on
    assert seen == [certify.START_MODEL, None, (0.0, 0.0, 0.0, 0.0), None, None]


def test_a_network_with_dead_filters_certifies_nothing_rather_than_nan() -> None:
    """Filters of zeros make their flip distances infinite; with most of them so, the
    quantiles are not finite. The radius is then 0 (or a real certificate), never NaN."""
    _, chain, x = strided_case()
    first = chain.layers[0]
    assert isinstance(first, Conv)
    weight = first.weight.clone()
    weight[1:] = 0
    dead = Chain(
        chain.in_shape, chain.subtract_mean, (replace(first, weight=weight), *chain.layers[1:])
    )
    pay = np.full(len(x), 0.5)
    for cfg in (CertifyConfig(), CertifyConfig(start_model=(0.0, 1.0, 0.0, 0.0))):
        radius = certified_radius(dead, x, pay, cfg)
        assert np.isfinite(radius).all() and (radius >= 0).all()


def test_flip_distances_set_the_first_layers_unstable_fraction() -> None:
    """A ball of radius d (a flip distance) leaves unstable exactly the neurons nearer than d."""
    _, chain, x = strided_case()
    xt = torch.from_numpy(x)
    z0 = xt - xt.mean(dim=(1, 2, 3), keepdim=True)
    dist = flip_distances(chain, z0)
    r = dist.median(dim=1).values
    with torch.no_grad():
        (lo, hi), *_ = layer_bounds(chain, Ball(z0, r * 1.0001, 2 * 81, True))[0]
    unstable = ((lo < 0) & (hi > 0)).flatten(1)
    assert torch.equal(unstable, dist < r[:, None] * 1.0001)
    # the distance is the true one: 1.001 d along the projected weights flips the neuron
    layer = chain.layers[0]
    assert isinstance(layer, Conv)
    k = int(dist[0].argmin())
    onehot = torch.zeros(1, *crown._shape(chain, 0))
    onehot.view(-1)[k] = 1
    g = torch.nn.functional.conv_transpose2d(onehot, layer.weight, padding=layer.padding)
    g = g - g.mean()
    y = lambda z: torch.nn.functional.conv2d(z, layer.weight, layer.bias, padding=1).view(-1)[k]  # noqa: E731
    y0 = y(z0[:1])
    step = -torch.sign(y0) * g / g.norm() * dist[0, k]
    assert torch.sign(y(z0[:1] + 1.001 * step)) != torch.sign(y0)
    assert torch.sign(y(z0[:1] + 0.999 * step)) == torch.sign(y0)


def test_chain_refuses_layers_it_cannot_bound() -> None:
    net = Small((1, 5, 5), [(2, 3, 1, 1)], 4)
    net.features[1] = nn.Sigmoid()
    with pytest.raises(ValueError):
        chain_of(net, 0.0)


@pytest.fixture(scope="module")
def shipped() -> tuple[nn.Module, np.ndarray, np.ndarray]:
    """Real detection windows of an unseen video, their DeepFool payoffs."""
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.detector import Detector
    from lesmc.video.synth import SynthConfig, frames

    nets = load_nets()
    det = Detector(nets)
    for img, _ in frames(SynthConfig(frames=6, width=512, height=512, seed=33)):
        res = det.push(img)
        if res is not None:
            windows = res[1].windows
            break
    rng = np.random.default_rng(0)
    w = windows[rng.choice(len(windows), 6, replace=False)]
    pay = payoffs(nets.dr, w, nets.settings.delta_dr, AttackConfig()).payoff
    return nets.dr, w, pay


def test_shipped_detector_bound_is_below_the_attack_and_no_attack_beats_it(shipped) -> None:
    from lesmc.perception.attack_settings import threshold_logit
    from lesmc.perception.attacks import margin

    net, w, pay = shipped
    t = threshold_logit(0.5)
    cert = certified_radius(detect_chain(net, t), w, pay)
    assert (cert > 0).all() and (cert <= pay).all()
    # PGD with restarts inside 0.99x the bound, plus random directions on its sphere
    x0 = torch.from_numpy(w)
    eps = torch.from_numpy(0.99 * cert).float().view(-1, 1, 1, 1)
    gen = torch.Generator().manual_seed(0)
    lowest = margin(net, x0, t).detach()
    for _ in range(4):
        delta = torch.randn(x0.shape, generator=gen)
        delta = delta / delta.flatten(1).norm(dim=1).view(-1, 1, 1, 1) * eps
        for _ in range(40):
            delta.requires_grad_(True)
            f = margin(net, (x0 + delta).clamp(0, 1), t)
            (g,) = torch.autograd.grad(f.sum(), delta)
            with torch.no_grad():
                lowest = torch.minimum(lowest, f)
                step = g / (g.flatten(1).norm(dim=1).view(-1, 1, 1, 1) + 1e-12)
                delta = delta - 0.1 * eps * step
                norm = delta.flatten(1).norm(dim=1).view(-1, 1, 1, 1)
                delta = delta * torch.clamp(eps / (norm + 1e-12), max=1.0)
    with torch.no_grad():
        for _ in range(20):
            d = torch.randn(x0.shape, generator=gen)
            d = d / d.flatten(1).norm(dim=1).view(-1, 1, 1, 1) * eps
            lowest = torch.minimum(lowest, margin(net, (x0 + d).clamp(0, 1), t))
    assert (lowest > 0).all()


def test_certify_detections_bounds_exactly_the_wanted_blobs() -> None:
    """verify's on-demand certification: each wanted detection gets its own blob's bound,
    computed here window by window; detections of other blobs get none."""
    from lesmc.perception.attack_settings import AttackConfig, threshold_logit
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.detector import Detector
    from lesmc.perception.run import PerceiveRun, _payoffs, certify_detections
    from lesmc.video.synth import SynthConfig, frames

    nets = load_nets()
    det = Detector(nets)
    run = PerceiveRun()
    for img, _ in frames(SynthConfig(frames=7, width=512, height=512, seed=33)):
        res = det.push(img)
        if res is not None:
            run.detections.append(res[1])
            run.payoffs.append(_payoffs(nets, res[1], AttackConfig(), None)[0])
    assert len(run.detections) >= 2
    a, b = run.detections[0], run.detections[-1]
    wanted = {a.index: np.array([0, 2]), b.index: np.array([len(b.positions) - 1])}
    cfg = CertifyConfig()
    got = certify_detections(nets, run, wanted, AttackConfig(), cfg)
    assert set(got) == set(wanted)
    chain = detect_chain(nets.dr, threshold_logit(nets.settings.delta_dr))
    for fd, pay in zip(run.detections, run.payoffs, strict=True):
        if fd.index not in wanted:
            continue
        blobs = set(fd.source[wanted[fd.index]].tolist())
        for i in range(len(fd.positions)):
            if fd.source[i] not in blobs:
                assert math.isnan(got[fd.index][i])
                continue
            alone = certified_radius(chain, fd.windows[fd.source[i]][None], pay[i : i + 1], cfg)
            assert got[fd.index][i] == pytest.approx(min(alone[0], pay[i]), rel=1e-4)
            assert 0 < got[fd.index][i] <= pay[i]
