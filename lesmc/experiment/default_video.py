"""``lesmc verify``'s embedded default video (``lesmc synth`` with :data:`DEFAULT_VIDEO`):
rendered into OUT/video, or reused when it is there already; and the video a run reads,
FRAMES_DIR or the default.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from lesmc.common.errors import UsageError
from lesmc.common.memory import release
from lesmc.common.progress import Reporter
from lesmc.experiment.verify_request import Request, spent

#: The embedded default video: `lesmc synth` with these settings.
DEFAULT_VIDEO = {"frames": 24, "width": 2048, "height": 2048, "seed": 1}


def video_and_truth(
    req: Request, rep: Reporter
) -> tuple[str, str | None, dict[str, Any], list[Path] | None]:
    """The video's frames and truth: FRAMES_DIR, or the embedded default in OUT/video; and
    the frames this run rendered (None: it rendered none)."""
    if req.frames_dir is not None:
        return req.frames_dir, req.truth, {"video": req.frames_dir}, None
    if req.truth is not None:
        raise UsageError("--truth is FRAMES_DIR's truth: the default video brings its own")
    video = req.out / "video"
    fresh = None
    if default_video_ready(video):
        rep.log(f"reusing the default video in {video}")
    else:
        with rep.bar("rendering", DEFAULT_VIDEO["frames"]) as bar:

            def rendered() -> None:
                bar.advance()
                spent(req.budget, "rendering the default video")

            fresh = write_default_video(video, rendered, meanwhile=import_perception)
        release()  # what rendering or the imports freed goes back before perception
    what = (
        f"embedded default: lesmc synth {video} --seed {DEFAULT_VIDEO['seed']} "
        f"--frames {DEFAULT_VIDEO['frames']}"
    )
    return str(video), str(video / "truth.json"), {"video": what}, fresh


def default_video_ready(video: Path) -> bool:
    """Whether ``video`` already holds exactly the embedded default video."""
    from lesmc.video.synth import SynthConfig

    truth = video / "truth.json"
    if not truth.is_file():
        return False
    try:
        same = json.loads(truth.read_text()).get("config") == asdict(SynthConfig(**DEFAULT_VIDEO))
    except ValueError:
        return False
    return same and len(list(video.glob("frame_*.png"))) == DEFAULT_VIDEO["frames"]


def write_default_video(
    video: Path,
    progress: Callable[[], None] | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> list[Path]:
    """Generate the embedded default video (``lesmc synth`` with ``DEFAULT_VIDEO``); the
    frames written. With ``meanwhile``, a child process renders while it runs here
    (:func:`lesmc.video.write.write_video`)."""
    from lesmc.video.synth import SynthConfig
    from lesmc.video.write import write_video

    return write_video(SynthConfig(**DEFAULT_VIDEO), video, progress, meanwhile)


def import_perception() -> None:
    """Import perception's code (torch and the networks', scipy.spatial, faiss) and the
    targets' while the default video renders aside: a video just rendered is perceived
    next (2-2.5 s of imports off the critical path)."""
    import lesmc.experiment.targets
    import lesmc.perception.run  # noqa: F401
