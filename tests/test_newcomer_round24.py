"""Round 24, a newcomer's reading of the issue-61 material: what the help says agrees
with what the tool does.

``lesmc import mot --help`` named the designs that take ``allow inject`` as
"single, sort, gnn", although ``joint`` takes it too (docs/language.md, "Attack
actions"). The test runs a ``joint`` check with ``allow hide, inject`` on an imported
scene with candidates (the tool's behaviour, independent of the help's text) and asks
the help to name every design that accepted it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from tests.cli_run import ROOT, lesmc

SPEC = """property reach {
    attack window 1..2 allow hide, inject
    minimize payoff
    subject to dist.sum(0..end) > 1
    holds if optimum > 100
    on x, y
}
"""

#: Three frames of a target moving right, a detection on it and a low-score line beside
#: it in each (conf 0.1 below the threshold 0.5: a candidate priced 0.25 by column 8).
DET = "".join(
    f"{f},-1,{98 + 5 * f},98,4,4,0.9,1.0\n{f},-1,{98 + 5 * f},118,4,4,0.1,0.25\n" for f in (1, 2, 3)
)
GT = "".join(f"{f},7,{98 + 5 * f},98,4,4,1,1,1\n" for f in (1, 2, 3))


def _help_designs() -> set[str]:
    """The designs ``lesmc import mot --help`` says take ``allow inject``."""
    out = lesmc("import", "mot", "--help")
    assert out.returncode == 0 and "Traceback" not in out.stderr
    text = " ".join(out.stdout.split())
    m = re.search(r"lets the attacker add \(([^)]*)\)", text)
    assert m, text
    return {w.strip() for w in m.group(1).split(",")}


def _scene(tmp: Path) -> Path:
    (tmp / "det.txt").write_text(DET)
    (tmp / "gt.txt").write_text(GT)
    scene = tmp / "scene.json"
    out = lesmc(
        "import", "mot", str(tmp / "det.txt"), "--gt", str(tmp / "gt.txt"), "--track", "7",
        "--inject-column", "8", "--threshold", "0.5", "-o", str(scene),
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    doc = json.loads(scene.read_text())
    assert doc["version"] == 3 and any(f.get("candidates") for f in doc["frames"])
    return scene


def test_import_mot_help_names_every_design_that_takes_inject(tmp_path: Path) -> None:
    scene = _scene(tmp_path)
    (tmp_path / "r.spec").write_text(SPEC)
    named = _help_designs()
    for design in ("single", "joint"):
        out = lesmc("check", str(scene), str(tmp_path / "r.spec"), "--design", design)
        assert "Traceback" not in out.stderr
        assert out.returncode in (0, 1), (design, out.stderr)  # taken: a verdict
        assert design in named, (design, named)


def test_language_doc_does_not_call_the_injection_replay_open() -> None:
    text = (ROOT / "docs" / "language.md").read_text()
    assert (ROOT / "lesmc" / "replay" / "inject.py").is_file()
    assert "Still open\n(issue 61): the replay of an injection" not in text


def _problems(scene: Path) -> list[str]:
    """The located problems ``lesmc track SCENE`` reports (exit 2, no traceback)."""
    out = lesmc("track", str(scene))
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    return [ln for ln in out.stderr.splitlines() if ln.startswith(f"{scene}:")]


def test_a_bad_candidate_payoff_is_one_problem_not_every_truth_row(tmp_path: Path) -> None:
    """A negative candidate payoff in frame 1 used to report, besides itself, the truth
    row of frame 1 as "not a frame of the scene" (the frame was left out of the steps)."""
    scene = _scene(tmp_path)
    doc = json.loads(scene.read_text())
    first = next(f for f in doc["frames"] if f.get("candidates"))
    first["candidates"][0]["payoff"] = -1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc, indent=1))
    got = _problems(bad)
    assert len(got) == 1 and f"frame {first['step']}, candidate" in got[0], got
    # a truth row outside the scene's frames is still refused, at the truth track
    doc["truth"][0]["positions"][0][0] = 99
    bad.write_text(json.dumps(doc, indent=1))
    got = _problems(bad)
    assert len(got) == 2 and "truth track '7'" in got[1], got


def test_cli_md_synopses_name_every_option_of_the_verb() -> None:
    """docs/cli.md's synopsis of a verb (its longest one-line `lesmc VERB ...`) names
    every option ``lesmc VERB --help`` has: ``perceive`` lacked --save-attacks,
    ``verify`` --detector, --locator, --tracker, --price-all, ``campaign`` --detector,
    --locator, --tracker."""
    import click

    from lesmc.cli.main import cli

    doc = (ROOT / "docs" / "cli.md").read_text()
    for verb in ("perceive", "verify", "campaign", "replay"):
        cmd = cli.commands[verb]
        lines = re.findall(rf"`lesmc {verb} ([^`]*)`", doc)
        synopsis = max(lines, key=lambda t: t.count("--"))
        named = set(re.findall(r"--[a-z0-9][-a-z0-9]*", synopsis)) | set(
            re.findall(r"(?<![-\w])-[a-z](?![-\w])", synopsis)
        )
        for p in cmd.params:
            if isinstance(p, click.Option) and "--help" not in p.opts:
                assert named & set(p.opts), (verb, p.opts, synopsis)


def test_perceive_says_when_inject_within_found_no_candidates(tmp_path: Path) -> None:
    """``perceive -o S --inject-within PX`` that finds none wrote ``meta.candidates`` and
    said nothing about candidates: a user could not tell "none found" from "not asked"."""
    video = tmp_path / "v"
    made = lesmc("synth", str(video), "--frames", "7", "--size", "256x256", "--seed", "3")
    assert made.returncode == 0, made.stderr
    scene = tmp_path / "s.json"
    out = lesmc("perceive", str(video), "-o", str(scene), "--inject-within", "0")
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    doc = json.loads(scene.read_text())
    assert not any(f.get("candidates") for f in doc["frames"])  # none within 0 px
    assert "no injection candidates" in out.stdout + out.stderr
