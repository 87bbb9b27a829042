"""``lesmc verify`` reuses what it computed when its inputs are unchanged (issue 31):
perception, the monitor's false alarms, the replay and the report's figures come from
OUT/cache, the results and figures are the same, and any change of the inputs (a
frame's bytes) or a broken entry makes it compute again."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc

from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video


def _content(doc: dict[str, Any]) -> dict[str, Any]:
    """The results without what differs from run to run (timings, dates, search seconds)."""
    doc = {k: v for k, v in doc.items() if k not in ("timings", "provenance")}
    doc.pop("replay", None)
    for run in doc["runs"]:
        for r in run["results"]:
            r.pop("stats", None)
    return doc


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache") / "tiny"
    write_video(SynthConfig(frames=12, width=448, height=448, seed=4, density=3.0), out)
    return out


def _verify(video: Path, out: Path) -> tuple[str, dict[str, Any]]:
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--design", "single", "--window", "3..4")  # fmt: skip
    assert r.returncode in (0, 1, 3), r.stderr
    assert "Traceback" not in r.stderr
    return r.stderr, json.loads((out / "results.json").read_text())


def test_a_rerun_reads_the_cache_and_gives_the_same_results(video: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    log1, doc1 = _verify(video, out)
    assert "reusing the perception" not in log1
    entries = sorted(p.name.split("-")[0] for p in (out / "cache").iterdir())
    assert "perception" in entries and "false" in entries and "figure" in entries
    figures = {p.name: p.read_bytes() for p in (out / "figures").iterdir()}
    log2, doc2 = _verify(video, out)
    assert f"reused {len(figures)} of {len(figures)} distinct figures" in log2
    assert {p.name: p.read_bytes() for p in (out / "figures").iterdir()} == figures
    assert "reusing the perception" in log2
    assert "perceiving" not in log2
    if doc1.get("replay", {}).get("replayed"):
        assert "reusing the replay" in log2
    assert _content(doc2) == _content(doc1)


def test_a_changed_frame_or_a_broken_entry_is_computed_again(video: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    _, doc1 = _verify(video, out)
    for entry in (out / "cache").iterdir():
        entry.write_text('{"format": "lesmc-cache", "version": 1, "stage": "x"')  # cut short
    log, doc = _verify(video, out)
    assert "reusing" not in log.replace("reusing the default video", "")
    assert "reused" not in log
    assert _content(doc) == _content(doc1)
    changed = tmp_path / "changed"
    shutil.copytree(video, changed)
    log, _ = _verify(changed, out)  # its own source path: computed, then cached
    log, _ = _verify(changed, out)
    assert "reusing the perception" in log
    first = sorted(changed.glob("frame_*.png"))[0]
    first.write_bytes(first.read_bytes() + b"\0")  # the same image, other bytes
    log, _ = _verify(changed, out)
    assert "reusing the perception" not in log
