"""The small WAMI video the replay and injection tests share (768 x 768, 16 frames, seed 4,
density 2.5), made by ``lesmc synth``, and its scene perceived around one target with
injection candidates (``--inject-within 30``), through the real entry point."""

from __future__ import annotations

from pathlib import Path

from cli_run import lesmc

#: The target the tests perceive and verify, as ``--target`` takes it.
TARGET = "206.434,202.672@4"


def synth_wami_video(video: Path, frames: int = 16) -> None:
    """Write the shared video (and its truth.json) to ``video``: its first ``frames``."""
    r = lesmc(
        "synth", str(video), "--frames", str(frames), "--size", "768x768", "--seed", "4",
        "--density", "2.5",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr


def perceive_with_candidates(video: Path, scene: Path, target: str = TARGET) -> None:
    """``lesmc perceive`` the shared video into ``scene``: ``target``, the truth, the
    injection candidates within 30 px."""
    r = lesmc(
        "perceive", str(video), "-o", str(scene), "--target", target,
        "--truth", str(video / "truth.json"), "--inject-within", "30",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
