"""What a user reads agrees with itself (issue 56, items 1-4, 12, 22): every note and label of
the default ``lesmc verify`` report against its verdict, the cheapest path of a property that
holds (not a counterexample), where an imported scene's payoffs came from, which count of
states is which, the replay command with the networks a scene was made with, and the help.

The default ``lesmc verify`` runs once for this module (:func:`verified`)."""

from __future__ import annotations

import html
import json
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc, lesmc_logged
from note_verdicts import contradictions

MOT = ROOT / "examples" / "mot"


@pytest.fixture(scope="module")
def verified(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, subprocess.CompletedProcess[str], dict[str, Any]]:
    """``lesmc verify --out OUT`` as a user first runs it (the embedded video, the bundled
    specs, the table on stdout): OUT, the finished process and OUT/results.json."""
    out = tmp_path_factory.mktemp("verify-default") / "v"
    r, _ = lesmc_logged("verify", "--out", str(out))
    assert r.returncode in (0, 1, 3) and "Traceback" not in r.stderr, r.stderr
    return out, r, json.loads((out / "results.json").read_text())


def _sections(page: str) -> dict[str, str]:
    """The report's design sections by design tag (their HTML)."""
    parts = re.split(r"<section><h2 id='design-", page)[1:]
    return {p.split("'", 1)[0]: p.split("</section>", 1)[0] for p in parts}


def _text(fragment: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", fragment))


def test_no_note_or_label_of_the_default_report_contradicts_its_verdict(
    verified: tuple[Path, subprocess.CompletedProcess[str], dict[str, Any]],
) -> None:
    """Item 1: results.json's notes and the report's notes are written from the verdict
    after the replay; no "counterexample" label on a property that holds."""
    out, _, doc = verified
    problems: list[str] = []
    replayed = 0
    for run in doc["runs"]:
        for r in run["results"]:
            replayed += (r.get("replay") or {}).get("status") in ("confirmed", "diverged")
            problems += [f"results.json {run['design']}: {p}" for p in
                         contradictions(r["status"], r["notes"])]  # fmt: skip
    assert replayed, "the default video's counterexamples are replayed: notes to look at"
    sections = _sections((out / "report.html").read_text())
    for run in doc["runs"]:
        section = sections[run["design"]]
        notes = [_text(n) for n in re.findall(r"<p class='note'>(.*?)</p>", section, re.S)]
        for r in run["results"]:
            mine = [n.removeprefix(r["property"] + ": ") for n in notes
                    if n.startswith(r["property"] + ": ")]  # fmt: skip
            problems += [f"report {run['design']}: {p}" for p in
                         contradictions(r["status"], mine)]  # fmt: skip
            # the verdict the section's Table 4 shows is the results' final one
            row = re.search(r"<th>" + re.escape(r["property"]) + r"</th>\s*<td[^>]*>(.*?)</td>",
                            section, re.S)  # fmt: skip
            assert row is not None, run["design"]
            cell = re.sub(r"^holds \(vacuous: .*\)$", "holds (vacuous)", _text(row.group(1)))
            assert cell == r["status"], run["design"]
            if r["verdict"] == "holds":
                assert f"{r['property']} counterexample" not in _text(section), run["design"]
    assert problems == []


def test_the_log_announces_each_model_before_its_checks(
    verified: tuple[Path, subprocess.CompletedProcess[str], dict[str, Any]],
) -> None:
    """Item 22: "building the single model" comes before "checking robustness (single)"."""
    _, r, doc = verified
    lines = [line.split(": ", 1)[-1] for line in r.stderr.splitlines()]
    built = {line.removeprefix("building the ").removesuffix(" model")
             for line in lines if line.startswith("building the ")}  # fmt: skip
    assert built, r.stderr
    for run in doc["runs"]:
        if run["label"] not in built:
            continue  # a design that shares another one's model (joint KFs + monitor)
        build = lines.index(f"building the {run['label']} model")
        checks = [i for i, line in enumerate(lines) if line.endswith(f" ({run['label']})")]
        assert checks and build < min(checks), r.stderr


def test_the_help_names_the_designs_verify_runs(
    verified: tuple[Path, subprocess.CompletedProcess[str], dict[str, Any]],
) -> None:
    """Item 22: the top-level help names what the default verify really ran (three
    designs), not "both designs"."""
    _, _, doc = verified
    ran = [run["design"] for run in doc["runs"]]
    assert len(ran) == 3
    r = lesmc("--help")
    assert r.returncode == 0
    text = " ".join(r.stdout.split())
    assert "both designs" not in text
    line = text.split("lesmc verify ", 1)[1].split("lesmc verify FRAMES/", 1)[0]
    assert all(re.search(rf"\b{d}\b", line) for d in ran), line
    assert f"the {len(ran)} of --design paper" in line


def test_verifys_table_and_report_say_which_states(
    verified: tuple[Path, subprocess.CompletedProcess[str], dict[str, Any]],
) -> None:
    """Item 4: the model's states are "states built", a search's are "states expanded"."""
    out, r, doc = verified
    states = {run["model"]["states"] for run in doc["runs"]}
    assert all(f"{n} states built" in r.stdout for n in states), r.stdout
    page = _text((out / "report.html").read_text())
    assert all(f"{n} states built" in page for n in states)
    for run in doc["runs"]:
        for res in run["results"]:
            assert f"{res['stats']['states_expanded']} states expanded" in page
            assert res["stats"]["states_built"] == run["model"]["states"]  # whole models


# ------------------------------------------------------------------ an imported MOT scene


def _spec(tmp_path: Path, threshold: float) -> Path:
    """The bundled robustness property with another threshold."""
    text = (ROOT / "specs" / "robustness.spec").read_text()
    path = tmp_path / f"robustness-{threshold:g}.spec"
    path.write_text(text.replace("holds if optimum > 3.0", f"holds if optimum > {threshold}"))
    return path


@pytest.fixture(scope="module")
def mot_scene(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """examples/mot imported twice: payoffs from the conf column (7), and the constant 1."""
    d = tmp_path_factory.mktemp("mot")
    out = {}
    for name, extra in (("conf", ("--payoff-column", "7")), ("constant", ())):
        out[name] = d / f"{name}.json"
        r = lesmc("import", "mot", str(MOT / "det.txt"), "--gt", str(MOT / "gt.txt"), "--track",
                  "7", "--fps", "1.25", *extra, "-o", str(out[name]))  # fmt: skip
        assert r.returncode == 0, r.stderr
    return out


def _objective(path: dict[str, Any]) -> float:
    """A path's payoff over the window, summed from its steps (Eq. 8's sum, again)."""
    return sum(float(s["combined_payoff"]) for s in path["steps"])


def test_the_cheapest_path_of_a_property_that_holds_is_no_counterexample(
    mot_scene: dict[str, Path], tmp_path: Path
) -> None:
    """Item 2: on the conf-column scene the cheapest path that breaks the system costs
    0.63; with the threshold 0.5 the property holds and that path is no counterexample (JSON,
    tables, report), with the threshold 3 it is one."""
    scene = str(mot_scene["conf"])
    for threshold, holds in ((0.5, True), (3.0, False)):
        spec = str(_spec(tmp_path, threshold))
        r = lesmc("check", scene, spec, "--json")
        assert r.returncode == (0 if holds else 1) and "Traceback" not in r.stderr, r.stderr
        res = json.loads(r.stdout)["results"][0]
        path = res["counterexample"]
        assert path is not None and (_objective(path) > threshold) == holds
        assert res["status"] == ("holds" if holds else "violated")
        assert res["is_counterexample"] is (not holds)
        table = lesmc("check", scene, spec).stdout
        assert ("counterexample (cheapest violating path)" in table) is (not holds)
        rep = tmp_path / f"rep-{threshold:g}"
        r = lesmc("check", scene, spec, "--report", str(rep))
        assert r.returncode == (0 if holds else 1), r.stderr
        page = _text((rep / "report.html").read_text())
        assert ("robustness counterexample" in page) is (not holds)
        assert ("robustness cheapest path" in page) is holds
        table4 = page.split("Verdicts (Table 4)", 1)[1]
        assert ("none (#" in table4) is holds


def test_the_api_calls_a_counterexample_only_what_violates(
    mot_scene: dict[str, Path], tmp_path: Path
) -> None:
    """Item 2, the API: ``CheckResult.counterexample`` is None on a property that holds;
    ``cheapest`` keeps the path (docs/api.md)."""
    import lesmc as api

    scene = api.load_scene(str(mot_scene["conf"]))
    for threshold, holds in ((0.5, True), (3.0, False)):
        (r,) = api.check(scene, api.load_spec(str(_spec(tmp_path, threshold))))
        assert r.cheapest is not None and (r.cheapest.objective > threshold) == holds
        assert r.status == ("holds" if holds else "violated")
        assert (r.counterexample is None) == holds
        assert r.counterexample is None or r.counterexample == r.cheapest


@pytest.mark.parametrize(("payoffs", "words"), [("conf", "column 7 (conf)"),
                                                ("constant", "the constant 1")])  # fmt: skip
def test_an_imported_scenes_report_says_where_its_payoffs_came_from(
    mot_scene: dict[str, Path], tmp_path: Path, payoffs: str, words: str
) -> None:
    """Item 3: the payoffs of `import mot` are the file's column or a constant, not attacks
    on N_dr: the report and results.json say so."""
    rep = tmp_path / "rep"
    r = lesmc("check", str(mot_scene[payoffs]), str(ROOT / "specs" / "robustness.spec"),
              "--report", str(rep))  # fmt: skip
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    page = _text((rep / "report.html").read_text())
    assert "hide" in page  # the table of hidden detections and its explanation
    assert "N_dr" not in page and "DeepFool" not in page
    meta = json.loads((rep / "results.json").read_text())["meta"]
    assert words in meta["payoff source"] and words in page


def test_check_says_which_states_are_built_and_which_expanded(
    mot_scene: dict[str, Path], tmp_path: Path
) -> None:
    """Item 4: `check`'s table has "states expanded" and "states built"; on a model file
    the states built are the file's."""
    scene = str(mot_scene["conf"])
    spec = str(ROOT / "specs" / "robustness.spec")
    model = tmp_path / "m.lts"
    assert lesmc("build", scene, "--window", "6..8", "-o", str(model)).returncode == 0
    n = len(json.loads(model.read_text())["states"])
    for source in (scene, str(model)):
        table = lesmc("check", source, spec).stdout
        assert "states expanded" in table and "states built" in table, table
        res = json.loads(lesmc("check", source, spec, "--json").stdout)["results"][0]
        assert res["stats"]["states_expanded"] > 0
        built = res["stats"]["states_built"]
        assert built == n if source == str(model) else 0 < built <= n


# ------------------------------------------------------------------ the replay command

SPEC_3_5 = """property robustness {
    attack window 3..5
    minimize payoff
    subject to dist.sum(0..end) > 5
    holds if optimum > 1e9
    on x, y
}
"""


def test_the_replay_command_names_the_networks_the_scene_was_made_with(tmp_path: Path) -> None:
    """Item 12: a scene perceived with ``--detector``, checked: the violation is not replayed,
    and its replay command names the frames, the detector, the spec and the design; following
    it replays the counterexample with that detector (no "now costs" mismatch)."""
    import shlex

    torch = pytest.importorskip("torch")
    from lesmc.perception.cnn import load_nets

    nets = load_nets()
    x = torch.rand(3, nets.settings.m + 1, 21, 21)
    dr = tmp_path / "dr.pt2"
    exported = torch.export.export(nets.dr, (x,), dynamic_shapes=({0: torch.export.Dim("b")},))
    torch.export.save(exported, dr)
    video, spec = tmp_path / "video", tmp_path / "r.spec"
    spec.write_text(SPEC_3_5)
    r = lesmc("synth", str(video), "--frames", "16", "--size", "768x768", "--seed", "4",
              "--density", "2.5")  # fmt: skip
    assert r.returncode == 0, r.stderr
    made = tmp_path / "made"
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--spec", str(spec),
              "--design", "single", "--detector", str(dr), "--out", str(made))  # fmt: skip
    assert r.returncode in (0, 1, 3) and "Traceback" not in r.stderr, r.stderr
    scene = made / "scene.json"
    assert json.loads(scene.read_text())["meta"]["networks"] == {"detector": str(dr)}
    r = lesmc("check", str(scene), str(spec), "--json")
    assert r.returncode == 1, r.stderr
    (res,) = json.loads(r.stdout)["results"]
    assert res["status"] == "violated (not replayed)" and res["notes"] == []
    command = shlex.split(res["replay"]["command"])
    want = ["lesmc", "verify", "--scene", str(scene), "--frames", str(video),
            "--detector", str(dr), "--spec", str(spec), "--design", "single"]  # fmt: skip
    assert command == want
    table = lesmc("check", str(scene), str(spec)).stdout
    assert f"--detector {dr}" in " ".join(table.split())
    r = lesmc(*command[1:], "--out", str(tmp_path / "again"), "--json")
    assert r.returncode in (1, 3) and "now costs" not in r.stderr, r.stderr
    (again,) = json.loads(r.stdout)["runs"][0]["results"]
    assert again["replay"]["status"] in ("confirmed", "diverged")
    assert (
        "command" not in again["replay"] and contradictions(again["status"], again["notes"]) == []
    )
