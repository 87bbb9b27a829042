"""Training N_dr and N_lp on synthetic WAMI video (``lesmc train``).

Samples come from running the front end on generated videos whose truth is
known: a candidate window is positive when it matches (one to one, 4 px) a
moving visible vehicle, negative when it matches nothing, and left out when it
matches a vehicle that does not count (stopped, occluded). Windows cut at the
true positions of moving vehicles are added as positives, so N_dr also learns
vehicles the front end found off-centre. N_lp learns a Gaussian bump (sd 0.8
cells) at every moving vehicle in a 45x45 window, on crowded candidates, on
vehicles with a close neighbour, and on a share of the other windows.

Everything is seeded: the same seeds give the same weights (on one machine).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from lesmc.common.errors import UsageError
from lesmc.perception.cnn import (
    DR_SIZE,
    LP_OUT,
    LP_SIZE,
    LP_STRIDE,
    DetectNet,
    LocateNet,
    Nets,
    NetSettings,
)
from lesmc.perception.detector import DetectorConfig, crowded_blobs
from lesmc.perception.frontend import FrontEnd, FrontEndConfig
from lesmc.perception.quality import care_mask, match, truth_frame
from lesmc.perception.registration import RegistrationError
from lesmc.perception.windows import M_PREVIOUS, cut, origins, stack
from lesmc.video.synth import SynthConfig, frames

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TrainConfig:
    """Videos, epochs and seeds of a training run."""

    train_seeds: tuple[int, ...] = (101, 102)
    val_seed: int = 103
    frames: int = 16
    width: int = 2048
    height: int = 2048
    epochs_dr: int = 8
    epochs_lp: int = 10
    batch: int = 256
    lr: float = 2e-3
    seed: int = 0
    min_speed: float = 1.5
    radius: float = 4.0
    frontend: FrontEndConfig = field(default_factory=FrontEndConfig)


@dataclass
class Samples:
    """Windows (uint8, to keep memory low) and their targets."""

    dr_x: list[np.ndarray] = field(default_factory=list)
    dr_y: list[np.ndarray] = field(default_factory=list)
    lp_x: list[np.ndarray] = field(default_factory=list)
    lp_y: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (
            np.concatenate(self.dr_x),
            np.concatenate(self.dr_y),
            np.concatenate(self.lp_x),
            np.concatenate(self.lp_y),
        )


def heatmaps(org: np.ndarray, truth_xy: np.ndarray, sd: float = 0.8) -> np.ndarray:
    """N_lp targets: a Gaussian bump per vehicle, in map cells, max over vehicles."""
    cells = np.arange(LP_OUT)
    out = np.zeros((len(org), LP_OUT, LP_OUT), np.float32)
    if len(truth_xy) == 0:
        return out
    tree = cKDTree(truth_xy)
    for i, o in enumerate(org):
        centre = o + LP_SIZE / 2
        for j in tree.query_ball_point(centre, LP_SIZE):
            u = (truth_xy[j] - o - 1) / LP_STRIDE  # pixel -> cell (cell c covers 3c..3c+2)
            gx = np.exp(-0.5 * ((cells - u[0]) / sd) ** 2)
            gy = np.exp(-0.5 * ((cells - u[1]) / sd) ** 2)
            np.maximum(out[i], np.outer(gy, gx).astype(np.float32), out=out[i])
    return out


def collect(
    cfg: TrainConfig,
    seed: int,
    samples: Samples,
    rng: np.random.Generator,
    progress: Progress | None = None,
) -> None:
    """Run the front end on one generated video and add its labelled windows."""
    video = SynthConfig(frames=cfg.frames, width=cfg.width, height=cfg.height, seed=seed)
    fe = FrontEnd(cfg.frontend)
    for k, (img, ft) in enumerate(frames(video)):
        try:
            out = fe.push(img)
        except RegistrationError as exc:
            raise UsageError(
                f"training video {seed} ({cfg.width}x{cfg.height}): frame {k} cannot be "
                f"registered ({exc}); use a larger --size"
            ) from None
        if progress:
            progress(f"video {seed}", k + 1, cfg.frames)
        if out is None:
            continue
        tf = truth_frame(ft.vehicles)
        care = care_mask(tf, out.aligned.valid, cfg.min_speed)
        fr = stack(out.frame, out.aligned.frames, M_PREVIOUS)
        cents = out.candidates.centroid
        label = np.zeros(len(cents), np.int64)
        ambiguous = np.zeros(len(cents), bool)
        for i, j, _ in match(cents, tf.positions, cfg.radius):
            if care[j]:
                label[i] = 1
            else:
                ambiguous[i] = True
        use = ~ambiguous
        pos_truth = tf.positions[care]
        dr_c = np.concatenate([cents[use], pos_truth])
        dr_l = np.concatenate([label[use], np.ones(len(pos_truth), np.int64)])
        samples.dr_x.append(_u8(cut(fr, dr_c, DR_SIZE)))
        samples.dr_y.append(dr_l)
        # N_lp windows: crowded candidates, close pairs of vehicles, and a share of the rest
        dc = DetectorConfig()
        crowded = crowded_blobs(cents, out.candidates.box, dc.big_px, dc.close_px)
        centres = [cents[crowded]]
        if len(pos_truth) > 1:
            d, nn_idx = cKDTree(pos_truth).query(pos_truth, k=2)
            close = d[:, 1] < 15
            mid = (pos_truth[close] + pos_truth[nn_idx[close, 1]]) / 2
            centres.append(mid + rng.normal(0, 3, mid.shape))
        rest = np.flatnonzero(~crowded)
        pick = rng.choice(rest, size=min(len(rest), 150), replace=False) if len(rest) else rest
        centres.append(cents[pick] + rng.normal(0, 3, (len(pick), 2)))
        lc = np.concatenate(centres)
        samples.lp_x.append(_u8(cut(fr, lc, LP_SIZE)))
        samples.lp_y.append(heatmaps(origins(lc, LP_SIZE), pos_truth))


def _u8(w: np.ndarray) -> np.ndarray:
    out: np.ndarray = np.rint(w * 255).astype(np.uint8)
    return out


def _batches(n: int, size: int, gen: torch.Generator) -> list[torch.Tensor]:
    perm = torch.randperm(n, generator=gen)
    return [perm[a : a + size] for a in range(0, n, size)]


LossOf = Callable[[nn.Module, torch.Tensor, torch.Tensor, torch.Generator], torch.Tensor]


def _fit(
    net: nn.Module,
    x: np.ndarray,
    y: np.ndarray,
    loss_of: LossOf,
    epochs: int,
    seed: int,
    label: str,
    cfg: TrainConfig,
    progress: Progress | None,
) -> None:
    """Adam with a one-cycle schedule over shuffled mini-batches of uint8 windows."""
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(seed)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    steps = epochs * ((len(x) + cfg.batch - 1) // cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr, total_steps=steps)
    done = 0
    net.train()
    for _ in range(epochs):
        for idx in _batches(len(x), cfg.batch, gen):
            loss = loss_of(net, xt[idx].float() / 255.0, yt[idx], gen)
            opt.zero_grad()
            loss.backward()  # type: ignore[no-untyped-call]
            opt.step()
            sched.step()
            done += 1
            if progress:
                progress(label, done, steps)
    net.eval()


def train_dr(
    x: np.ndarray, y: np.ndarray, cfg: TrainConfig, progress: Progress | None
) -> DetectNet:
    """Cross-entropy with class weights (vehicles are the minority), flips and rotations."""
    net = DetectNet(x.shape[1])
    pos = float(y.mean())
    loss_fn = nn.CrossEntropyLoss(
        weight=torch.tensor([0.5 / (1 - pos), 0.5 / pos], dtype=torch.float32)
    )

    def loss_of(
        m: nn.Module, xb: torch.Tensor, yb: torch.Tensor, gen: torch.Generator
    ) -> torch.Tensor:
        out: torch.Tensor = loss_fn(m(_augment(xb, gen)), yb)
        return out

    _fit(net, x, y, loss_of, cfg.epochs_dr, cfg.seed, "N_dr", cfg, progress)
    return net


def train_lp(
    x: np.ndarray, y: np.ndarray, cfg: TrainConfig, progress: Progress | None
) -> LocateNet:
    """Binary cross-entropy against the Gaussian maps, weighted towards the rare peak cells."""
    net = LocateNet(x.shape[1])

    def loss_of(
        m: nn.Module, xb: torch.Tensor, yb: torch.Tensor, gen: torch.Generator
    ) -> torch.Tensor:
        out: torch.Tensor = nn.functional.binary_cross_entropy(m(xb), yb, weight=1.0 + 20.0 * yb)
        return out

    _fit(net, x, y, loss_of, cfg.epochs_lp, cfg.seed + 1, "N_lp", cfg, progress)
    return net


def _augment(xb: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Random flips and right-angle rotations (vehicles drive in any direction)."""
    k = int(torch.randint(4, (1,), generator=gen))
    xb = torch.rot90(xb, k, dims=(2, 3))
    if int(torch.randint(2, (1,), generator=gen)):
        xb = torch.flip(xb, dims=(3,))
    return xb


@dataclass
class Validation:
    """Held-out metrics of N_dr (on candidate windows) and N_lp (peaks within 3 px)."""

    dr_accuracy: float
    dr_precision: float
    dr_recall: float
    lp_precision: float
    lp_recall: float
    samples_dr: int
    samples_lp: int


def validate(nets: Nets, s: Samples) -> Validation:
    """N_dr accuracy, precision, recall on held-out windows; N_lp peaks matched within 3 px."""
    from lesmc.perception.detector import dr_probability, lp_maps, peaks

    x, y, lx, ly = s.arrays()
    p = dr_probability(nets, x.astype(np.float32) / 255.0) > nets.settings.delta_dr
    tp = int((p & (y == 1)).sum())
    maps = lp_maps(nets, lx.astype(np.float32) / 255.0)
    got, want = peaks(maps, nets.settings.delta_lp), peaks(ly, 0.5)
    ltp = lfp = lfn = 0
    for g, w in zip(got, want, strict=True):
        m = len(match(g[:, :2], w[:, :2], 3.0))
        ltp, lfp, lfn = ltp + m, lfp + len(g) - m, lfn + len(w) - m
    return Validation(
        dr_accuracy=float((p == (y == 1)).mean()),
        dr_precision=tp / max(int(p.sum()), 1),
        dr_recall=tp / max(int((y == 1).sum()), 1),
        lp_precision=ltp / max(ltp + lfp, 1),
        lp_recall=ltp / max(ltp + lfn, 1),
        samples_dr=len(x),
        samples_lp=len(lx),
    )


def train(cfg: TrainConfig, progress: Progress | None = None) -> tuple[Nets, Validation]:
    """Generate the videos, collect samples, train both networks, validate on a held-out video."""
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    tr = Samples()
    for seed in cfg.train_seeds:
        collect(cfg, seed, tr, rng, progress)
    x, y, lx, ly = tr.arrays()
    if not (0 < int(y.sum()) < len(y)) or not len(lx):
        raise UsageError(
            f"the training videos ({cfg.frames} frames of {cfg.width}x{cfg.height}) gave "
            f"{int(y.sum())} vehicle and {len(y) - int(y.sum())} background windows: both "
            "networks need some of each; use a larger --size or more --frames or --videos"
        )
    dr = train_dr(x, y, cfg, progress)
    lp = train_lp(lx, ly, cfg, progress)
    settings = NetSettings(
        trained_on=f"lesmc synth seeds {list(cfg.train_seeds)}, "
        f"{cfg.frames} frames {cfg.width}x{cfg.height}; "
        f"validated on seed {cfg.val_seed}"
    )
    nets = Nets(dr, lp, settings)
    va = Samples()
    collect(cfg, cfg.val_seed, va, rng, progress)
    return nets, validate(nets, va)
