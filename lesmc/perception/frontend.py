"""The classical front end run frame by frame: register, align, median, subtract, blobs.

``FrontEnd.push`` takes frames in order and, once L previous frames are held,
returns the candidates Q_bc of the new frame together with what later stages
(the CNNs) need: the aligned previous frames and the homography to the
previous frame. Frames before that only fill the history.

:func:`registered_ahead` reads and registers the next frame on a second thread while
the caller works on the current one (the CNNs, the attack).
"""

from __future__ import annotations

from collections.abc import Generator, Iterable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from lesmc.perception import HISTORY
from lesmc.perception.background import Aligned, FrameHistory, background
from lesmc.perception.blobs import BlobConfig, Blobs, blobs, foreground
from lesmc.perception.registration import (
    Features,
    Registration,
    RegistrationConfig,
    describe,
    register,
)


@dataclass(frozen=True)
class FrontEndConfig:
    """All front-end settings; ``history`` is the paper's L (4 or 5)."""

    history: int = HISTORY
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    blobs: BlobConfig = field(default_factory=BlobConfig)


@dataclass
class FrontEndOutput:
    """What the front end found in one frame."""

    index: int  # position of the frame in the video
    frame: np.ndarray
    candidates: Blobs
    aligned: Aligned  # previous frames in this frame's pixels, oldest first
    background: np.ndarray
    registration: Registration  # previous frame -> this frame


class FrontEnd:
    """Stateful frame-by-frame runner of the front end.

    ``known``: registrations an earlier pass over the same frames made (frame index ->
    its registration from the previous frame, :attr:`registrations` of that pass). Such a
    frame is not described or matched again: registration is deterministic, so the
    result is the same (the replay of lesmc verify uses this for its attacked frames).
    """

    def __init__(
        self, cfg: FrontEndConfig | None = None, known: Mapping[int, Registration] | None = None
    ) -> None:
        self.cfg = cfg or FrontEndConfig()
        if self.cfg.history < 1:
            raise ValueError("history (L) must be at least 1")
        self.history = FrameHistory(self.cfg.history)
        self.features: Features | None = None  # of the newest frame, when it was described
        self.index = -1
        self.known: Mapping[int, Registration] = known or {}
        #: frame index -> its registration from the previous frame (h_k^{k-1}, Eq. 15)
        self.registrations: dict[int, Registration] = {}

    def push(
        self, frame: np.ndarray, registration: Registration | None = None
    ) -> FrontEndOutput | None:
        """Feed the next uint8 grey frame; candidates once L previous frames are known.

        ``registration``: this frame's from the previous one, when the caller made it
        (:func:`registered_ahead`); otherwise it is made here.
        """
        self.index += 1
        out = None
        feats = None
        if self.history.frames:
            reg = self.known.get(self.index, registration)
            if reg is None:
                prev = self.history.frames[-1]
                before = self.features
                if before is None:  # the first frame, or one whose registration was known
                    before = describe(prev, self.cfg.registration)
                feats = describe(frame, self.cfg.registration)
                reg = register(before, feats, self.cfg.registration, prev, frame)
            self.registrations[self.index] = reg
            self.history.advance(reg.homography)
            if self.history.full():
                out = self._detect(frame, reg)
        self.history.push(frame)
        self.features = feats
        return out

    def _detect(self, frame: np.ndarray, reg: Registration) -> FrontEndOutput:
        size = (frame.shape[1], frame.shape[0])
        aligned = self.history.aligned(size)
        bg = background(aligned, frame)
        diff, mask = foreground(frame, bg, aligned.valid, self.cfg.blobs)
        cands = blobs(mask, diff, self.cfg.blobs)
        return FrontEndOutput(self.index, frame, cands, aligned, bg, reg)


def registered_ahead(
    images: Iterable[np.ndarray], cfg: RegistrationConfig
) -> Generator[tuple[np.ndarray, Registration | None], None, None]:
    """Each frame with its registration from the previous one (None for the first).

    The next frame is read (decoded) and registered on a second thread while the
    caller works on this one: registration is OpenCV's and faiss's work (ORB, exact
    matching, RANSAC, Lucas-Kanade), which releases the GIL, and depends on nothing
    the caller computes, so the result is the same as :meth:`FrontEnd.push` makes.
    An error reading or registering frame k is raised when frame k is asked for.
    """
    frames = iter(images)
    prev: tuple[np.ndarray, Features] | None = None  # the last frame read, described

    def step() -> tuple[np.ndarray, Registration | None] | None:
        nonlocal prev
        img = next(frames, None)
        if img is None:
            return None
        feats = describe(img, cfg)
        reg = None if prev is None else register(prev[1], feats, cfg, prev[0], img)
        prev = (img, feats)
        return img, reg

    pool = ThreadPoolExecutor(1, thread_name_prefix="lesmc-register")
    try:
        pending: Future[tuple[np.ndarray, Registration | None] | None] = pool.submit(step)
        while (got := pending.result()) is not None:
            pending = pool.submit(step)
            yield got
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
