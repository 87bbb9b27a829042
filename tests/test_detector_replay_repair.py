"""The replay through a detector file repairs its attacks (issue 61, item 4; docs/detectors.md,
"Replay"; lesmc/replay/repair.py, the loop the window pipeline's replay uses too).

The hand-set heatmap network of tests/spot_detector.py on one frame: a bright spot at
(40, 28) and a fainter one (grey 110) 13 px below it. The faint spot's peak cell scores
above the threshold but lies within the NMS square of a brighter cell of the bright
spot's tail: it is no detection of the clean frame. Hiding the bright spot (its square
driven below the threshold, the attack the scene priced) lifts that suppression: the
faint spot comes out as an extra detection, which the model does not have. Without the
repair (round limit 0) the attacked frame keeps it; with it, one round attacks it away
on the perturbed input, and the frame has no detection left. The repair's cost is the
L2 norm of the perturbations it added (recomputed here from the perturbations the attack
hands back, not from the replay's bookkeeping), and onnxruntime, given the frame plus
every perturbation, decodes no cell at or above the threshold.

The same two spots move right 4 px a frame (one stride: every frame decodes alike) past a
static spot 16 px above the track at frame 6. The model's cheapest counterexample
(``SPEC``) hides the moving spot at step 6 so that the tracker takes the static one.
Replayed without the repair, the revealed faint spot, 13 px from the track, is nearer
than the static one: the tracker takes it and the replay diverges at step 6. With the
repair it is confirmed, ``"attack": "repaired"``; and under a
threshold between the optimum and the optimum plus ``repair_cost`` the repaired attack
makes the property hold, so the replay is diverged (docs/semantics.md, "Repaired attack").

A box-list file (tests/test_detector_replay_boxes.py's box head) has the same case: a
faint spot's box that NMS drops beside the bright one's comes out once that is hidden,
and the repair hides it. And an injection whose perturbation falls short (handed back at
half its size) leaves the candidate undetected; the repair raises it again.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import lesmc
from spot_detector import SPEC, H, W, write_spot_detector

from lesmc.perception.attack_settings import AttackConfig
from lesmc.results.read import HiddenDoc

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

BRIGHT, FAINT = (40, 28), (40, 41)  # the spots' centres (x, y)


def _frame() -> np.ndarray:
    """The network input (1, 1, H, W): the two spots, blurred, in [0, 1]."""
    img = np.full((H, W), 20, np.uint8)
    cv2.circle(img, BRIGHT, 3, 230, -1)
    cv2.circle(img, FAINT, 3, 110, -1)
    img = cv2.GaussianBlur(img, (5, 5), 1.0)
    return (img.astype(np.float32) / np.float32(255.0))[None, None]


@pytest.fixture(scope="module")
def spot(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Path]:
    """The loaded detector file and its directory (spot.onnx)."""
    from lesmc.perception.detector_file import load_detector

    d = tmp_path_factory.mktemp("detrepair")
    return load_detector(str(write_spot_detector(d))), d


def _raw(d: Path, x: np.ndarray) -> np.ndarray:
    """onnxruntime's raw heatmap (rows, cols) of input ``x``."""
    sess = ort.InferenceSession(str(d / "spot.onnx"))
    out: np.ndarray = sess.run(None, {sess.get_inputs()[0].name: x})[0][0, 0]
    return out


def _spy(monkeypatch: pytest.MonkeyPatch, boxes: bool = False) -> list[list[np.ndarray]]:
    """Every call of the hiding attack (heatmap, or ``boxes``) records the perturbations
    it hands back."""
    from lesmc.perception import boxes as box_module
    from lesmc.perception import heatmap_attack

    module: Any = box_module if boxes else heatmap_attack
    name = "price_boxes" if boxes else "price_frame"
    calls: list[list[np.ndarray]] = []
    real = getattr(module, name)

    def spying(*args: Any) -> Any:
        *rest, save = args if len(args) == (5 if boxes else 4) else (*args, None)
        got: list[np.ndarray] = []
        calls.append(got)

        def keep(k: int, delta: np.ndarray) -> None:
            got.append(delta.copy())
            if save is not None:
                save(k, delta)

        return real(*rest, keep)

    monkeypatch.setattr(module, name, spying)
    return calls


def _attack(det: Any) -> Any:
    """The replay's attack on the frame that hides the bright spot (detection 0:0)."""
    from lesmc.replay.detector_file import _decode, attack_frame

    x = _frame()
    clean = _decode(det, x, 0)
    assert len(clean.positions) == 1  # the faint spot is suppressed: no detection
    assert np.hypot(*(clean.positions[0] - BRIGHT)) < 4
    hidden = HiddenDoc(1, 0, "0:0", math.nan, math.nan, math.nan)
    return attack_frame(det, x, clean, [hidden], AttackConfig())


def _near_faint(points: list[tuple[float, float]]) -> bool:
    return any(math.hypot(px - FAINT[0], py - FAINT[1]) < 4 for px, py in points)


def test_without_the_repair_the_hidden_spot_reveals_its_neighbour(
    spot: tuple[Any, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    from lesmc.replay import detector_file

    det, d = spot
    monkeypatch.setattr(detector_file, "REPAIR_ROUNDS", 0)
    calls = _spy(monkeypatch)
    fa = _attack(det)
    assert fa.repaired_rounds == 0 and fa.extra_cost == 0.0
    assert not fa.still and _near_faint(fa.extra), fa.extra
    assert len(calls) == 1 and len(calls[0]) == 1
    y = _raw(d, _frame() + calls[0][0])  # the priced hiding alone, through onnxruntime
    i, j = FAINT[1] // 4, FAINT[0] // 4
    assert float(y[i - 1 : i + 2, j - 1 : j + 2].max()) >= 0.0  # the faint spot detected
    assert float(y[5:10, 8:13].max()) < 0.0  # and the bright one's square hidden


def test_the_repair_hides_the_neighbour_at_the_cost_of_its_norm(
    spot: tuple[Any, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    det, d = spot
    calls = _spy(monkeypatch)
    fa = _attack(det)
    assert fa.repaired_rounds >= 1
    assert not fa.still and not fa.extra and not fa.lost
    assert len(fa.detections.positions) == 0
    first, repair = calls[0], [delta for call in calls[1:] for delta in call]
    assert len(first) == 1 and repair
    norms = [float(np.sqrt((r.astype(np.float64) ** 2).sum())) for r in repair]
    assert fa.extra_cost == pytest.approx(sum(norms), rel=1e-9)
    assert fa.extra_windows == len(repair)  # each extra perturbation counted once
    assert fa.perturbations[0]["payoff_recomputed"] == pytest.approx(
        float(np.sqrt((first[0].astype(np.float64) ** 2).sum())), rel=1e-9
    )
    x = _frame() + first[0] + sum(repair, np.zeros_like(first[0]))
    assert float(_raw(d, x).max()) < 0.0  # onnxruntime: no cell at or above the threshold


STATIC = (32, 12)  # the static spot (x, y), 16 px above the track at frame 6


def _video(d: Path) -> Path:
    """12 frames: the bright spot at (8 + 4k, 28), the faint one 13 px below, the static one."""
    fr = d / "frames"
    fr.mkdir()
    for k in range(12):
        img = np.full((H, W), 20, np.uint8)
        cv2.circle(img, (8 + 4 * k, BRIGHT[1]), 3, 230, -1)
        cv2.circle(img, (8 + 4 * k, FAINT[1]), 3, 110, -1)
        cv2.circle(img, STATIC, 3, 230, -1)
        cv2.imwrite(str(fr / f"f{k:02d}.png"), cv2.GaussianBlur(img, (5, 5), 1.0))
    return fr


@pytest.fixture(scope="module")
def checked(spot: tuple[Any, Path]) -> dict[str, Any]:
    """``lesmc perceive`` and ``lesmc check --report`` of :data:`SPEC` on the video."""
    _, d = spot
    frames, scene = _video(d), d / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(d / "spot.toml"), "-o", str(scene),
              "--target", "8,28@0")  # fmt: skip
    assert r.returncode == 0, r.stderr
    (d / "p.spec").write_text(SPEC)
    r = lesmc("check", str(scene), str(d / "p.spec"), "--json", "--report", str(d / "rep"))
    assert r.returncode == 1, r.stdout + r.stderr
    res = json.loads(r.stdout)["results"][0]
    return {"dir": d, "frames": frames, "results": d / "rep" / "results.json", "res": res}


class _Bar:
    """A progress bar that shows nothing."""

    def update(self, **_: Any) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


def _replay(checked: dict[str, Any], threshold: float | None = None) -> dict[str, Any]:
    """The in-process replay of the results (their threshold replaced by ``threshold``)."""
    from lesmc.replay.detector_file import replay_with_file
    from lesmc.results.load import load_results
    from lesmc.results.read import results_of

    raw = load_results(str(checked["results"]))
    if threshold is not None:
        raw["runs"][0]["results"][0]["threshold"] = threshold
    doc = results_of(raw)
    toml = str(checked["dir"] / "spot.toml")
    out = replay_with_file(doc, str(checked["frames"]), toml, None, _Bar())  # type: ignore[arg-type]
    rp: dict[str, Any] = out.replays[(0, 0)]
    return rp


def test_the_counterexample_hides_the_track_for_the_static_spot(checked: dict[str, Any]) -> None:
    run = json.loads(checked["results"].read_text())["runs"][0]
    (hid,) = run["hidden"]["hide_cheap"]  # the moving spot at frame 6 (34, 30), alone
    assert (hid["step"], hid["obs"], hid["x"], hid["y"]) == (6, "6:1", 34.0, 30.0)
    taken = {s["step"]: s["obs"] for s in checked["res"]["counterexample"]["steps"]}
    assert taken[6] == "6:0"  # the static spot, 16 px from the track
    assert checked["res"]["optimum"] < 10


def test_without_the_repair_the_replay_diverges(
    checked: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    from lesmc.replay import detector_file

    monkeypatch.setattr(detector_file, "REPAIR_ROUNDS", 0)
    rp = _replay(checked)
    assert rp["status"] == "diverged" and rp["step"] == 6, rp
    assert rp["attack"] == "as modelled" and rp["repair_cost"] == 0.0
    # the faint spot at frame 6, (32, 41): the centre of its cell (10, 8) is (34, 42)
    assert "extra detection (34.0, 42.0)" in rp["reason"]


def test_the_repaired_replay_is_confirmed(checked: dict[str, Any]) -> None:
    rp = _replay(checked)
    assert rp["status"] == "confirmed", rp
    assert rp["attack"] == "repaired" and rp["repair_cost"] > 0
    assert rp["frames"] == ["frame 6: after 1 round(s) of the repaired joint attack"]
    checked["repaired"] = rp


def test_a_repair_that_costs_the_property_diverges(checked: dict[str, Any]) -> None:
    full = checked.get("repaired") or _replay(checked)
    opt, extra = checked["res"]["optimum"], full["repair_cost"]
    assert full["status"] == "confirmed" and extra > 0
    rp = _replay(checked, opt + extra / 2)  # optimum > T only with the repair's cost
    assert rp["status"] == "diverged" and rp["step"] == 6, rp
    assert "the repaired joint attack replays, but costs" in rp["reason"]


def _box_detector(d: Path) -> Any:
    """tests/test_detector_replay_boxes.py's box head on the spot network (reshaped to
    constant sizes: TorchScript's exporter then writes no Shape node, in a fraction of
    the dynamo exporter's time), loaded."""
    import torch
    from test_detector_replay_boxes import HALF, SpotBoxes

    from lesmc.perception.detector_file import load_detector

    class Fixed(SpotBoxes):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            s = self.body(x).reshape(-1, 1, (H // 4) * (W // 4))
            cx, cy = self.cx + 0.0 * s, self.cy + 0.0 * s
            rows = torch.cat([cx - HALF, cy - HALF, cx + HALF, cy + HALF, s], dim=1)
            return rows.transpose(1, 2)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            Fixed().eval(), (torch.rand(2, 1, H, W),), d / "boxes.onnx", dynamo=False,
            input_names=["x"], dynamic_axes={"x": {0: "batch"}},
        )  # fmt: skip
    toml = d / "boxes.toml"
    toml.write_text(
        'kind = "boxes"\nnetwork = "boxes.onnx"\nthreshold = 0.0\nscore = "raw"\niou_nms = 0.1\n'
    )
    return load_detector(str(toml))


def test_a_box_list_repair_hides_the_box_its_neighbour_suppressed(
    spot: tuple[Any, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Boxes: a faint spot 8 px below the bright one; its 12 x 12 box overlaps the bright
    one's by IoU 0.2 > ``iou_nms`` 0.1, so NMS drops it; the bright box hidden, it is an
    extra detection; the repair hides it too."""
    from lesmc.replay.detector_file import _decode, attack_frame

    _, d = spot
    det = _box_detector(d)
    img = np.full((H, W), 20, np.uint8)
    cv2.circle(img, BRIGHT, 3, 230, -1)
    cv2.circle(img, (BRIGHT[0], BRIGHT[1] + 8), 3, 110, -1)
    x = (cv2.GaussianBlur(img, (5, 5), 1.0).astype(np.float32) / np.float32(255.0))[None, None]
    clean = _decode(det, x, 0)
    assert clean.positions.tolist() == [[42.0, 30.0]]  # the bright spot's box alone
    hidden = HiddenDoc(1, 0, "0:0", math.nan, math.nan, math.nan)
    calls = _spy(monkeypatch, boxes=True)
    fa = attack_frame(det, x, clean, [hidden], AttackConfig())
    assert fa.repaired_rounds == 1 and not fa.extra and len(fa.detections.positions) == 0
    first, repair = calls[0], [delta for call in calls[1:] for delta in call]
    assert len(first) == 1 and repair
    norms = [float(np.sqrt((r.astype(np.float64) ** 2).sum())) for r in repair]
    assert fa.extra_cost == pytest.approx(sum(norms), rel=1e-9)
    assert fa.extra_windows == len(repair)  # each extra perturbation counted once
    sess = ort.InferenceSession(str(d / "boxes.onnx"))
    rows = sess.run(None, {sess.get_inputs()[0].name: x + first[0]})[0][0]
    live = rows[rows[:, 4] >= 0.0]  # the priced hiding alone: the faint spot's box is left
    assert len(live) and np.allclose(live[:, :4].mean(axis=0), [36.0, 32.0, 48.0, 44.0])
    rows = sess.run(None, {sess.get_inputs()[0].name: x + first[0] + sum(repair)})[0][0]
    assert float(rows[:, 4].max()) < 0.0  # with the repair's: no box scores at the threshold


def test_an_injection_that_falls_short_is_raised_again(
    spot: tuple[Any, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Hide the bright spot and inject the faint one 14 px below it (a local maximum
    below the threshold), the injection's first perturbation handed back at half its
    size: the candidate is not detected, and the repair raises it again on the perturbed
    input, at the cost of that second perturbation's norm."""
    import torch

    from lesmc.perception import heatmap_attack
    from lesmc.perception.detector_file import score_of
    from lesmc.perception.heatmap import sub_peaks
    from lesmc.replay.detector_file import _decode, attack_listed

    det, d = spot
    img = np.full((H, W), 20, np.uint8)
    cv2.circle(img, BRIGHT, 3, 230, -1)
    cv2.circle(img, (BRIGHT[0], BRIGHT[1] + 14), 3, 100, -1)
    x = (cv2.GaussianBlur(img, (5, 5), 1.0).astype(np.float32) / np.float32(255.0))[None, None]
    clean = _decode(det, x, 0)
    with torch.no_grad():
        raw = det.score_maps(det.net.module(torch.from_numpy(x)))[0].double().numpy()
    subs = sub_peaks(score_of(raw, det.spec.score), det.spec.threshold, det.spec.nms_radius)
    k = int(np.argmin(np.abs(subs - [(BRIGHT[1] + 14) / 4, BRIGHT[0] / 4]).sum(axis=1)))
    cell = subs[k]
    assert cell.tolist() == [11, 10]  # the faint spot's peak, 3 rows below the bright one's
    real, handed = heatmap_attack.price_candidates, []

    def short(p: Any, frame: np.ndarray, fd: Any, save: Any) -> Any:
        def keep(k: int, delta: np.ndarray) -> None:
            handed.append(delta.copy())
            save(k, delta * np.float32(0.5) if len(handed) == 1 else delta)

        return real(p, frame, fd, keep)

    monkeypatch.setattr(heatmap_attack, "price_candidates", short)
    hides = _spy(monkeypatch)
    hidden = HiddenDoc(1, 0, "0:0", math.nan, math.nan, math.nan)
    fa = attack_listed(det, (x, clean), 1, ([hidden], [(f"0:c{k}", cell)]), AttackConfig())
    assert len(handed) == 2 and fa.repaired_rounds == 1
    assert not fa.not_injected and not fa.still and not fa.extra
    assert fa.detections.raw.cells.tolist() == [cell.tolist()]
    second = float(np.sqrt((handed[1].astype(np.float64) ** 2).sum()))
    assert fa.extra_cost == pytest.approx(second, rel=1e-9) and fa.extra_windows == 1
    (hide,) = hides[0]
    y = _raw(d, x + hide + np.float32(0.5) * handed[0] + handed[1])  # through onnxruntime
    i, j = (int(v) for v in cell)
    assert float(y[i, j]) >= 0.0 and y[i, j] == y[i - 2 : i + 3, j - 2 : j + 3].max()
    assert float(y[5:10, 8:13].max()) < 0.0  # the bright spot's square still hidden
