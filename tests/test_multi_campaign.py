"""``lesmc campaign --design sort`` (issue 58): a multi-target design's campaign on a small
video, its rows (schema campaign-row) with the identity properties' verdicts and optima,
each equal to what the command the campaign names for it (``lesmc verify --scene
OUT/scenes/VIDEO.json --target X,Y@STEP --window L..U --design sort``) answers; bad
combinations refused before any work."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
from cli_run import lesmc
from multi_video import write_small_video

from lesmc.schemas import schema

SPEC = """property hijack {
    attack window 2..4 within 30
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 3.0
}
property lose {
    attack window 2..4 within 30
    minimize count
    subject to lost(0..end) > 1
    holds if optimum > 1
}
"""
#: Two targets of the video (seed 5) whose identity hiding detections switches.
TARGETS = ("119,71.5@4", "194.71,80.92@4")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The campaign's OUT and its spec file."""
    base = tmp_path_factory.mktemp("multicampaign")
    video = base / "v5"
    write_small_video(video)
    spec = base / "identity.spec"
    spec.write_text(SPEC)
    targets = base / "targets.txt"
    targets.write_text("\n".join(TARGETS) + "\n")
    out = base / "out"
    r = lesmc("campaign", str(video), "--out", str(out), "--design", "sort", "--spec", str(spec),
              "--windows", "2..2:2..2", "--targets", str(targets), "--workers", "0")  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # some violated
    return out, spec


def test_rows_hold_the_identity_verdicts_that_verify_gives(campaign: tuple[Path, Path]) -> None:
    out, spec = campaign
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    for row in rows:
        jsonschema.validate(row, schema("campaign-row"))
    got = {(f"{r['target']['x']:g},{r['target']['y']:g}@{r['target']['step']}", r["property"])
           for r in rows}  # fmt: skip
    assert got == {(t, p) for t in TARGETS for p in ("hijack", "lose")}
    assert all(r["design"] == "sort" and r["window"] == [2, 4] for r in rows)
    for t in TARGETS:
        r = lesmc("verify", "--scene", str(out / "scenes" / "v5.json"), "--target", t,
                  "--window", "2..4", "--design", "sort", "--spec", str(spec), "--json",
                  "--out", str(out.parent / f"verify-{t}"))  # fmt: skip
        assert "Traceback" not in r.stderr, r.stderr
        doc = json.loads(r.stdout)
        for res in doc["results"]:
            (row,) = [x for x in rows if x["property"] == res["property"]
                      and f"{x['target']['x']:g},{x['target']['y']:g}@4" == t]  # fmt: skip
            assert row["verdict"] == res["verdict"]
            want = "inf" if res["optimum"] is None else res["optimum"]
            assert row["optimum"] == want and row["bounds"] == [want, want]
            assert row["witness_value"] == res["constraint_value"]
            steps = res["counterexample"] or []
            hidden = sum(1 for s in steps if s["hidden"])
            assert row["attacked_frames"] == (hidden if res["verdict"] == "violated" else None)
    summary = (out / "campaign.html").read_text()
    assert "hijack" in summary and "lose" in summary


def test_a_model_past_max_states_makes_its_rows_unknown(
    campaign: tuple[Path, Path], tmp_path: Path
) -> None:
    """The same campaign (its perceived scene copied: not perceived again) with
    ``--max-states 1``: every row unknown, exit 3, no traceback."""
    import shutil

    out, spec = campaign
    again = tmp_path / "out"
    shutil.copytree(out / "scenes", again / "scenes")
    targets = out.parent / "targets.txt"
    r = lesmc("campaign", str(out.parent / "v5"), "--out", str(again), "--design", "sort",
              "--spec", str(spec), "--windows", "2..2:2..2", "--targets", str(targets),
              "--workers", "0", "--max-states", "1")  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    rows = [json.loads(line) for line in (again / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 4
    for row in rows:
        jsonschema.validate(row, schema("campaign-row"))
        assert (row["verdict"], row["optimum"], row["stats"]["stopped"]) == (
            "unknown",
            "unknown",
            "max_states",
        )


def test_a_multi_target_campaign_refuses_certified_payoffs(tmp_path: Path) -> None:
    r = lesmc("campaign", "--design", "sort", "--payoffs", "certified", "--out",
              str(tmp_path / "c"))  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "multi-target design is checked on attack payoffs" in r.stderr
    assert not (tmp_path / "c").exists()
