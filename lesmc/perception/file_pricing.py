"""A detector file's detections priced (and certified) some at a time, after perception.

``lesmc verify --detector`` prices a detection when a model first reads its payoff, and
``lesmc campaign --detector --payoffs certified|interval`` certifies the detections a
check's model can hide (lesmc/experiment/detector_verify.py). Both know a detection by
its frame and its place K among the frame's detections, as the scene holds them. One
interface, :class:`FilePricing`, serves both kinds of detector file (docs/detectors.md):

* heatmap: a detection is found again by its cell (``cells_of`` its position) and priced
  by the crop attack ``lesmc perceive --detector`` runs (heatmap_attack.price_cells), or
  certified by the crop bound propagation (heatmap_certify.certify_cells);
* boxes: the frame is decoded again (one network run) for the detections' boxes, which
  must be the scene's, and each asked-for box is priced by the whole-frame attack
  (boxes.price_box_list). Box detectors are attack-only: certifying is refused.

Each detection's attack (and bound) is its own, so a detection priced on demand gets the
payoff it gets when every detection is priced up front.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import UsageError

if TYPE_CHECKING:
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.detector_file import LoadedDetector
    from lesmc.video.reader import FrameSet

#: How far (pixels) a box's centre decoded again may lie from the scene's (the scene file
#: keeps positions to its own precision).
SAME_PX = 1e-3


class FilePricing:
    """Prices (and, for a heatmap, certifies) chosen detections of one video's frames
    through a loaded detector file, with the attack settings ``cfg``."""

    def __init__(self, det: LoadedDetector, frames: FrameSet, cfg: AttackConfig) -> None:
        self.det, self.frames, self.cfg = det, frames, cfg
        self._how: Any = None  # heatmap_attack.Pricing, made on the first heatmap request
        self._conv: Any = None  # heatmap_crop.ConvNet, on the first certification

    def price(self, k: int, positions: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(len(idx),) the payoffs of detections ``idx`` of frame ``k``, whose detections
        sit at the (n, 2) ``positions`` (``inf``: unattackable)."""
        from lesmc.perception.heatmap import frame_input

        arr = frame_input(self.frames, k, self.det)
        if self.det.spec.kind == "boxes":
            from lesmc.perception.boxes import price_box_list

            return price_box_list(self.det, arr, self._boxes(arr, k, positions)[idx], self.cfg)
        from lesmc.perception.heatmap_attack import price_cells, pricing

        if self._how is None:
            self._how = pricing(self.det, self.cfg)
        return price_cells(self._how, arr, self._cells(positions)[idx], k)

    def certify(
        self, k: int, positions: np.ndarray, idx: np.ndarray, upper: np.ndarray
    ) -> np.ndarray:
        """(len(idx),) certified lower bounds of detections ``idx`` of frame ``k``, at most
        their payoffs ``upper`` (len(idx),), as ``lesmc perceive --detector --certify``
        bounds them (:func:`refuse_uncertifiable` first)."""
        from lesmc.perception.heatmap import frame_input
        from lesmc.perception.heatmap_attack import raw_threshold
        from lesmc.perception.heatmap_certify import certifiable, certify_cells

        if self._conv is None:
            self._conv = certifiable(self.det)
        arr = frame_input(self.frames, k, self.det)
        cells = self._cells(positions)[idx]
        return certify_cells(
            self.det, arr, cells, np.asarray(upper, float), raw_threshold(self.det),
            conv=self._conv,
        )  # fmt: skip

    def _cells(self, positions: np.ndarray) -> np.ndarray:
        """A heatmap's detections' cells, from their positions."""
        from lesmc.perception.heatmap import cells_of

        return cells_of(positions, self.det.spec.stride)

    def _boxes(self, arr: np.ndarray, k: int, positions: np.ndarray) -> np.ndarray:
        """Frame ``k``'s boxes decoded again from its input ``arr``; they must sit where the
        scene's detections (``positions``) do."""
        from lesmc.perception.boxes import detect_boxes

        bd = detect_boxes(arr, self.det, k)
        pos = np.asarray(positions, float).reshape(-1, 2)
        if bd.positions.shape != pos.shape or not np.allclose(
            bd.positions, pos, rtol=0, atol=SAME_PX
        ):
            raise UsageError(
                f"frame {k}: the detector file {self.det.spec.path} now finds other boxes "
                f"({len(bd.boxes)}) than the perceived ones ({len(pos)}) it was asked to "
                "price: perceive the video again (remove OUT/cache)"
            )
        return np.asarray(bd.boxes)


def refuse_uncertifiable(det: LoadedDetector, option: str = "--certify") -> None:
    """A detector file whose detections get no certified bounds is a located error, before
    any frame is perceived: a box detector (attack-only), or a heatmap network outside the
    chain the bound propagation supports (heatmap_certify.certifiable names the node).
    ``option``: what asked for the bounds, named in the error."""
    from lesmc.perception.detector_file import located
    from lesmc.perception.heatmap_certify import certifiable

    if det.spec.kind == "boxes":
        raise located(
            det.spec, "kind",
            "box-list detectors are attack-only: certified bounds are built for fully "
            f"convolutional heatmap detectors (drop {option})",
        )  # fmt: skip
    certifiable(det)
