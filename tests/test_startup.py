"""Start-up stays light: each verb imports only what it uses (no timing assertions here).

Every case runs the real entry point (``lesmc.cli.main.main``) in a fresh
interpreter and records ``sys.modules`` when the interpreter exits, whatever
the exit status. benchmarks/bench_startup.py measures the wall time.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"

HEAVY = ("torch", "cv2", "matplotlib", "filterpy", "scipy.stats")
"""Modules that cost 0.3-2.5 s each to import and that light verbs must not touch."""

_RUNNER = """
import atexit, json, sys
record_to, args = sys.argv[1], sys.argv[2:]
def _record():
    with open(record_to, "w") as f:
        json.dump(sorted(sys.modules), f)
atexit.register(_record)
sys.argv = ["lesmc", *args]
from lesmc.cli.main import main
main()
"""


def modules_after(tmp_path: Path, *args: str) -> tuple[int, set[str]]:
    """Run ``lesmc ARGS`` through the console entry point; its exit status and modules."""
    out = tmp_path / "modules.json"
    r = subprocess.run(
        [sys.executable, "-c", _RUNNER, str(out), *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert out.exists(), r.stderr
    return r.returncode, set(json.loads(out.read_text()))


def heavy_in(modules: set[str]) -> list[str]:
    return sorted(h for h in HEAVY if h in modules or any(m.startswith(h + ".") for m in modules))


def test_check_imports_nothing_heavy(tmp_path: Path) -> None:
    status, modules = modules_after(
        tmp_path, "check", str(TINY / "model.lts"), str(TINY / "properties.spec")
    )
    assert status == 1  # the tiny model violates some properties: the check really ran
    assert "lesmc.engines.check" in modules
    assert heavy_in(modules) == []


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["--version"],
        *([verb, "--help"] for verb in ("check", "build", "track", "synth", "perceive")),
        *([verb, "--help"] for verb in ("train", "verify")),
        ["reduce", "knapsack", "--help"],
    ],
    ids=lambda a: " ".join(a),
)
def test_help_imports_nothing_heavy(tmp_path: Path, args: list[str]) -> None:
    status, modules = modules_after(tmp_path, *args)
    assert status == 0
    assert heavy_in(modules) == []
    # --help needs neither the engines nor numpy: only click and the option declarations
    assert "numpy" not in modules and "lesmc.engines.check" not in modules


def test_check_default_budget_matches_the_engines() -> None:
    """lesmc/cli/options.py repeats the default so that the options do not import the
    engines; check, verify and campaign all take that one."""
    from lesmc.cli import campaign, check, options, verify
    from lesmc.engines.check import DEFAULT_MAX_STATES

    assert options.DEFAULT_MAX_STATES == DEFAULT_MAX_STATES
    for cli in (check, verify, campaign):
        assert cli.DEFAULT_MAX_STATES is options.DEFAULT_MAX_STATES


def test_video_constants_match_the_generator() -> None:
    """lesmc.video holds the constants the CLI shows; lesmc.video.synth uses the same ones."""
    from lesmc import video
    from lesmc.video import synth

    assert synth.FPS == video.FPS == 1.25
    assert synth.SynthConfig.density == video.DEFAULT_DENSITY
