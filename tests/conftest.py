"""Shared fixtures and paths for the test suite."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture(autouse=True)
def search_small_trees(monkeypatch: pytest.MonkeyPatch) -> None:
    """In-process tests exercise bnb's and levels' own search on every model: their
    enumeration of small trees (engines/enumerate.py, SMALL_TREE) would otherwise answer
    most of the small random models. tests/test_engines.py tests that probe itself;
    the CLI tests (subprocesses) run with the default."""
    from lesmc.engines import enumerate as enumerate_engine

    monkeypatch.setattr(enumerate_engine, "SMALL_TREE", 0)


@pytest.fixture(scope="session")
def default_verify(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, subprocess.CompletedProcess[str], list[float]]:
    """The main job, run once for the session: ``lesmc verify --payoffs interval --json``
    on the embedded default video. Its output directory (with the perceived scene.json),
    the finished process and the seconds at which each stderr line came."""
    from cli_run import lesmc_logged

    out = tmp_path_factory.mktemp("default-video") / "v"
    r, times = lesmc_logged("verify", "--out", str(out), "--payoffs", "interval", "--json")
    return out, r, times
