"""The verification report: path measures against the engines, files, figures, the browser view."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, assume, given, settings
from oracle import brute_force
from pipeline_run import design_runs
from test_engines import _bound_property, cases

from lesmc.cli.main import cli
from lesmc.engines.check import check_bound
from lesmc.language.parser import load_spec
from lesmc.model.lts import to_arrays, to_lts
from lesmc.report.publish import publish
from lesmc.results.document import provenance, run_json
from lesmc.results.record import DesignRun
from lesmc.scene import load_scene

SCENES = Path(__file__).parent / "scenes"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_track_measures_in_the_results_equal_an_independent_brute_force(case: tuple) -> None:
    """Table 3 as the results file holds it: every track the oracle admits (tests/oracle.py,
    Eq. 4, 5, 8, 9 and the monitor written out again) has the oracle's objective and
    constraint, and the engines' optimum is the least objective of the tracks that break."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    # the threshold is one of the values that occur; move it off them, so that two independent
    # float sums cannot round to different sides of it
    if math.isfinite(bp.bound):
        bp = dataclasses.replace(bp, bound=bp.bound * (1 + 1e-7) + 1e-9)
    oracle = brute_force(model, bp)
    cm = to_arrays(model)
    r = check_bound(cm, bp, "bnb")
    run = run_json(DesignRun("model", [bp], [r], cm))
    assert run["paths_total"] == len(run["paths"]) == _count(model)
    want = {tuple(states): (o, c) for states, o, c in oracle.paths}
    seen = set()
    for p in run["paths"]:
        j = p["judged"][0]
        states = tuple(p["states"][: bp.end + 1])
        if j["admissible"] and not j["alarms"] and states in want:
            seen.add(states)
            o, c = want[states]
            assert _f(j["objective"]) == pytest.approx(o, rel=1e-12, abs=1e-12)
            assert _f(j["constraint"]) == pytest.approx(c, rel=1e-12, abs=1e-12)
    assert seen == {s[: bp.end + 1] for s in want}
    assume(
        all(not math.isclose(c, bp.bound, rel_tol=1e-9, abs_tol=1e-12) for _, _, c in oracle.paths)
    )
    assert _f(r.optimum_json()) == pytest.approx(oracle.optimum, rel=1e-12, abs=1e-12)


def _f(x: float | str) -> float:
    return float(x)


def _count(model: object) -> int:
    """Root-to-leaf paths of the LTS object, counted by walking them (independent of lesmc)."""

    def walk(q: str) -> int:
        out = model.out(q)  # type: ignore[attr-defined]
        return sum(walk(t.dst) for t in out) if out else 1

    return walk(model.initial)  # type: ignore[attr-defined]


def _runs(design: str = "single") -> tuple[list[DesignRun], object]:
    scene = load_scene(SCENES / "rq4_merge.json")
    specs = [load_spec(str(SCENES / "rq4_merge.spec"))]
    return design_runs(scene, specs, [design]), scene


def write_report(runs: list[DesignRun], out: Path, meta: dict | None = None) -> Path:
    specs = [load_spec(str(SCENES / "rq4_merge.spec"))]
    return publish(runs, out, meta or {}, provenance(specs, ["test"]))[0]


def test_report_files_and_contents(tmp_path: Path) -> None:
    runs, _ = _runs()
    out = write_report(runs, tmp_path / "rep", {"scene": "rq4_merge.json"})
    html = out.read_text()
    assert html.startswith("<!DOCTYPE html>")
    assert html.count("data:image/png;base64,") == len(
        list((tmp_path / "rep/figures").glob("*.png"))
    )
    assert "src='@@" not in html and "http" not in html.split("</style>")[1]  # self-contained
    for title in ("Verdicts (Table 4)", "Measures of the attacked tracks (Table 3)"):
        assert title in html
    for png in (tmp_path / "rep/figures").glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads((tmp_path / "rep/results.json").read_text())
    run = doc["runs"][0]
    assert run["paths_total"] == _count(to_lts(runs[0].model)) == len(run["paths"])
    assert [r["verdict"] for r in run["results"]] == [r.verdict for r in runs[0].results]
    assert not [p for p in (tmp_path / "rep").iterdir() if p.name.startswith(".")]


def test_two_designs_are_compared(tmp_path: Path) -> None:
    scene = load_scene(SCENES / "rq4_merge.json")
    specs = [load_spec(str(SCENES / "rq1_platoon.spec"))]
    runs = design_runs(scene, specs, ["single", "joint", "improved"])
    assert [r.label for r in runs] == ["single", "joint KFs", "joint KFs + monitor"]
    assert all(bp.monitor_components is None for bp in runs[1].bound)
    assert all(bp.monitor_components is not None for bp in runs[2].bound)
    assert runs[1].model is runs[2].model  # one model for the joint tracker
    html = write_report(runs, tmp_path / "rep").read_text()
    assert "Designs compared (Table 5)" in html


def test_a_large_tree_is_summarised_and_compressed(tmp_path: Path) -> None:
    from lesmc.report import figures
    from lesmc.report.figures import TreePath

    runs, _ = _runs()
    doc = json.loads((write_report(runs, tmp_path / "rep").parent / "results.json").read_text())
    run = doc["runs"][0]
    paths = [TreePath(p["no"], tuple(p["states"]), tuple(p["labels"])) for p in run["paths"]]
    png = figures.tree(paths[:3], run["paths_total"], tuple(run["window"]))
    assert png[:4] == b"\x89PNG"
    # only steps where some path branches are drawn, plus the first and the last
    cols = figures.tree_columns(paths, run["window"][0] - 1)
    last = max(len(p.states) for p in paths) - 1
    assert cols[0] == run["window"][0] - 1 and cols[-1] == last
    for k in cols[1:-1]:
        assert len({p.states[: k + 1] for p in paths}) > len({p.states[:k] for p in paths})
    assert all(run["window"][0] <= k <= run["window"][1] for k in cols[1:-1])


def test_report_redraws_from_the_results_file_alone(tmp_path: Path) -> None:
    """``lesmc report`` needs only results.json: the scene and specs may be gone."""
    runs, _ = _runs()
    first = write_report(runs, tmp_path / "a")
    copy = tmp_path / "only" / "results.json"
    copy.parent.mkdir()
    copy.write_text((first.parent / "results.json").read_text())
    r = CliRunner().invoke(cli, ["report", str(copy), "--out", str(tmp_path / "b"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["format"] == "lesmc-report" and out["version"] == 1
    assert (tmp_path / "b/report.html").read_text() == first.read_text()
    broken = tmp_path / "broken.json"
    doc = json.loads(copy.read_text())
    del doc["runs"][0]["paths"]
    broken.write_text(json.dumps(doc))
    from test_cli import lesmc

    r2 = lesmc("report", str(broken), "--out", str(tmp_path / "c"))
    assert r2.returncode == 2 and "runs[0]" in r2.stderr and "paths" in r2.stderr
    assert "Traceback" not in r2.stderr and not (tmp_path / "c").exists()


def test_report_dir_keeps_what_the_run_did_not_create(tmp_path: Path) -> None:
    runs, _ = _runs()
    out = tmp_path / "rep"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "mine.txt").write_text("keep me")
    (out / "notes.txt").write_text("keep me too")
    write_report(runs, out)
    assert (out / "figures" / "mine.txt").read_text() == "keep me"
    assert (out / "notes.txt").read_text() == "keep me too"
    assert (out / "report.html").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging left


def test_a_second_run_into_a_locked_dir_fails_clearly(tmp_path: Path) -> None:
    import fcntl
    import os

    from lesmc.common.errors import UsageError
    from lesmc.report.staging import staged

    out = tmp_path / "rep"
    with staged(out) as tmp:
        (tmp / "a.txt").write_text("first")
        with pytest.raises(UsageError, match="another lesmc run"), staged(out):
            pass
    assert (out / "a.txt").read_text() == "first"
    lock = tmp_path / ".rep.lesmc-lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        from test_cli import lesmc

        runs, _ = _runs()
        results = write_report(runs, tmp_path / "src").parent / "results.json"
        r = lesmc("report", str(results), "--out", str(out))
        assert r.returncode == 2 and "another lesmc run" in r.stderr, r.stderr
        assert not (out / "report.html").exists()
    finally:
        os.close(fd)


def test_results_file_validates_against_the_shipped_schema(tmp_path: Path) -> None:
    import jsonschema

    from lesmc.schemas import schema

    runs = design_runs(
        load_scene(SCENES / "rq4_merge.json"),
        [load_spec(str(SCENES / "rq1_platoon.spec"))],
        ["single", "improved"],
    )
    doc = json.loads((write_report(runs, tmp_path / "r").parent / "results.json").read_text())
    jsonschema.validate(doc, schema("results"))
    assert doc["format"] == "lesmc-results" and doc["version"] == 2
    prov = doc["provenance"]
    assert prov["command"] == ["test"] and prov["specs"][0]["text"].startswith("#")
    assert set(prov["model_sha256"]) == {"single", "improved"}
    monitored = doc["runs"][1]["results"]
    assert all(r["original_alarms"] is not None for r in monitored)
    assert all(r["original_alarms"] is None for r in doc["runs"][0]["results"])


def test_check_report_cli_on_a_scene_and_on_a_model(tmp_path: Path) -> None:
    scene, spec = str(SCENES / "rq2_stop.json"), str(SCENES / "rq2_stop.spec")
    r = CliRunner().invoke(cli, ["check", scene, spec, "--report", str(tmp_path / "a"), "--json"])
    plain = CliRunner().invoke(cli, ["check", scene, spec, "--json"])
    assert r.exit_code == plain.exit_code
    got = [(x["property"], x["verdict"], x["optimum"]) for x in json.loads(r.stdout)["results"]]
    want = [
        (x["property"], x["verdict"], x["optimum"]) for x in json.loads(plain.stdout)["results"]
    ]
    assert got == want  # the built model gives the same answers as checking on the fly
    assert (tmp_path / "a/report.html").is_file()
    model = tmp_path / "m.lts"
    assert (
        CliRunner().invoke(cli, ["build", scene, "--window", "6..8", "-o", str(model)]).exit_code
        == 0
    )
    r2 = CliRunner().invoke(cli, ["check", str(model), spec, "--report", str(tmp_path / "b")])
    assert r2.exit_code in (0, 1) and (tmp_path / "b/report.html").is_file()


def test_verify_on_a_scene(tmp_path: Path) -> None:
    r = CliRunner().invoke(
        cli,
        [
            "verify",
            "--scene",
            str(SCENES / "rq4_merge.json"),
            "--spec",
            str(SCENES / "rq1_platoon.spec"),
            "--out",
            str(tmp_path / "v"),
            "--json",
        ],
    )
    assert r.exit_code in (0, 1), r.output
    doc = json.loads(r.stdout)
    assert [run["design"] for run in doc["runs"]] == ["single", "joint", "improved"]
    assert [run["label"] for run in doc["runs"]] == ["single", "joint KFs", "joint KFs + monitor"]
    assert (tmp_path / "v/report.html").is_file()


def test_verify_end_to_end_on_a_small_video(tmp_path: Path) -> None:
    """Frames -> scene -> models -> verdicts -> report, with the target chosen from the truth."""
    video = tmp_path / "video"
    assert (
        CliRunner()
        .invoke(
            cli,
            [
                "synth",
                str(video),
                "--frames",
                "16",
                "--size",
                "768x768",
                "--seed",
                "4",
                "--density",
                "2.5",
            ],
        )
        .exit_code
        == 0
    )
    r = CliRunner().invoke(
        cli,
        [
            "verify",
            str(video),
            "--truth",
            str(video / "truth.json"),
            "--window",
            "3..5",
            "--out",
            str(tmp_path / "v"),
            "--json",
        ],
    )
    assert r.exit_code in (0, 1, 3), r.output
    doc = json.loads(r.stdout)
    assert "target choice" in doc["meta"]
    scene = load_scene(tmp_path / "v/scene.json")
    assert scene.target.step == 4 and len(scene.frames) == 12
    html = (tmp_path / "v/report.html").read_text()
    assert "detections of step 5" in html
    doc = json.loads((tmp_path / "v/results.json").read_text())
    assert doc["runs"][0]["scene"]["truth_ref"]  # the target's ground truth, drawn in figures
    assert "ground truth" in html
    fa = doc["monitor_false_alarms"]["rows"]
    assert fa[0]["tracks"] > 0 and fa[-1]["alarms"] == 0  # the largest-rise tolerance is silent


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.skipif(_chromium() is None, reason="Chromium is not installed (.ci/run installs it)")
def test_report_renders_in_a_real_browser(tmp_path: Path) -> None:
    import cv2

    runs, _ = _runs()
    report = write_report(runs, tmp_path / "rep")
    shot = tmp_path / "shot.png"
    cmd = [
        _chromium(),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--window-size=1200,2000",
        f"--screenshot={shot}",
        report.as_uri(),
    ]
    subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    img = cv2.imread(str(shot))
    assert img is not None, "Chromium wrote no screenshot"
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert (grey < 200).mean() > 0.03  # text, tables and figures, not a blank page
    # the figures were decoded and drawn: plenty of colour (green, red, blue lines)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    assert (hsv[..., 1] > 100).mean() > 0.001
    assert np.unique(grey).size > 50


@pytest.mark.parametrize("case", ["tiny", "knapsack12", "wami_single"])
def test_report_on_any_model(case: str, tmp_path: Path) -> None:
    """Models that are not tracks (1-D states, no images) still get a report."""
    d = Path(__file__).parent / "golden" / case
    specs = [str(p) for p in sorted(d.glob("*.spec"))]
    r = CliRunner().invoke(
        cli, ["check", str(d / "model.lts"), *specs, "--report", str(tmp_path / "r"), "--json"]
    )
    assert r.exit_code in (0, 1), r.output
    doc = json.loads((tmp_path / "r/results.json").read_text())
    assert [x["verdict"] for x in doc["runs"][0]["results"]] == [
        x["verdict"] for x in json.loads(r.stdout)["results"]
    ]
    # the report's path count, against an independent enumeration by networkx
    import networkx as nx

    from lesmc.model.lts import to_lts
    from lesmc.model.lts_format import load_lts

    model = to_lts(load_lts(d / "model.lts"))
    leaves = [q for q in model.graph if model.graph.out_degree(q) == 0]
    n = sum(len(list(nx.all_simple_paths(model.graph, model.initial, leaf))) for leaf in leaves)
    assert doc["runs"][0]["paths_total"] == n
    from html_tables import table_problems

    assert table_problems((tmp_path / "r" / "report.html").read_text()) == []


def test_verify_refuses_a_window_past_the_track(tmp_path: Path) -> None:
    import sys

    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "lesmc",
            "verify",
            "--scene",
            str(SCENES / "rq4_merge.json"),
            "--window",
            "30..40",
            "--out",
            str(tmp_path / "v"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "--window 30..40" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "v" / "report.html").exists()


def test_the_table_checker_finds_what_a_browser_would_show_broken() -> None:
    """tests/html_tables.py itself (the browserless half of tests/test_browser.py)."""
    from html_tables import table_problems

    head = "<tr><th>a</th><th>b</th></tr>"
    assert table_problems(f"<table>{head}<tr><td>1</td><td>2</td></tr></table>") == []
    assert table_problems(f"<table>{head}<tr><td>1</td></tr></table>") == [
        "table 0: rows of [1, 2] columns"
    ]
    assert table_problems(
        "<table><tr><th></th><th> </th></tr><tr><td>1</td><td>2</td></tr></table>"
    ) == ["table 0: an empty header row"]
    spanned = "<table><tr><th colspan='2'>ab</th></tr><tr><td>1</td><td>2</td></tr></table>"
    assert table_problems(spanned) == []


def test_the_templates_escape_what_the_results_file_says(tmp_path: Path) -> None:
    """report.html comes from Jinja2 templates with autoescaping: text from the results
    file (here its meta) cannot inject markup; the page's own markup is intact."""
    runs, _ = _runs()
    page = write_report(runs, tmp_path / "r", {"video": "<script>alert(1)</script> & more"})
    html = page.read_text()
    assert "<script>" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt; &amp; more" in html
    assert "<h2 id='verdicts'>Verdicts</h2>" in html and "<figure><img src='data:image/png" in html


def test_a_table_refuses_rows_narrower_or_wider_than_its_header() -> None:
    """lesmc/report/pages.py: every table of both pages is built through Table, which
    counts colspans and the cells rows above span into a row."""
    from lesmc.report.pages import Cell, Row, Table, table

    assert table(["a", "b"], [[1, 2], [3, Cell(4)]]).width == 2
    with pytest.raises(ValueError, match="not 2 columns wide"):
        table(["a", "b"], [[1]])
    two_rows = [[Cell("p", head=True, rows=2), Cell("d", head=True, span=2)],
                [Cell("x", head=True), Cell("y", head=True)]]  # fmt: skip
    assert Table(two_rows, [Row([Cell(1), Cell(2), Cell(3)])]).width == 3
    with pytest.raises(ValueError):
        Table(two_rows, [Row([Cell(1), Cell(2)])])


def test_figures_are_the_bytes_of_savefigs_tight_box(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """figures.png finds the tight box without savefig's extra drawing pass: each figure of
    a report (three designs), of frame crops and of attack patches must be the very PNG
    that ``savefig(bbox_inches="tight")`` writes."""
    import io

    from lesmc.report import figures

    own = figures.png
    compared = []

    def both(fig: object) -> bytes:
        buf = io.BytesIO()
        fig.savefig(  # type: ignore[attr-defined]
            buf, format="png", dpi=figures.DPI, bbox_inches="tight",
            pil_kwargs={"compress_level": 1},
        )  # fmt: skip
        png = own(fig)  # type: ignore[arg-type]
        assert png == buf.getvalue()
        compared.append(1)
        return png

    monkeypatch.setattr(figures, "png", both)
    monkeypatch.setenv("LESMC_DRAW_PROCESSES", "1")  # every figure compared here
    scene = load_scene(SCENES / "rq4_merge.json")
    specs = [load_spec(str(SCENES / "rq4_merge.spec"))]
    write_report(design_runs(scene, specs, ["single", "joint", "improved"]), tmp_path / "r")
    rng = np.random.default_rng(3)
    image = rng.integers(0, 255, size=(96, 128)).astype(np.uint8)
    xy = np.array([[20.0, 30.0], [40.0, 35.0], [60.0, 52.0]])
    track = figures.Series("original", "original", np.array([0.0, 1.0, 2.0]))
    figures.track_crop([(track, xy)], 0, 0, xy + 3, xy - 2, image, "a crop")
    patch = rng.uniform(0, 255, size=(21, 21))
    figures.patches([("d1", patch), ("d2", patch[::-1])])
    delta = rng.normal(0, 0.01, size=(21, 21))
    figures.perturbations([("d1", patch, delta), ("d2", patch, -delta)])
    assert len(compared) >= 10
