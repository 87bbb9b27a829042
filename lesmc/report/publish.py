"""Results, then report: the one path ``check --report``, ``verify`` and ``report`` share.

:func:`publish` turns checked design runs into the results document
(lesmc/results/document.py) and draws the report from that document alone
(lesmc/report/html.py), exactly as ``lesmc report RESULTS.json`` does later.
Video frames come only from a directory named on the command line.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import LesmcError
from lesmc.report.figures import ImageFor
from lesmc.results.document import results_document
from lesmc.results.record import DesignRun

if TYPE_CHECKING:
    from lesmc.video.reader import FrameSet


def frames_reader(frames_dir: str | None) -> ImageFor | None:
    """``frame index -> grey image`` from a directory the user named (None: no images)."""
    if frames_dir is None:
        return None
    from lesmc.video.reader import open_frames

    return frame_reader(open_frames(frames_dir, 1, check=False))


def frame_reader(fs: FrameSet, skip_unreadable: bool = False) -> ImageFor:
    """``frame index -> grey image`` of ``fs``: None past its end and, with
    ``skip_unreadable``, for a frame that cannot be read (else its error). The figures of
    one counterexample draw the same few frames again and again (the default report: 12
    reads of 3 frames, 30 ms of PNG decoding each): each is decoded once and kept
    read-only, as every figure shares the array."""

    @lru_cache(maxsize=8)
    def read(index: int) -> np.ndarray | None:
        if not 0 <= index < len(fs):
            return None
        try:
            img = fs.read(index)
        except LesmcError:
            if skip_unreadable:
                return None
            raise
        img.setflags(write=False)
        return img

    return read


def publish(
    runs: list[DesignRun],
    out_dir: str | Path,
    meta: dict[str, Any],
    prov: dict[str, Any],
    image_for: ImageFor | None = None,
    timings: dict[str, float] | None = None,
    truth: list[Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Write OUT/results.json and OUT/report.html (+ figures/); return the report and the doc."""
    from lesmc.report.html import write_report

    doc = results_document(runs, meta, prov, timings, truth, extra)
    return write_report(doc, out_dir, image_for), doc
