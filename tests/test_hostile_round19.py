"""The hostile-input run on round 19's inputs: ``lesmc tune`` space files and its
outputs, the gnn design's tracker keys, scene format 3's candidates, the attack window of
a spec, ``lesmc import mot --inject-column``, and box detector files. Each case was
mishandled before its fix (an exception other than a LesmcError, exit 4 on bad input, a
hang, an input file overwritten); the CLI cases run the real entry point."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_tune import _scene

ROBUSTNESS = str(ROOT / "specs" / "robustness.spec")


def _refused(r: Any, *wanted: str) -> None:
    """Exit 2, no traceback, nothing on stdout, every ``wanted`` text on stderr."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    for w in wanted:
        assert w in r.stderr, r.stderr


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        # np.linspace was asked for 10**12 values: MemoryError, exit 4
        ("gate = {from = 1.0, to = 2.0, count = 1000000000000}\n", 1, "gate: count"),
        # a whole-number range of 10**8 values: minutes of work before any check
        ("[monitor]\nmisses = {from = 1, to = 100000000}\n", 2, "misses: the range has"),
        # each list is small, their product is not: 25 million designs to check
        (
            "gate = {from = 1.0, to = 2.0, count = 50}\n"
            "sigma_q = {from = 1.0, to = 2.0, count = 5000}\n",
            2,
            "sigma_q: the space makes 250000 designs",
        ),
    ],
)
def test_a_space_too_big_to_search_is_refused_at_its_key(
    tmp_path: Path, text: str, line: int, message: str
) -> None:
    scene = _scene(tmp_path / "s.json", 0)
    space = tmp_path / "space.toml"
    space.write_text(text)
    r = lesmc("tune", str(scene), ROBUSTNESS, "--space", str(space), timeout=120)
    _refused(r, message)
    assert re.search(rf"{re.escape(str(space))}:{line}:\d+: ", r.stderr), r.stderr
    assert r.stdout == ""


@pytest.mark.parametrize("which", ["SOURCE", "SPECS", "--space"])
def test_best_out_naming_an_input_is_refused_before_any_work(tmp_path: Path, which: str) -> None:
    """``--best-out SOURCE`` used to check the space and then overwrite the scene with a
    tracker file (exit 0, the scene lost)."""
    scene = _scene(tmp_path / "s.json", 0)
    spec = tmp_path / "r.spec"
    spec.write_text(Path(ROBUSTNESS).read_text())
    space = tmp_path / "space.toml"
    space.write_text("gate = [2.0]\n")
    target = {"SOURCE": scene, "SPECS": spec, "--space": space}[which]
    before = {p: p.read_bytes() for p in (scene, spec, space)}
    r = lesmc("tune", str(scene), str(spec), "--space", str(space), "--best-out", str(target))
    _refused(r, "--best-out name the same file", which)
    assert {p: p.read_bytes() for p in before} == before
    assert "checking" not in r.stderr, r.stderr


def test_best_out_and_plot_naming_one_file_is_refused(tmp_path: Path) -> None:
    scene = _scene(tmp_path / "s.json", 0)
    space = tmp_path / "space.toml"
    space.write_text("gate = [2.0]\n")
    out = tmp_path / "best.toml"
    r = lesmc(
        "tune", str(scene), ROBUSTNESS, "--space", str(space), "--best-out", str(out),
        "--plot", str(out),
    )  # fmt: skip
    _refused(r, "--best-out and --plot name the same file")
    assert not out.exists()


def test_a_plot_named_for_no_figure_format_is_refused(tmp_path: Path) -> None:
    """--plot out.txt wrote a PNG named .txt (the review found it): refused before work."""
    scene = _scene(tmp_path / "s.json", 0)
    space = tmp_path / "space.toml"
    space.write_text("gate = [2.0]\n")
    out = tmp_path / "out.txt"
    r = lesmc("tune", str(scene), ROBUSTNESS, "--space", str(space), "--plot", str(out))
    _refused(r, ".png, .svg or .pdf")
    assert not out.exists()


_TOKENS = [
    "nan", "inf", "-1", "0", "1e400", "[]", "{}", "{from = 1, to = 2, count = 3}", "true",
    '"x"', "1e-320", '["single", "single"]', "\u202e", "=", "[", "]", "\n[monitor]\n", '""',
    "9999999999999999999999", "{from = 1, to = 2, count = 100000000}",
]  # fmt: skip


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.integers(0, 10**6), st.sampled_from(["insert", "cut", "end"]),
                  st.sampled_from(_TOKENS), st.integers(1, 12)),
        min_size=1, max_size=3,
    )
)  # fmt: skip
def test_mutated_space_files_are_read_or_refused_at_a_line(
    tmp_path_factory: pytest.TempPathFactory, edits: list[tuple[int, str, str, int]]
) -> None:
    """The example space file, mutated: read, or an InputError at FILE:LINE:COL; never
    another exception, never a space of more designs than the limit."""
    from lesmc.common.errors import InputError
    from lesmc.experiment.tune_space import MAX_DESIGNS, read_space
    from lesmc.scene.scene import TrackerConfig

    text = (ROOT / "examples" / "tune-space.toml").read_text()
    for at, op, token, n in edits:
        pos = at % (len(text) + 1)
        if op == "insert":
            text = text[:pos] + token + text[pos:]
        elif op == "cut":
            text = text[:pos] + text[pos + n :]
        else:
            text = text[:pos]
    path = tmp_path_factory.mktemp("space") / "space.toml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        space = read_space(str(path), TrackerConfig())
    except InputError as e:
        assert e.location is not None and e.location.line is not None, str(e)
        assert e.location.path == str(path)
    else:
        assert 1 <= space.size <= MAX_DESIGNS


def _gnn_scene(path: Path) -> Path:
    """A format-3 scene of two boxed objects and one injection candidate a frame, gnn."""
    import json

    frames = []
    for k in range(4):
        dets = [
            {"id": f"{k}:{i}", "x": 100.0 + 60 * i + 3 * k, "y": 50.0 + 2 * k, "payoff": 1.0}
            | {"w": 20.0, "h": 30.0}
            for i in range(2)
        ]
        cand = {"id": f"c{k}", "x": 300.0, "y": 60.0, "payoff": 0.5, "w": 20.0, "h": 30.0}
        frames.append({"step": k, "detections": dets, "candidates": [cand]})
    doc = {
        "format": "lesmc-scene", "version": 3, "dt": 0.1, "frames": frames,
        "tracker": {"design": "gnn"},
        "target": {"step": 0, "start": [100.0, 50.0], "velocity": [0.0, 0.0]},
    }  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("name", "text", "located"),
    [
        # the gnn keys; before, "t.toml: confirm_window must be ..." with no line
        ("t.toml", 'design = "gnn"\nconfirm_window = 0\n', [(2, "confirm_window must be")]),
        ("t.toml", 'design = "gnn"\n\ngate_probability = nan\n', [(3, "gate_probability")]),
        ("t.toml", 'design = "gnn"\nmin_hits = 7\n', [(2, "min_hits 7 must be at most")]),
        ("t.toml", 'confirm_window = 2\ndesign = "gnn"\n', [(1, "min_hits 3 must be at most")]),
        (
            "t.toml",
            'comment = 3\ndesign = "gnn"\nmax_age = -1\n"\u00e9" = 1\n',
            [(1, "comment: must be a string"), (3, "max_age must be"), (4, "unknown key")],
        ),
        ("t.toml", 'design = "single"\nsigma_r = 1e-300\n', [(2, "sigma_r = 1e-300 makes R")]),
        ("t.json", '{"design": "gnn",\n "gate_probability": 2}', [(2, "gate_probability")]),
    ],
)
def test_tracker_file_problems_are_at_their_keys_lines(
    tmp_path: Path, name: str, text: str, located: list[tuple[int, str]]
) -> None:
    scene = _gnn_scene(tmp_path / "s.json")
    tracker = tmp_path / name
    tracker.write_text(text, encoding="utf-8")
    r = lesmc("track", str(scene), "--tracker", str(tracker))
    _refused(r)
    assert r.stdout == ""
    for line, message in located:
        assert re.search(
            rf"{re.escape(str(tracker))}:{line}:\d+: {re.escape(message)}", r.stderr
        ), r.stderr


@pytest.mark.parametrize("budget", ["nan", "-nan"])
def test_a_nan_budget_is_refused(tmp_path: Path, budget: str) -> None:
    """click's FloatRange(0, 1) let nan through its comparisons: tune ran, exit 0, and
    --best-out then found no design "within nan"."""
    scene = _scene(tmp_path / "s.json", 0)
    space = tmp_path / "space.toml"
    space.write_text("gate = [2.0]\n")
    r = lesmc("tune", str(scene), ROBUSTNESS, "--space", str(space), "--budget", budget)
    _refused(r, "--budget", "not a finite number")
    assert "checking" not in r.stderr and r.stdout == ""


def test_a_quoted_key_with_escapes_is_located(tmp_path: Path) -> None:
    """A TOML key written with escapes (``"\\u001b[31m"``) was looked up by its raw text:
    the error named the file but no line."""
    scene = _scene(tmp_path / "s.json", 0)
    space = tmp_path / "space.toml"
    space.write_text('[monitor]\nnis = [0.5]\n"\\u001b[31m" = 1\n')
    r = lesmc("tune", str(scene), ROBUSTNESS, "--space", str(space))
    _refused(r, "unknown monitor")
    assert f"{space}:3:1: \\x1b[31m: unknown monitor" in r.stderr, r.stderr
    assert "\x1b" not in r.stderr


_GNN_TRACKER = (
    'design = "gnn"\nmin_hits = 2\nconfirm_window = 4\nmax_age = 1\n'
    'gate_probability = 0.95\nsigma_q = 3.0\nsigma_r = 5.0\ncomment = "a gnn"\n'
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.integers(0, 10**6), st.sampled_from(["insert", "cut", "end"]),
                  st.sampled_from(_TOKENS), st.integers(1, 12)),
        min_size=1, max_size=3,
    )
)  # fmt: skip
def test_mutated_gnn_tracker_files_are_read_or_refused(
    tmp_path_factory: pytest.TempPathFactory, edits: list[tuple[int, str, str, int]]
) -> None:
    """A gnn tracker file, mutated: read (M ≤ N, the probability in (0, 1)), or an
    InputError of that file, each problem about a key in the file at its line."""
    from lesmc.common.errors import InputError
    from lesmc.scene.tracker_file import load_tracker

    text = _GNN_TRACKER
    for at, op, token, n in edits:
        pos = at % (len(text) + 1)
        if op == "insert":
            text = text[:pos] + token + text[pos:]
        elif op == "cut":
            text = text[:pos] + text[pos + n :]
        else:
            text = text[:pos]
    path = tmp_path_factory.mktemp("tracker") / "t.toml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        cfg = load_tracker(path)
    except InputError as e:
        assert e.location is not None and e.location.path == str(path), str(e)
        for line in str(e).splitlines():
            if line.startswith(" "):
                continue  # a quoted source line under a caret
            assert line.startswith(str(path)), str(e)
    else:
        if cfg.design == "gnn":
            assert 1 <= cfg.min_hits <= cfg.confirm_window
        assert 0 < cfg.gate_probability < 1


@pytest.mark.parametrize("verb", ["track", "check"])
def test_design_gnn_over_a_tracker_file_blames_the_file(tmp_path: Path, verb: str) -> None:
    """``--design gnn`` with a sort tracker file of min_hits 7 (the default N is 5) named
    the scene as the culprit (``error: s.json: the gnn design confirms ...``); the value is
    the tracker file's, at its line."""
    scene = _gnn_scene(tmp_path / "s.json")
    tracker = tmp_path / "t.toml"
    tracker.write_text('design = "sort"\nmin_hits = 7\n')
    specs = [ROBUSTNESS] if verb == "check" else []
    r = lesmc(verb, str(scene), *specs, "--tracker", str(tracker), "--design", "gnn")
    _refused(r, f"{tracker}:2:1: min_hits 7 must be at most confirm_window 5")
    assert "s.json" not in r.stderr and r.stdout == ""
    # the sort design reads no confirm_window: the same file is fine for it
    ok = lesmc("track", str(scene), "--tracker", str(tracker), "--design", "sort")
    assert ok.returncode == 0, ok.stderr
