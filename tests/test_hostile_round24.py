"""Round 24's hostile inputs (issue 61's additions: injection candidates, multi-check
documents fed to ``lesmc report``, tracker and detector files, ``import mot``):

- a ``lesmc-multi-check`` document one of whose counterexample steps lost its
  ``attacked`` (or ``tracks``) list, while its first step has them (so the report draws
  every step), was an internal error (KeyError, exit 4) in ``lesmc report``: now refused
  at that step's ``FILE:LINE:COL``;
- ``inject grid D within R`` with R / D above about 1e154 (``10 within 1e308``,
  ``1e-200 within 1e-40``) overflowed counting the grid's points (OverflowError, exit 4):
  now "more than 1000 points" at D;
- a scene's ``meta.frontend`` out of range, misspelt or not an object was refused only
  where it was recorded (``check --report`` on a point design, ``verify --scene``):
  ``check --design sort`` (whose results the multi replay reruns), ``track`` and the rest
  read it silently. Now the scene's reader checks it, as it checks ``meta.attack``; a
  ``meta`` that is not an object (``[]``) is refused too;
- a TOML integer beyond 64 bits (``gate = 1000...0``, 401 digits, in a ``tune --space``
  file) was kept by ``tomllib`` and overflowed in ``float()`` (exit 4): the TOML reader
  (lesmc/common/files.py ``read_toml``, which every TOML input goes through) now refuses
  it at its token, as the JSON reader does, skipping comments and strings; and TOML
  arrays or inline tables nested thousands deep (a ``--tracker`` file) were a
  RecursionError (exit 4): now "nesting deeper than 64" where the 65th opens;
- a point design's results whose ``runs[].replay_inputs.tracker`` is not a tracker (a
  ``P0_sd`` of 3 entries for the 4-state model) went through ``lesmc replay`` to the
  frames and perception, the tracker read only after perceiving (with no line): now the
  results reader checks it as a scene's ``tracker`` block, at its ``FILE:LINE:COL``;
- ``lesmc campaign --targets FILE`` (no FRAMES_DIR) rendered the embedded video into
  OUT/video (half a minute) before reading the file, and a bad line then left OUT/video
  behind: the file is now read first (the videos' names are known without them); its
  message no longer says ``t.txt:3:1: error: --target ...``;
- ``monitor trace 1e999`` said "the the trace monitor's parameter must be finite", and
  ``monitor uncertainty tolerance 1e308`` printed numpy's RuntimeWarning (overflow) on
  stderr: the bound is inf (the alarm never fires), now without the warning;

Every case goes through the real entry point: exit 2, the location, no traceback."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc


def _refused_at(r: Any, path: str, line: int, *said: str) -> str:
    """Exit 2, no traceback, stderr's first line at ``path:line:COL`` saying ``said``."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    first = r.stderr.splitlines()[0]
    assert re.match(rf"{re.escape(path)}:{line}:\d+: ", first), (line, r.stderr)
    for s in said:
        assert s in first, (s, r.stderr)
    return first


def _line_of(text: str, needle: str, nth: int = 0) -> int:
    """The 1-based line of the ``nth`` occurrence of ``needle`` in ``text``."""
    pos = -1
    for _ in range(nth + 1):
        pos = text.index(needle, pos + 1)
    return text.count("\n", 0, pos) + 1


@pytest.fixture(scope="module")
def multi_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The SORT hijack's ``lesmc-multi-check`` document as ``check --report`` writes it
    (version 2: every step with its tracks and attacked detections; exit 1: violated)."""
    base = tmp_path_factory.mktemp("hostile24")
    r = lesmc(
        "check", str(ROOT / "examples" / "crossing.json"), str(ROOT / "examples" / "hijack.spec"),
        "--design", "sort", "--report", str(base / "r"),
    )  # fmt: skip
    assert r.returncode == 1, r.stderr
    doc: dict[str, Any] = json.loads((base / "r" / "results.json").read_text())
    return doc


@pytest.mark.parametrize("key", ["attacked", "tracks"])
def test_a_multi_check_step_without_its_drawn_lists_is_refused(
    tmp_path: Path, multi_doc: dict[str, Any], key: str
) -> None:
    """Step 3 of the counterexample loses ``key``: refused at that step's line (the
    report would draw it from the list), not an internal error; nothing written."""
    doc = json.loads(json.dumps(multi_doc))
    steps = doc["results"][0]["counterexample"]
    assert "tracks" in steps[0] and len(steps) > 3
    del steps[3][key]
    text = json.dumps(doc, indent=1)
    (tmp_path / "r.json").write_text(text)
    r = lesmc("report", "r.json", "--out", "out", cwd=tmp_path)
    step_line = _line_of(text, '"step": 3', 0) - 1  # the step's "{" is the line before
    _refused_at(r, "r.json", step_line, "counterexample[3]", repr(key))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("grid", ["10 within 1e308", "1e-200 within 1e-40"])
def test_an_astronomical_inject_grid_is_too_big_not_an_overflow(tmp_path: Path, grid: str) -> None:
    """A grid whose radius / spacing overflows a float square: refused at D as too big."""
    (tmp_path / "g.spec").write_text(
        "property g {\n"
        "  attack window 6..8 allow hide, inject\n"
        f"  inject grid {grid} payoff 1\n"
        "  minimize payoff\n"
        "  subject to dist.sum(0..end) > 120\n"
        "  holds if optimum > 3\n"
        "}\n"
    )
    r = lesmc("check", str(ROOT / "examples" / "merge.json"), "g.spec", cwd=tmp_path)
    first = _refused_at(r, "g.spec", 3, "more than 1000 points")
    assert first.startswith("g.spec:3:15: "), first


@pytest.mark.parametrize(
    ("meta", "field", "said"),
    [
        ({"frontend": {"history": 2}}, '"history"', "meta.frontend.history"),
        ({"frontend": {"Delta_bc": 12}}, '"Delta_bc"', "unknown setting"),
        ([], '"meta"', "meta: must be an object"),
    ],
)
def test_a_bad_meta_frontend_is_refused_when_the_scene_is_read(
    tmp_path: Path, meta: Any, field: str, said: str
) -> None:
    """``lesmc track`` (and every verb reading the scene) refuses it at its line."""
    doc = json.loads((ROOT / "examples" / "crossing.json").read_text())
    doc["meta"] = meta
    text = json.dumps(doc, indent=1)
    (tmp_path / "s.json").write_text(text)
    r = lesmc("track", "s.json", cwd=tmp_path)
    _refused_at(r, "s.json", _line_of(text, field), said)


def _scene_with_truth(tmp_path: Path) -> str:
    """examples/merge.json with a truth track (each frame's first detection), which
    ``lesmc tune`` needs before it reads the space: the file's name in ``tmp_path``."""
    doc = json.loads((ROOT / "examples" / "merge.json").read_text())
    first = [[f["step"], f["detections"][0]["x"], f["detections"][0]["y"]] for f in doc["frames"]]
    doc["truth"] = [{"id": "v1", "positions": first}]
    (tmp_path / "s.json").write_text(json.dumps(doc))
    return "s.json"


BIG = "1" + "0" * 400


@pytest.mark.parametrize(
    ("space", "line", "col"),
    [
        (f"gate = [2.0, {BIG}]\n", 1, 14),
        (f"# {BIG} in a comment\nsigma_q = 3.0\n[monitor]\nnis = 0x{BIG}\n", 4, 7),
    ],
    ids=["in-a-list", "hex-after-a-comment"],
)
def test_a_toml_integer_beyond_64_bits_is_refused_at_its_token(
    tmp_path: Path, space: str, line: int, col: int
) -> None:
    """Not an OverflowError (exit 4): ``FILE:LINE:COL`` of the integer, not of the comment."""
    scene = _scene_with_truth(tmp_path)
    (tmp_path / "space.toml").write_text(space)
    spec = str(ROOT / "examples" / "merge.spec")
    r = lesmc("tune", scene, spec, "--space", "space.toml", cwd=tmp_path)
    first = _refused_at(r, "space.toml", line, "out of range", "64 bits")
    assert first.startswith(f"space.toml:{line}:{col}: "), first


def test_a_replay_tracker_that_is_no_tracker_is_refused_before_the_frames(tmp_path: Path) -> None:
    """``lesmc replay`` refuses it at the results file's ``tracker`` line, before it
    looks at the (empty) frames directory."""
    (tmp_path / "p.spec").write_text(
        "property p {\n  attack window 6..7\n  minimize payoff\n"
        "  subject to dist.at(end) > 1\n  holds if optimum > 1\n}\n"
    )
    r = lesmc(
        "check", str(ROOT / "examples" / "merge.json"), "p.spec", "--report", "r", cwd=tmp_path
    )
    assert r.returncode in (0, 1), r.stderr
    doc = json.loads((tmp_path / "r" / "results.json").read_text())
    doc["runs"][0]["replay_inputs"]["tracker"]["P0_sd"] = [30.0, 30.0, 20.0]
    text = json.dumps(doc, indent=1)
    (tmp_path / "bad.json").write_text(text)
    (tmp_path / "frames").mkdir()
    r = lesmc("replay", "bad.json", "--frames", "frames", cwd=tmp_path)
    line = text.count("\n", 0, text.index('"tracker"', text.index('"replay_inputs"'))) + 1
    _refused_at(r, "bad.json", line, "replay_inputs.tracker", "P0_sd must have 4 entries")


def test_a_bad_campaign_targets_file_is_refused_before_rendering(tmp_path: Path) -> None:
    """Exit 2 at the file's line, nothing rendered, no OUT left behind."""
    (tmp_path / "t.txt").write_text("# targets\n812.5,96@4\nnan,2@3\n")
    r = lesmc(
        "campaign", "--out", "o", "--targets", "t.txt", "--windows", "4..4:1..1",
        "--design", "single", cwd=tmp_path,
    )  # fmt: skip
    first = _refused_at(r, "t.txt", 3, "nan,2@3")
    assert first.startswith("t.txt:3:1: --target must look like"), first  # no "error: " inside
    assert "rendering" not in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("opens", "closes"), [("[", "]"), ("{b = ", "}")])
def test_a_toml_file_nested_thousands_deep_is_refused(
    tmp_path: Path, opens: str, closes: str
) -> None:
    """``--tracker deep.toml``: exit 2 at the 65th bracket, not a RecursionError."""
    head = "gate = " if opens == "[" else "a = "
    (tmp_path / "deep.toml").write_text(head + opens * 5000 + "1" + closes * 5000 + "\n")
    scene = str(ROOT / "examples" / "crossing.json")
    r = lesmc("track", scene, "--tracker", "deep.toml", cwd=tmp_path)
    first = _refused_at(r, "deep.toml", 1, "nesting deeper than 64")
    col = len(head) + 64 * len(opens) + 1
    assert first.startswith(f"deep.toml:1:{col}: "), first


def _monitored_spec(monitor: str) -> str:
    return (
        "property m {\n  attack window 6..7\n  minimize payoff\n"
        f"  subject to dist.at(end) > 1\n  holds if optimum > 1\n  monitor {monitor}\n}}\n"
    )


def test_an_infinite_monitor_parameter_is_named_once(tmp_path: Path) -> None:
    (tmp_path / "m.spec").write_text(_monitored_spec("trace 1e999"))
    r = lesmc("check", str(ROOT / "examples" / "merge.json"), "m.spec", cwd=tmp_path)
    first = _refused_at(r, "m.spec", 6, "the trace monitor's parameter must be finite")
    assert "the the" not in first, first


def test_a_huge_tolerance_checks_without_a_numpy_warning(tmp_path: Path) -> None:
    """The alarm never fires: the result is the unmonitored one, stderr without warnings."""
    (tmp_path / "m.spec").write_text(_monitored_spec("uncertainty tolerance 1e308"))
    r = lesmc("check", str(ROOT / "examples" / "merge.json"), "m.spec", cwd=tmp_path)
    assert r.returncode in (0, 1), r.stderr
    assert "Warning" not in r.stderr and "Traceback" not in r.stderr, r.stderr
