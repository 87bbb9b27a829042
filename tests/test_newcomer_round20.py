"""A new user's round on the inputs merged today: a built multi-target model file
(``lesmc build SCENE --design sort --spec SPEC -o m.npz``) edited by hand is refused by
``lesmc check`` and ``lesmc export`` with a located message and exit status 2, where the
old reader accepted it and printed a wrong design, a nan optimum or an MDP of nothing."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import ROOT, lesmc

from lesmc.model.lts_binary import read_npz, write_npz

SPEC = """property p {
  attack window 4..4
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 1
}
"""


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """examples/crossing.json's sort model for SPEC's property, and the spec."""
    tmp = tmp_path_factory.mktemp("built")
    spec = tmp / "p.spec"
    spec.write_text(SPEC)
    model = tmp / "m.npz"
    r = lesmc(
        "build", str(ROOT / "examples/crossing.json"), "--design", "sort", "--spec", str(spec),
        "-o", str(model),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    return model, spec


def _header(edit: Callable[[dict[str, Any]], None]) -> Callable[[dict[str, np.ndarray]], None]:
    """An edit of the file's JSON header."""

    def apply(arrays: dict[str, np.ndarray]) -> None:
        head = json.loads(arrays["header"].tobytes())
        edit(head)
        arrays["header"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8).copy()

    return apply


def _set(arrays: dict[str, np.ndarray], name: str, index: Any, value: float) -> None:
    a = arrays[name].copy()
    a[index] = value
    arrays[name] = a


EDITS: dict[str, tuple[Callable[[dict[str, np.ndarray]], None], str]] = {
    # a design that is not a multi-target design was printed as the check's design
    "design single": (
        _header(lambda h: h["meta"].__setitem__("design", "single")),
        "header.meta.design: must be sort or gnn, got 'single'",
    ),
    "design unknown": (
        _header(lambda h: h["meta"].__setitem__("design", "sortt")),
        "header.meta.design: must be sort or gnn, got 'sortt'",
    ),
    "tracker disagrees with design": (
        _header(lambda h: h["meta"].__setitem__("design", "gnn")),
        "header.meta.tracker: design 'sort' must be meta.design 'gnn'",
    ),
    "tracker key unknown": (
        _header(lambda h: h["meta"]["tracker"].__setitem__("bogus", 1)),
        "header.meta.tracker: unknown key 'bogus'",
    ),
    "tracker value bad": (
        _header(lambda h: h["meta"]["tracker"].__setitem__("max_age", -1)),
        "header.meta.tracker: max_age",
    ),
    "frames repeat": (
        _header(lambda h: h.__setitem__("frames", [0] * len(h["frames"]))),
        "header.frames: must increase from step to step",
    ),
    "names repeat": (
        _header(lambda h: h["names"].__setitem__(4, ["4:0", "4:0", "4:2"])),
        "header.names[4]: must name each detection once, got '4:0' twice",
    ),
    "unpriced names nothing": (
        _header(lambda h: h["meta"].__setitem__("unpriced", [4, "zz"])),
        "header.meta.unpriced: 'zz' is no detection of step 4",
    ),
    # nan payoffs without meta.unpriced: the check printed 'optimum nan', export an MDP
    "nan payoff, nothing unpriced": (
        lambda a: a.__setitem__("payoff", np.full_like(a["payoff"], np.nan)),
        "array 'payoff'[0]: is nan (an unpriced detection hidden), but header.meta.unpriced",
    ),
    "box inf": (
        lambda a: _set(a, "box", (3, 1), np.inf),
        "array 'box'[3, 1]: must be finite (nan: no box), got inf",
    ),
    "refbox -inf": (
        lambda a: _set(a, "refbox", (2, 0), -np.inf),
        "array 'refbox'[2, 0]: must be finite (nan: no box), got -inf",
    ),
}


@pytest.mark.parametrize("case", sorted(EDITS))
def test_an_edited_model_file_is_a_located_error(
    built: tuple[Path, Path], tmp_path: Path, case: str
) -> None:
    model, spec = built
    edit, message = EDITS[case]
    arrays = read_npz(str(model))
    edit(arrays)
    bad = tmp_path / "bad.npz"
    with bad.open("wb") as fh:
        write_npz(fh, arrays)
    out = tmp_path / "out.drn"
    for args in (
        ("check", str(bad), str(spec), "--json"),
        ("export", str(bad), "--format", "drn", "--spec", str(spec), "-o", str(out)),
    ):
        r = lesmc(*args)
        assert "Traceback" not in r.stderr, r.stderr
        assert r.returncode == 2, (args[0], r.returncode, r.stdout[:300], r.stderr)
        assert f"{bad}: {message}" in r.stderr, r.stderr
        if "--json" in args:  # the error as a lesmc-error document, nothing else
            assert json.loads(r.stdout)["format"] == "lesmc-error"
        else:
            assert r.stdout == ""
    assert not out.exists()


def test_the_unedited_model_still_checks(built: tuple[Path, Path]) -> None:
    """The file as built loads (the new rules refuse nothing lesmc writes)."""
    model, spec = built
    r = lesmc("check", str(model), str(spec), "--json")
    assert r.returncode == 1, r.stderr
    doc = json.loads(r.stdout)
    assert doc["design"] == "sort"
    assert [p["optimum"] for p in doc["results"]] == [1.0]


def test_the_table_says_dash_where_the_target_has_no_track(built: tuple[Path, Path]) -> None:
    """The counterexample's last step has no target's track (the JSON's null): the table
    printed Python's ``None`` there; it says ``-``, as for no hidden detection."""
    model, spec = built
    doc = json.loads(lesmc("check", str(model), str(spec), "--json").stdout)
    steps = doc["results"][0]["counterexample"]
    r = lesmc("check", str(model), str(spec))
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = [ln.strip() for ln in r.stdout.splitlines() if ln.strip().startswith("step ")]
    assert len(lines) == len(steps)
    assert any(s["target_id"] is None for s in steps)
    for line, s in zip(lines, steps, strict=True):
        want = "-" if s["target_id"] is None else str(s["target_id"])
        assert line.endswith(f"; target {want}"), line
    assert "None" not in r.stdout


def test_design_on_a_built_model_names_the_npz_form(built: tuple[Path, Path]) -> None:
    model, spec = built
    r = lesmc("check", str(model), str(spec), "--design", "sort")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--design applies to scenes, not to built models (.lts, .npz)" in r.stderr


def test_alarms_of_a_multi_target_design_says_alarms(tmp_path: Path) -> None:
    """``lesmc alarms --design sort`` (offered by its --help) is refused; the message
    named verify, campaign and replay as the single-target step, not alarms."""
    mot = ROOT / "examples/mot"
    scene = tmp_path / "s.json"
    r = lesmc(
        "import", "mot", str(mot / "det.txt"), "--gt", str(mot / "gt.txt"), "--track", "10",
        "-o", str(scene),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = lesmc("alarms", str(scene), "--design", "sort")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "design 'sort' is a multi-target tracker" in r.stderr
    assert "alarms" in r.stderr.split("single-target step")[1]
