"""Reading a directory of frames: natural sort order, grey or colour, 8 or 16 bit.

Everything is checked before the first frame is processed (every file decodes,
all have one size of at least :data:`MIN_SIDE` pixels a side, there are enough of
them, none is a symbolic link leading out of the directory), so a bad directory
fails at once with the file named and nothing written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lesmc.common.errors import InputError, Location

EXTENSIONS = {".png", ".tif", ".tiff", ".jpg", ".jpeg"}
#: Smallest width and height of a frame (pixels): less cannot be registered or windowed.
MIN_SIDE = 8


def natural_key(name: str) -> list[object]:
    """Sort key so that ``frame2.png`` comes before ``frame10.png``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


@dataclass(frozen=True)
class FrameSet:
    """A checked list of frame files of one size, and the scale that maps them to 8 bit."""

    paths: list[Path]
    width: int
    height: int
    scale: float  # multiply raw values by this to get grey levels 0..255

    def __len__(self) -> int:
        return len(self.paths)

    def read(self, i: int) -> np.ndarray:
        """Frame ``i`` as a uint8 grey image."""
        return to_grey8(_imread(self.paths[i]), self.scale)

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self.paths)):
            yield self.read(i)


def _imread(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError("cannot decode the image (not a PNG, TIFF or JPEG?)", Location(str(path)))
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(
            f"unsupported pixel type {img.dtype} (8 or 16 bit only)", Location(str(path))
        )
    if img.ndim == 3 and img.shape[2] not in (1, 3, 4):
        raise InputError(f"unsupported channel count {img.shape[2]}", Location(str(path)))
    return img


def to_grey8(img: np.ndarray, scale: float) -> np.ndarray:
    """Colour to grey (OpenCV's luma weights), then scale to 0..255 uint8."""
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code) if img.shape[2] != 1 else img[:, :, 0]
    if img.dtype == np.uint8 and scale == 1.0:
        return img
    return cv2.convertScaleAbs(img, alpha=scale)


def _check_inside(path: Path, root: Path) -> None:
    """``path`` (listed in ``root``) is a regular file inside ``root``: a symbolic link that
    leads out of the directory the user named is refused, so is anything but a file."""
    if path.is_symlink():
        try:
            target = path.resolve(strict=True)
            inside = target.is_relative_to(root.resolve(strict=True))
        except (OSError, RuntimeError):  # dangling link, or a loop
            raise InputError("a broken symbolic link", Location(str(path))) from None
        if not inside:
            raise InputError(
                "a symbolic link leading out of the frames directory (refused: only the "
                "directory given is read)",
                Location(str(path)),
            )
    if not path.is_file():
        raise InputError("not a regular file", Location(str(path)))


def open_frames(directory: str | Path, minimum: int, check: bool = True) -> FrameSet:
    """List, sort and check the frames of ``directory`` (at least ``minimum`` of them).

    With ``check`` every frame is decoded up front (so a bad file fails before
    any work); without, only the first (for its size and scale).

    16-bit frames are scaled to 8 bit by one factor for the whole video (taken
    from the first frame's 99.9th percentile), so that grey levels stay
    comparable between frames, which background subtraction relies on.
    """
    root = Path(directory)
    if not root.is_dir():
        raise InputError("not a directory of frames", Location(str(root)))
    paths = sorted(
        (
            p
            for p in root.iterdir()
            if p.suffix.lower() in EXTENSIONS and not p.name.startswith(".")
        ),
        key=lambda p: natural_key(p.name),
    )
    for p in paths:
        _check_inside(p, root)
    if len(paths) < minimum:
        raise InputError(
            f"{len(paths)} frame(s) found, at least {minimum} are needed "
            f"(the background model uses the previous frames)",
            Location(str(root)),
        )
    size: tuple[int, int] | None = None
    scale = 1.0
    todo = paths if check else paths[:1]
    # a header-only check would be faster, but decoding is the only sure test; frames
    # are decoded on two threads (OpenCV's decoders release the GIL; two frames held at
    # once, less than perception's history holds) and looked at in order, so the first
    # bad file in sort order is the one reported
    workers = max(1, min(2, len(os.sched_getaffinity(0)), len(todo)))
    pool = ThreadPoolExecutor(workers, thread_name_prefix="lesmc-frames")
    try:
        facts = pool.map(_facts, todo, [i == 0 for i in range(len(todo))])
        for p, (shape, first_scale) in zip(todo, facts, strict=True):
            if min(shape) < MIN_SIDE:
                raise InputError(
                    f"frame is {shape[0]}x{shape[1]} pixels; frames must be at least "
                    f"{MIN_SIDE}x{MIN_SIDE}",
                    Location(str(p)),
                )
            if size is None:
                size, scale = shape, first_scale
            elif shape != size:
                raise InputError(
                    f"frame is {shape[0]}x{shape[1]} but {paths[0].name} is "
                    f"{size[0]}x{size[1]}: all frames must have one size",
                    Location(str(p)),
                )
    finally:  # a bad frame (or Ctrl-C) leaves the frames after it undecoded
        pool.shutdown(wait=True, cancel_futures=True)
    assert size is not None
    return FrameSet(paths, size[0], size[1], scale)


def _facts(path: Path, first: bool) -> tuple[tuple[int, int], float]:
    """A frame decoded: its (width, height), and for the first frame of a 16-bit video the
    scale to 8 bit (from its 99.9th percentile), else 1."""
    img = _imread(path)
    scale = 1.0
    if first and img.dtype == np.uint16:
        top = float(np.percentile(img, 99.9)) or 1.0
        scale = 255.0 / top
    return (img.shape[1], img.shape[0]), scale
