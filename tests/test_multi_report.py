"""Multi-target designs in verify and the report (issue 58): the WAMI front end's detections
carry their window's box, ``lesmc verify --design sort`` runs end to end on a small video
and writes a ``lesmc-multi-check`` results file, and ``lesmc report`` draws a
counterexample's tracks, whose ids the reference SORT (sort-tracker-py) reproduces."""

from __future__ import annotations

import json
import re
from html import unescape
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from cli_run import lesmc

from lesmc.schemas import schema, validate
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

pytest.importorskip("sort_tracker")
import sort_reference
from test_multi_attack import _doc, _frames


def _valid(doc: dict[str, Any]) -> None:
    """``doc`` conforms to the shipped schema (jsonschema, and lesmc's own validator)."""
    jsonschema.validate(doc, schema("multi-check"))
    validate(doc, "multi-check")


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc verify VIDEO --design sort`` on a 12-frame 448 x 448 video: its OUT."""
    base = tmp_path_factory.mktemp("multi")
    video = base / "video"
    write_video(SynthConfig(frames=12, width=448, height=448, seed=4, density=3.0), video)
    out = base / "out"
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--design", "sort", "--window", "3..4")  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), r.stderr
    return out


def test_a_perceived_scene_has_each_detections_window_as_its_box(verified: Path) -> None:
    doc = json.loads((verified / "scene.json").read_text())
    assert doc["version"] == 2
    dets = [d for f in doc["frames"] for d in f["detections"]]
    assert dets
    # N_dr classifies a 21 x 21 window centred on the candidate (the paper's section 6.6)
    assert all((d["w"], d["h"]) == (21.0, 21.0) for d in dets)


def test_verify_sort_writes_a_multi_check_results_file_and_a_report(
    verified: Path, tmp_path: Path
) -> None:
    doc = json.loads((verified / "results.json").read_text())
    _valid(doc)
    assert (doc["format"], doc["version"], doc["design"]) == ("lesmc-multi-check", 2, "sort")
    assert [r["property"] for r in doc["results"]] == ["robustness", "resilience", "hijack"]
    assert "target" in doc["meta"] and "models and checks" in doc["timings"]
    page = (verified / "report.html").read_text()
    assert "the sort design (multi-target)" in page
    video = verified.parent / "video"
    again = lesmc(
        "report",
        str(verified / "results.json"),
        "--out",
        str(tmp_path / "r"),
        "--frames",
        str(video),
    )
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    redrawn = (tmp_path / "r" / "report.html").read_text()
    assert redrawn == page  # drawn from the results file alone, as verify drew it
    for r in doc["results"]:
        assert f"Property {r['property']}" in redrawn
        steps = r["counterexample"] or []
        if not steps:
            continue
        for s, row in zip(steps, _rows(redrawn, r["property"]), strict=True):
            assert row[:3] == [str(s["step"]), str(s["frame"]), str(s["target_id"] or "-")]
            words = row[6].split(" (and ")
            listed = [w for w in words[0].split() if w != "-"]
            have = {f"{t['id']}:{t['status'][:4]}" for t in s["tracks"]}
            assert set(listed) <= have and len(listed) == len(set(listed))
            if s["target_id"] is not None:  # the target's track is always in view
                assert any(w.startswith(f"{s['target_id']}:") for w in listed)
            # every track is listed, or the row counts those left out
            rest = int(words[1].split()[0]) if len(words) > 1 else 0
            assert len(listed) + rest == len(s["tracks"])
            assert rest == 0 or len(s["tracks"]) > 40


def _rows(page: str, prop: str) -> list[list[str]]:
    """The steps table of property ``prop`` on the report page: its cells' texts."""
    part = page.split(f"Property {prop}</h2>", 1)[1].split("<h2", 1)[0]
    body = part.split("tracks (id:status)", 1)[1].split("</tbody>", 1)[0]
    return [
        [unescape(c) for c in re.findall(r"<td>(.*?)</td>", row)]
        for row in re.findall(r"<tr>(.*?)</tr>", body)
    ]


def _switching_scene(tmp_path: Path) -> tuple[Path, list[np.ndarray], dict[str, Any]]:
    """A random box scene (tests/test_multi_attack.py's: three objects crossing) on which
    the cheapest hijack exists, its frames, and ``lesmc check --design sort --json``
    (with ``--report``: its results file is that document, and its report marks the
    switch)."""
    spec = tmp_path / "hijack.spec"
    spec.write_text(
        "property hijack {\n  attack window 2..4\n  minimize payoff\n"
        "  subject to switches(0..end) > 0\n  holds if optimum > 3\n}\n"
    )
    import lesmc as api

    for seed in range(40):
        rng = np.random.default_rng(seed)
        frames = _frames(rng, 7)
        pay = [rng.integers(1, 6, len(f)).astype(float) for f in frames]
        scene = tmp_path / f"scene{seed}.json"
        scene.write_text(json.dumps(_doc(frames, pay)))
        (res,) = api.check(scene, spec, designs="sort")
        if res.counterexample is not None:
            chk = tmp_path / "chk"
            r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json",
                      "--report", str(chk))  # fmt: skip
            assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
            doc = json.loads(r.stdout)
            # check --report writes the same document and draws it
            assert json.loads((chk / "results.json").read_text()) == doc
            assert "SWITCH" in (chk / "report.html").read_text()
            return scene, frames, doc
    raise AssertionError("no seed of 40 gives a hijack")


def test_the_report_draws_a_switch_that_the_reference_sort_reproduces(tmp_path: Path) -> None:
    _, frames, doc = _switching_scene(tmp_path)
    _valid(doc)
    results = tmp_path / "check.json"
    results.write_text(json.dumps(doc))
    r = lesmc("report", str(results), "--out", str(tmp_path / "rep"))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "SWITCH" in page and list((tmp_path / "rep" / "figures").glob("multi_0_*.png"))
    rows = _rows(page, "hijack")
    assert [int(c[0]) for c in rows] == list(range(len(frames)))
    # the hidden detections, read from the page, run through Bewley's SORT
    names = [h for c in rows for h in c[4].split(", ") if h != "-"]
    hidden = {(int(h.split(":")[0]), int(h.split(":")[1])) for h in names}
    assert hidden
    kept = [np.delete(b, [j for k2, j in hidden if k2 == k], axis=0) for k, b in enumerate(frames)]
    ref = sort_reference.reference_sort(kept)
    rename: dict[int, int] = {}  # ours -> the reference's, fixed at first sight
    for k, (c, out) in enumerate(zip(rows, ref, strict=True)):
        shown = {int(t.split(":")[0]) for t in c[6].split() if t.endswith(":conf")}
        step = next(s for s in doc["results"][0]["counterexample"] if s["step"] == k)
        boxes = {t["id"]: np.array(t["box"]) for t in step["tracks"] if t["status"] == "confirmed"}
        assert set(boxes) == shown
        for i in sorted(shown):
            j = min(out, key=lambda j: float(np.abs(out[j] - boxes[i]).max()))
            assert np.allclose(out[j], boxes[i], atol=1e-6), (k, i)
            assert rename.setdefault(i, j) == j, (k, i, j)
        assert len(out) == len(shown), (k, sorted(out), sorted(shown))
    switch_rows = [c for c in rows if c[3] == "SWITCH"]
    assert switch_rows
    before = [c[2] for c in rows[: rows.index(switch_rows[0])] if c[2] != "-"]
    assert before and before[-1] != switch_rows[0][2]  # the id the page shows changed


def test_verify_refuses_a_multi_target_design_among_point_designs(tmp_path: Path) -> None:
    """One results file holds one kind of result: sort with single is a UsageError before
    any work (nothing written), as is a second multi-target design."""
    import lesmc as api
    from lesmc.common.errors import UsageError

    for designs, word in ((("single", "sort"), "single"), (("sort", "gnn"), "one multi-target")):
        req = api.VerifyRequest(designs=designs, out=tmp_path / "out")
        with pytest.raises(UsageError) as err:
            api.verify(req)
        assert word in err.value.message
    assert not (tmp_path / "out").exists()


def test_verify_gnn_draws_point_tracks(verified: Path, tmp_path: Path) -> None:
    """``--design gnn`` on the same video (its perception read from the sort run's cache):
    the tracks are positions, and the report draws them."""
    import shutil

    out = tmp_path / "gnn"
    shutil.copytree(verified / "cache", out / "cache")
    video = verified.parent / "video"
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--design", "gnn", "--window", "3..4")  # fmt: skip
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    assert "reusing the perception" in r.stderr
    doc = json.loads((out / "results.json").read_text())
    _valid(doc)
    assert doc["design"] == "gnn"
    steps = [s for res in doc["results"] for s in res["counterexample"] or []]
    assert steps and all("position" in t and "box" not in t for s in steps for t in s["tracks"])
    assert "the gnn design (multi-target)" in (out / "report.html").read_text()
