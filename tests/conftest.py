"""Shared fixtures and paths for the test suite."""

from __future__ import annotations

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
