"""`import lesmc` is the Python API (docs/api.md): light to import, the same answers as
the hand-derived table of tests/golden/README.md ("tiny")."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

import lesmc

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"

#: tests/golden/README.md, derived by hand: property -> (verdict, optimum)
BY_HAND = {
    "robustness": ("violated", 2.0),
    "robustness_monitored": ("holds", 3.5),
    "robustness_mean": ("holds", 1.0),
    "resilience": ("violated", 5.0),
    "nothing_breaks": ("holds", math.inf),
}


def test_importing_lesmc_loads_no_pipeline() -> None:
    code = "import sys, lesmc; print(sorted(m for m in sys.modules if m.startswith('lesmc')))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    assert out.strip() == "['lesmc']"


def test_the_api_answers_as_derived_by_hand() -> None:
    results = lesmc.check(
        lesmc.load_model(TINY / "model.lts"), lesmc.load_spec(TINY / "properties.spec")
    )
    got = {r.property: (r.verdict, r.optimum) for r in results}
    assert got == BY_HAND
    assert {r.property: r.status for r in results}["robustness"] == "violated"


def test_dir_lesmc_is_exactly_all() -> None:
    """No subpackage, no import of lesmc/__init__.py (sys, types, Any), no name twice, even
    after every subpackage has been imported; no subpackage is named like an API function
    (issue 57: lesmc/unfold, lesmc/experiment, lesmc/exporters), so importing one never
    rebinds an API name."""
    import pkgutil

    import lesmc.experiment.experiment
    import lesmc.exporters.drn
    import lesmc.unfold.unfold

    assert dir(lesmc) == sorted(set(lesmc.__all__)) == sorted(lesmc.__all__)
    assert {"sys", "types", "Any"}.isdisjoint(dir(lesmc))
    assert callable(lesmc.build) and callable(lesmc.export) and callable(lesmc.verify)
    packages = {m.name for m in pkgutil.iter_modules(lesmc.__path__)}
    assert not packages & set(lesmc.__all__), packages & set(lesmc.__all__)


def test_the_api_page_is_a_notebook_session() -> None:
    """docs/api.md is written as a notebook user writes: paths, to_dict(), lesmc.export,
    designs on results (the doctest below runs it)."""
    text = (ROOT / "docs" / "api.md").read_text()
    for used in (
        'lesmc.check("examples/merge.json", "examples/merge.spec"',
        "r.design",
        ".to_dict()",
        "lesmc.export(",
        'lesmc.build("examples/merge.json", "6..8")',
        "r.sweep",
    ):
        assert used in text, used
    assert ".to_json()" not in text.replace("`to_json()` is a deprecated", "")


def test_to_json_is_a_deprecated_alias_of_to_dict() -> None:
    (r, *_) = lesmc.check(TINY / "model.lts", TINY / "properties.spec")
    with pytest.warns(DeprecationWarning, match="to_dict"):
        old = r.to_json()
    assert old == r.to_dict()


def test_windows_as_text_tuple_or_range_build_the_same_model() -> None:
    scene = ROOT / "examples" / "merge.json"
    sizes = {lesmc.build(scene, w).n_states for w in ("6..8", (6, 8), range(6, 9), [6, 8])}
    assert sizes == {597}  # issue 57: 597 states for merge.json in 6..8


def test_the_api_page_runs_as_written(monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/api.md's session, as a doctest from the repository's root."""
    import doctest

    monkeypatch.chdir(ROOT)
    out = doctest.testfile(
        str(ROOT / "docs" / "api.md"),
        module_relative=False,
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
    )
    assert out.attempted >= 10 and out.failed == 0


@pytest.mark.parametrize("load", ["load_model", "load_scene", "load_spec", "load_model_or_scene"])
def test_a_bad_file_raises_a_located_input_error(load: str, tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "lesmc-scene",\n  "version": }')
    with pytest.raises(lesmc.InputError) as info:
        getattr(lesmc, load)(bad)
    assert info.value.location is not None and info.value.location.path == str(bad)
    assert info.value.location.line in (1, 2)


def test_the_lazy_names_are_the_apis() -> None:
    """lesmc/__init__.py lists the API's names without importing it (start-up stays light);
    the list must be lesmc.api's own."""
    import lesmc.api

    assert sorted(lesmc._API) == sorted(lesmc.api.__all__)


def test_perceive_raises_located_errors_for_bad_inputs(tmp_path: Path) -> None:
    """lesmc.perceive: a missing frames directory and a broken truth file are InputErrors
    naming the file, never SystemExit; a scene without the CNN is a UsageError."""
    with pytest.raises(lesmc.InputError) as info:
        lesmc.perceive(tmp_path / "no-such-frames")
    assert info.value.location is not None and "no-such-frames" in info.value.location.path
    frames = tmp_path / "frames"
    frames.mkdir()
    import cv2
    import numpy as np

    for i in range(6):
        cv2.imwrite(str(frames / f"f{i}.png"), np.full((64, 64), 100 + i, dtype=np.uint8))
    truth = tmp_path / "truth.json"
    truth.write_text('{"format": "lesmc-truth",\n "version": }')
    with pytest.raises(lesmc.InputError) as info:
        lesmc.perceive(lesmc.PerceiveRequest(str(frames), truth=str(truth)))
    assert info.value.location is not None and info.value.location.path == str(truth)
    with pytest.raises(lesmc.UsageError):
        lesmc.perceive(lesmc.PerceiveRequest(str(frames), cnn=False))
    # a frames directory itself is the documented short form (it was refused as "a file to
    # write"): the blank frames are read, and their registration is what fails, located
    with pytest.raises(lesmc.InputError) as info:
        lesmc.perceive(frames)
    assert info.value.location is not None and info.value.location.path.endswith("f1.png")


def test_perceive_refuses_settings_the_command_line_would(tmp_path: Path) -> None:
    """The API checks the ranges and choices click checks for `lesmc perceive`."""
    for bad in ({"attack": "fgsm"}, {"history": 2}, {"dt": 0.0}, {"overshoot": 2.0}):
        with pytest.raises(lesmc.UsageError):
            lesmc.perceive(lesmc.PerceiveRequest(str(tmp_path), **bad))


def test_export_json_writes_json_whatever_the_name(tmp_path: Path) -> None:
    model = lesmc.load_model(ROOT / "tests" / "golden" / "tiny" / "model.lts")
    lesmc.export(model, tmp_path / "m.npz", format="json")
    assert json.loads((tmp_path / "m.npz").read_text())["format"] == "lesmc-lts"
