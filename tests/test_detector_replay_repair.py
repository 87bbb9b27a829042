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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from spot_detector import H, W, write_spot_detector

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


def _spy(monkeypatch: pytest.MonkeyPatch) -> list[list[np.ndarray]]:
    """Every call of the heatmap hiding attack records the perturbations it hands back."""
    from lesmc.perception import heatmap_attack

    calls: list[list[np.ndarray]] = []
    real = heatmap_attack.price_frame

    def spying(p: Any, frame: np.ndarray, fd: Any, save: Callable[..., None] | None = None) -> Any:
        got: list[np.ndarray] = []
        calls.append(got)

        def keep(k: int, delta: np.ndarray) -> None:
            got.append(delta.copy())
            if save is not None:
                save(k, delta)

        return real(p, frame, fd, keep)

    monkeypatch.setattr(heatmap_attack, "price_frame", spying)
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
    assert fa.perturbations[0]["payoff_recomputed"] == pytest.approx(
        float(np.sqrt((first[0].astype(np.float64) ** 2).sum())), rel=1e-9
    )
    x = _frame() + first[0] + sum(repair, np.zeros_like(first[0]))
    assert float(_raw(d, x).max()) < 0.0  # onnxruntime: no cell at or above the threshold
