"""A synthetic video written to a directory: frames and truth.json, all or nothing.

Rendering itself is :func:`lesmc.video.synth.render_into`; here it runs into a staging
directory, in this process or in a child one (:mod:`lesmc.video.aside`) while the
caller does something else, and the files are moved in only when all are written.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from lesmc.video.aside import render_aside
from lesmc.video.synth import SynthConfig, render_into


def write_video(
    cfg: SynthConfig,
    out_dir: Path,
    progress: Callable[[], None] | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> list[Path]:
    """Write frames and truth.json into ``out_dir``; returns the frame paths.

    Files go to a temporary directory first and are moved in at the end, so an
    interrupted run leaves nothing half-written behind. One writer thread encodes
    each frame while the next one is drawn (:func:`lesmc.video.synth.frames`): a frame of W x H
    pixels holds 4WH bytes as float32 and two are in flight, as is one encoded frame.
    ``progress()`` after each frame written.

    With ``meanwhile``, a child process renders the frames (:mod:`lesmc.video.aside`)
    while ``meanwhile()`` runs here: ``lesmc verify`` imports torch then, which on the
    same interpreter would wait for the GIL that rendering's Python holds. The files
    are the same bytes either way.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".synth.", dir=out_dir))
    try:
        if meanwhile is not None and sys.executable:
            render_aside(cfg, tmp, out_dir, progress, meanwhile)
        else:  # no interpreter to start (an embedded Python): one after the other
            if meanwhile is not None:
                meanwhile()
            render_into(cfg, tmp, out_dir, progress)
        paths = []
        for p in sorted(tmp.iterdir()):
            os.replace(p, out_dir / p.name)
            paths.append(out_dir / p.name)
        return [p for p in paths if p.name != "truth.json"]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
