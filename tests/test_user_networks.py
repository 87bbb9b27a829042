"""The user's detector networks (issue 26, item 3): ``.pt2`` and ``.onnx`` files through
``--detector``/``--locator``, their payoffs and certified bounds against the shipped CNNs',
onnxruntime as the oracle of the ONNX reader, and the refusals through the real CLI."""

from __future__ import annotations

import json
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_run import lesmc
from torch import nn

from lesmc.perception.certify import CertifyConfig, certified_radius
from lesmc.perception.chain import margin_of
from lesmc.perception.cnn import LP_SIZE, load_nets
from lesmc.perception.network_file import load_network
from lesmc.perception.ops_to_chain import chain_of_ops

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxscript")

BATCH = {0: torch.export.Dim("batch")}


def export(net: nn.Module, shape: tuple[int, ...], path: Path) -> Path:
    """``net`` as a .pt2 or .onnx file (by the suffix), with a dynamic batch."""
    x = torch.rand(3, *shape)
    if path.suffix == ".pt2":
        torch.export.save(torch.export.export(net, (x,), dynamic_shapes=(BATCH,)), path)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(
                net, (x,), path, dynamic_shapes=(BATCH,), dynamo=True, external_data=False
            )
    return path


@pytest.fixture(scope="module")
def shipped(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The shipped N_dr and N_lp exported both ways, and a small synthetic video."""
    d = tmp_path_factory.mktemp("nets")
    nets = load_nets()
    c = nets.settings.m + 1
    out = {"video": d / "v"}
    for suffix in ("pt2", "onnx"):
        out[f"dr.{suffix}"] = export(nets.dr, (c, 21, 21), d / f"dr.{suffix}")
        out[f"lp.{suffix}"] = export(nets.lp, (c, LP_SIZE, LP_SIZE), d / f"lp.{suffix}")
    r = lesmc("synth", str(out["video"]), "--frames", "6", "--size", "384x384", "--density", "3")
    assert r.returncode == 0, r.stderr
    _perceive(out["video"], d / "shipped.json")
    out["scene"] = d / "shipped.json"
    return out


def _perceive(video: Path, out: Path, *extra: str) -> dict[str, Any]:
    r = lesmc("perceive", str(video), "-o", str(out), "--max-iter", "20", "--certify", *extra)
    assert r.returncode == 0, r.stderr
    return json.loads(out.read_text())


@pytest.mark.parametrize("suffix", ["pt2", "onnx"])
def test_exported_shipped_networks_give_the_same_scene(
    shipped: dict[str, Path], tmp_path: Path, suffix: str
) -> None:
    """Same detections (ids; positions to 1e-6 px: the locator's sums may run in another
    order when torch's thread count differs, e.g. on a busy machine), DeepFool payoffs
    (1e-5 relative) and certified lower bounds."""
    want = json.loads(shipped["scene"].read_text())
    got = _perceive(
        shipped["video"], tmp_path / "b.json",
        "--detector", str(shipped[f"dr.{suffix}"]), "--locator", str(shipped[f"lp.{suffix}"]),
    )  # fmt: skip
    n = 0
    for fw, fg in zip(want["frames"], got["frames"], strict=True):
        assert [d["id"] for d in fg["detections"]] == [d["id"] for d in fw["detections"]]
        for dw, dg in zip(fw["detections"], fg["detections"], strict=True):
            assert (dg["x"], dg["y"]) == pytest.approx((dw["x"], dw["y"]), abs=1e-6)
        for dw, dg in zip(fw["detections"], fg["detections"], strict=True):
            for key in ("payoff", "payoff_lower"):
                a, b = dg[key], dw[key]
                if isinstance(b, str):
                    assert a == b
                else:
                    assert a == pytest.approx(b, rel=1e-5, abs=1e-7)
            n += 1
    assert n >= 5
    assert str(shipped[f"dr.{suffix}"]) in got["meta"]["detector"]


def test_the_onnx_reader_runs_as_onnxruntime(shipped: dict[str, Path]) -> None:
    ort = pytest.importorskip("onnxruntime")
    c = load_nets().settings.m + 1
    for name, size in (("dr.onnx", 21), ("lp.onnx", LP_SIZE)):
        net = load_network(shipped[name])
        x = np.random.default_rng(0).random((7, c, size, size), dtype=np.float32)
        sess = ort.InferenceSession(str(shipped[name]), providers=["CPUExecutionProvider"])
        want = sess.run(None, {sess.get_inputs()[0].name: x})[0]
        with torch.no_grad():
            got = net.module(torch.from_numpy(x)).numpy()
        assert got.shape == want.shape
        assert np.allclose(got, want, rtol=1e-5, atol=1e-6)


class Folded(nn.Module):
    """Operations the certification folds into its chain: input normalisation, batch
    norm, average pooling, constants added and multiplied."""

    def __init__(self, seed: int, pool: bool) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.c1 = nn.Conv2d(4, 6, 3)
        self.bn1 = nn.BatchNorm2d(6)
        self.c2 = nn.Conv2d(6, 6, 3, padding=1)
        self.pool = nn.AvgPool2d(2, 2) if pool else nn.Identity()
        self.c3 = nn.Conv2d(6, 6, 3)
        side = 7 if pool else 17
        self.fc = nn.Linear(6 * side * side, 12)
        self.out = nn.Linear(12, 2)
        for p in self.parameters():
            p.data = torch.randn(p.shape, generator=g) * 0.3
        self.bn1.running_mean.uniform_(-0.5, 0.5, generator=g)
        self.bn1.running_var.uniform_(0.5, 2.0, generator=g)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = (x - 0.5) / 0.25
        h = torch.relu(self.bn1(self.c1(x)))
        h = self.pool(torch.relu(self.c2(h)))
        h = torch.relu(self.c3(h) * 1.5 + 0.2)
        return self.out(torch.relu(self.fc(torch.flatten(h, 1))))


@pytest.mark.parametrize("seed", range(6))
def test_folded_operations_keep_the_margin_and_the_bounds_hold(tmp_path: Path, seed: int) -> None:
    """The chain's margin equals the network's logit difference, and no sampled input
    within the certified radius changes the decision (the bound contains the truth)."""
    net = Folded(seed, pool=seed % 2 == 0).eval()
    for suffix in ("pt2", "onnx") if seed < 2 else ("pt2",):
        user = load_network(export(net, (4, 21, 21), tmp_path / f"n.{suffix}"))
        chain = chain_of_ops(user.certifiable_ops(), user.in_shape, 0.0)
        x = torch.rand(64, 4, 21, 21, generator=torch.Generator().manual_seed(seed))
        with torch.no_grad():
            logits = net(x)
        want = logits[:, 1] - logits[:, 0]
        # float32 rounding grows with the logits' size (up to 8e-6 of the largest was seen,
        # 2.6e-4 at 34): a margin near zero is judged on that scale
        scale = float(want.abs().max())
        assert torch.allclose(margin_of(chain, x), want, rtol=1e-4, atol=2e-5 * scale + 1e-6)
    rng = np.random.default_rng(seed)
    x0 = rng.random((16, 4, 21, 21), dtype=np.float32)
    radius = certified_radius(chain, x0, np.full(16, 50.0, np.float32), CertifyConfig())
    for i in np.flatnonzero(radius > 0):
        d = rng.normal(size=(200, 4, 21, 21)).astype(np.float32)
        d *= radius[i] / np.linalg.norm(d.reshape(200, -1), axis=1)[:, None, None, None]
        with torch.no_grad():
            lg = net(torch.from_numpy(x0[i] + d))
        assert bool(((lg[:, 1] - lg[:, 0]) > 0).all())


class WithMaxPool(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.c = nn.Conv2d(4, 8, 3, padding=1)
        self.pool = nn.MaxPool2d(2, 2)
        self.fc = nn.Linear(8 * 10 * 10, 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(torch.flatten(self.pool(torch.relu(self.c(x))), 1))


@pytest.mark.parametrize("suffix", ["pt2", "onnx"])
def test_an_unsupported_operation_is_named_and_attacks_still_work(
    shipped: dict[str, Path], tmp_path: Path, suffix: str
) -> None:
    det = export(WithMaxPool().eval(), (4, 21, 21), tmp_path / f"detector.{suffix}")
    out = tmp_path / "s.json"
    r = lesmc(
        "perceive", str(shipped["video"]), "-o", str(out), "--certify", "--detector", str(det)
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    op = "MaxPool" if suffix == "onnx" else "max_pool2d"
    assert f"{det}: node '" in r.stderr
    assert f"{op} is not supported by certified bounds; payoffs from attacks still work" in r.stderr
    assert not out.exists()
    r = lesmc("perceive", str(shipped["video"]), "-o", str(out), "--max-iter", "5",
              "--detector", str(det))  # fmt: skip
    assert r.returncode == 0, r.stderr


def test_a_wrong_input_shape_is_refused(shipped: dict[str, Path], tmp_path: Path) -> None:
    net = nn.Sequential(nn.Conv2d(3, 4, 3), nn.ReLU(), nn.Flatten(), nn.Linear(4 * 19 * 19, 2))
    det = export(net.eval(), (3, 21, 21), tmp_path / "d.pt2")
    video = str(shipped["video"])
    r = lesmc("perceive", video, "-o", str(tmp_path / "s.json"), "--detector", str(det))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "the detector takes inputs of 3 channels of 21x21" in r.stderr, r.stderr


def test_a_pickled_payload_is_refused_without_unpickling(
    shipped: dict[str, Path], tmp_path: Path
) -> None:
    """An archive whose weights say ``use_pickle`` is refused before anything is loaded."""
    src = zipfile.ZipFile(shipped["dr.pt2"])
    bad = tmp_path / "bad.pt2"
    with zipfile.ZipFile(bad, "w") as dst:
        for info in src.infolist():
            data = src.read(info.filename)
            if info.filename.endswith("model_weights_config.json"):
                data = data.replace(b'"use_pickle": false', b'"use_pickle": true', 1)
            dst.writestr(info, data)
    with pytest.raises(Exception, match="stored pickled; lesmc never unpickles"):
        load_network(bad)
    junk = tmp_path / "junk.pt2"
    junk.write_bytes(b"PK\x03\x04 not really")
    video = str(shipped["video"])
    r = lesmc("perceive", video, "-o", str(tmp_path / "s.json"), "--detector", str(junk))
    assert r.returncode == 2 and "not a torch.export archive" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_chain_that_misreads_the_network_is_refused(shipped: dict[str, Path]) -> None:
    """The guard behind every certification of a user's detector: a chain computing another
    margin than the network's forward pass is an error, not a silently wrong bound."""
    from lesmc.common.errors import InputError
    from lesmc.perception.certify import detect_chain
    from lesmc.perception.cnn import DetectNet
    from lesmc.perception.graphs import same_margin
    from lesmc.perception.run import detector_chain

    nets = load_nets(None, str(shipped["dr.pt2"]))
    detector_chain(nets, 0.0)  # the true reading passes
    torch.manual_seed(1)
    other = DetectNet(nets.settings.m + 1).eval()
    with pytest.raises(InputError, match="does not compute its forward pass"):
        same_margin(nets.dr_file, detect_chain(other, 0.0), 0.0)
