"""The small video the multi-target replay, campaign and review tests share (seed 5, 12
frames of 448 x 448), and the identity properties checked on it."""

from __future__ import annotations

from pathlib import Path

from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

#: A hijack and a loss of the target's identity, each at a payoff under 3 on this video.
SPEC = """property hijack {
    attack window 2..4 within 30
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 3.0
}
property lose {
    attack window 2..4 within 30
    minimize payoff
    subject to lost(0..end) > 1
    holds if optimum > 3.0
}
"""


def write_small_video(path: Path) -> None:
    """Write the shared 12-frame 448 x 448 video (seed 5, density 3) to ``path``."""
    write_video(SynthConfig(frames=12, width=448, height=448, seed=5, density=3.0), path)
