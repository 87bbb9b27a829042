"""The output contract (issue 13) and the budgets' remaining cases (issue 15), end to end.

Every verb's ``--json`` prints one document on stdout that validates against its
shipped schema (with the ``jsonschema`` package and with lesmc's own validator);
options that would be ignored are errors; budgets stop every engine and stage.
All through the real entry point (``python -m lesmc``), on tiny inputs.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from test_cli import ROOT, TINY, lesmc

from lesmc.schemas import SCHEMAS, schema, validate

SCENES = ROOT / "tests" / "scenes"


def document(r: subprocess.CompletedProcess[str], fmt: str) -> dict[str, Any]:
    """stdout is exactly one JSON document of format ``fmt``, valid per its schema."""
    assert "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)  # the whole of stdout: nothing else was printed there
    assert doc["format"] == fmt and isinstance(doc["version"], int)
    jsonschema.validate(doc, schema(SCHEMAS[fmt]))
    validate(doc, SCHEMAS[fmt])  # the built-in validator agrees
    return doc


def refused(r: subprocess.CompletedProcess[str], *words: str) -> None:
    """Exit 2 with the reason on stderr; on stdout nothing, or with --json the same reason
    as a lesmc-error document."""
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert no_result_on_stdout(r, "--json" in r.args)
    for w in words:
        assert w in r.stderr, r.stderr


def no_result_on_stdout(r: subprocess.CompletedProcess[str], as_json: bool) -> bool:
    """Nothing on stdout; with --json only the error document (format lesmc-error)."""
    if not as_json:
        return r.stdout == ""
    doc = json.loads(r.stdout)
    jsonschema.validate(doc, schema("error"))
    return bool(doc["exit"] == r.returncode and doc["error"]["message"] in r.stderr)


def test_every_verb_has_json() -> None:
    """A verb added without --json fails here."""
    import click

    from lesmc.cli.main import cli

    def leaves(cmd: click.Command, name: str) -> list[tuple[str, click.Command]]:
        if isinstance(cmd, click.Group):
            return [x for n, c in cmd.commands.items() for x in leaves(c, f"{name} {n}")]
        return [(name, cmd)]

    verbs = leaves(cli, "lesmc")
    assert len(verbs) >= 10
    for name, cmd in verbs:
        assert "--json" in [o for p in cmd.params for o in getattr(p, "opts", [])], name


def test_shipped_schemas_are_valid_json_schemas() -> None:
    for name in sorted(set(SCHEMAS.values())):
        jsonschema.Draft202012Validator.check_schema(schema(name))
        assert schema(name)["properties"]["format"]["const"] in SCHEMAS


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("video") / "v"
    r = lesmc("synth", str(out), "--frames", "6", "--size", "256x256", "--density", "3", "--json")
    assert r.returncode == 0, r.stderr
    return out, document(r, "lesmc-synth")


def test_synth_json_describes_the_files_written(video: tuple[Path, dict[str, Any]]) -> None:
    out, doc = video
    files = sorted(p for p in out.iterdir() if p.name != "truth.json")
    assert [Path(f["path"]).name for f in doc["frames"]] == [p.name for p in files]
    assert all(f["bytes"] == Path(f["path"]).stat().st_size for f in doc["frames"])
    truth = json.loads((out / "truth.json").read_text())
    ids = {v["id"] for f in truth["frames"] for v in f["vehicles"]}
    assert doc["vehicles"] == len(ids) > 0
    assert (doc["width"], doc["height"], doc["seed"], doc["bit_depth"]) == (256, 256, 1, 8)
    assert doc["provenance"]["seeds"] == {"video": 1}


def test_perceive_json_with_and_without_a_scene(
    video: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    out, _ = video
    truth = str(out / "truth.json")
    doc = document(lesmc("perceive", str(out), "--truth", truth, "--json"), "lesmc-perceive")
    assert doc["scene"] is None and len(doc["frames"]) == 6 - 4  # history 4: frames 4, 5
    total = doc["overall"]["detector"]
    assert total["tp"] == sum(f["detector"]["tp"] for f in doc["frames"])
    scene = tmp_path / "scene.json"
    r = lesmc("perceive", str(out), "-o", str(scene), "--max-iter", "2", "--json")
    doc = document(r, "lesmc-perceive")
    assert "overall" not in doc and "wrote" in r.stderr  # the human line went to stderr
    written = json.loads(scene.read_text())
    n = sum(len(f["detections"]) for f in written["frames"])
    assert doc["scene"]["detections"] == n and doc["scene"]["bytes"] == scene.stat().st_size
    assert doc["scene"]["target"] is None and doc["scene"]["steps"] == [4, 5]


def test_train_json_on_the_smallest_run(tmp_path: Path) -> None:
    """The smallest training the CLI allows that has samples of both classes (1 video of
    6 frames, 256x256, 1 epoch): a few seconds; the metrics are not the point here."""
    nets = tmp_path / "nets"
    r = lesmc(
        "train",
        "--out",
        str(nets),
        "--frames",
        "6",
        "--size",
        "256x256",
        "--videos",
        "1",
        "--epochs",
        "1",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    doc = document(r, "lesmc-train")
    for f in doc["files"]:
        data = Path(f["path"]).read_bytes()
        assert f["sha256"] == hashlib.sha256(data).hexdigest() and f["bytes"] == len(data)
    assert {Path(f["path"]).name for f in doc["files"]} == {
        "dr.safetensors",
        "lp.safetensors",
        "nets.json",
    }
    assert doc["provenance"]["seeds"] == {"training": 0, "train_videos": [101], "validation": 102}
    assert doc["validation"]["dr"]["samples"] > 0 and doc["settings"]["epochs_dr"] == 1


@pytest.mark.parametrize("size", ["64x64", "128x128"])
def test_train_on_videos_too_small_is_a_clear_error(size: str, tmp_path: Path) -> None:
    """64x64 frames cannot be registered; 128x128 ones give no vehicle window."""
    args = ["--frames", "6", "--size", size, "--videos", "1", "--epochs", "1"]
    r = lesmc("train", "--out", str(tmp_path / "n"), *args)
    refused(r, "--size")
    assert not (tmp_path / "n").exists()


def test_build_json_counts_what_the_file_holds(tmp_path: Path) -> None:
    from lesmc.model.lts_format import load_lts
    from lesmc.results.document import model_hash

    model = tmp_path / "m.lts"
    r = lesmc("build", str(SCENES / "rq4_merge.json"), "--window", "2..6", "-o", str(model))
    assert r.returncode == 0 and "wrote" in r.stdout  # without --json: the human line
    again = tmp_path / "again.lts"
    r = lesmc(
        "build", str(SCENES / "rq4_merge.json"), "--window", "2..6", "-o", str(again), "--json"
    )
    doc = document(r, "lesmc-build")
    raw = json.loads(again.read_text())
    assert doc["states"] == len(raw["states"]) and doc["transitions"] == len(raw["transitions"])
    assert doc["model"] == {"path": str(again), "bytes": again.stat().st_size}
    assert doc["model_sha256"] == model_hash(load_lts(model))  # as results files do
    assert doc["window"] == [2, 6] and doc["design"] == "single"


def test_reduce_json_and_files_that_would_overwrite_each_other(tmp_path: Path) -> None:
    items = tmp_path / "items.csv"
    items.write_text("cost,capacity\n3,4\n2,3\n5,1\n")
    k = tmp_path / "k.lts"
    r = lesmc("reduce", "knapsack", str(items), "--demand", "5", "-o", str(k), "--json")
    doc = document(r, "lesmc-reduce")
    assert doc["items"] == 3 and doc["spec"]["path"] == str(tmp_path / "k.spec")
    assert doc["states"] == len(json.loads(k.read_text())["states"])
    for args in (["-o", str(tmp_path / "x.lts"), "--spec", str(tmp_path / "x.lts")],
                 ["-o", str(tmp_path / "y.spec")],
                 ["-o", str(items)]):  # fmt: skip
        r = lesmc("reduce", "knapsack", str(items), "--demand", "5", *args)
        refused(r, "name the same file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["items.csv", "k.lts", "k.spec"]
    assert items.read_text() == "cost,capacity\n3,4\n2,3\n5,1\n"


# ------------------------------------------------------------- ignored options are errors


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--max-iter", "3"], ["--max-iter", "-o"]),
        (["--attack", "pgd"], ["--attack", "-o"]),
        (["--dt", "0.5"], ["--dt", "-o"]),
        (["--payoff-norm", "per-pixel"], ["--payoff-norm"]),
        (["--overshoot", "0.1"], ["--overshoot"]),
        (["--radius", "3"], ["--radius", "--truth"]),
        (["--min-speed", "2"], ["--min-speed", "--truth"]),
        (["--no-cnn", "--nets", "."], ["--nets", "--no-cnn"]),
        (["--certify"], ["--certify", "-o"]),
    ],
)
def test_perceive_refuses_options_it_would_ignore(
    args: list[str], words: list[str], tmp_path: Path
) -> None:
    refused(lesmc("perceive", str(tmp_path), *args), *words)


def test_check_refuses_no_paths_with_json() -> None:
    r = lesmc(
        "check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--json", "--no-paths"
    )
    refused(r, "--no-paths")


def test_verify_refuses_a_truth_for_the_default_video(tmp_path: Path) -> None:
    r = lesmc("verify", "--out", str(tmp_path / "o"), "--truth", str(tmp_path / "t.json"))
    refused(r, "--truth")
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------ budgets


def test_enumerate_on_a_scene_answers_unknown_with_bounds() -> None:
    scene, spec = str(SCENES / "rq4_merge.json"), str(SCENES / "rq4_merge.spec")
    exact = document(lesmc("check", scene, spec, "--json"), "lesmc-check")["results"]
    r = lesmc("check", scene, spec, "--engine", "enumerate", "--max-states", "50", "--json")
    assert r.returncode == 3, r.stderr
    stopped = document(r, "lesmc-check")["results"]
    for got, want in zip(stopped, exact, strict=True):
        assert got["verdict"] == "unknown" and got["optimum"] == "unknown"
        assert got["stats"]["stopped"] == "max_states" and got["stats"]["engine"] == "enumerate"
        lo, hi = got["bounds"]["lower"], got["bounds"]["upper"]
        assert lo <= want["optimum"] and (hi == "inf" or want["optimum"] <= hi)
    # unbudgeted, enumerate on the scene agrees with the default engine
    full = lesmc("check", scene, spec, "--engine", "enumerate", "--json")
    for got, want in zip(document(full, "lesmc-check")["results"], exact, strict=True):
        assert got["verdict"] == want["verdict"]
        assert got["optimum"] == pytest.approx(want["optimum"])
        assert got["witness_value"] == pytest.approx(want["witness_value"])


@pytest.mark.parametrize("engine", ["enumerate", "bnb", "levels"])
def test_a_spent_deadline_stops_every_engine_on_a_scene(engine: str) -> None:
    """--timeout 1e-9 is spent before any work: exit 3, every verdict unknown (or, if the
    deadline's alarm came first while loading, a lesmc-error document that says so)."""
    scene, spec = str(SCENES / "rq4_merge.json"), str(SCENES / "rq4_merge.spec")
    r = lesmc("check", scene, spec, "--engine", engine, "--timeout", "1e-9", "--json")
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr
    if json.loads(r.stdout)["format"] == "lesmc-check":
        results = document(r, "lesmc-check")["results"]
        assert {x["verdict"] for x in results} == {"unknown"}
        assert {x["stats"]["stopped"] for x in results} == {"timeout"}
    else:  # the hard alarm came first while loading (a loaded machine): an error document
        error = document(r, "lesmc-error")
        assert error["exit"] == 3 and "--timeout ran out" in error["error"]["message"]
        assert "--timeout ran out" in r.stderr


def _stopped_at(stderr: str) -> int:
    m = re.search(r"ran out while unfolding \((\d+) states", stderr)
    assert m, stderr
    return int(m.group(1))


def test_build_max_states_stops_within_one_state_of_the_limit(tmp_path: Path) -> None:
    scene = str(SCENES / "rq4_merge.json")
    full = tmp_path / "full.lts"
    r = lesmc("build", scene, "--window", "2..8", "-o", str(full), "--json")
    doc = document(r, "lesmc-build")
    raw = json.loads(full.read_text())
    fanout = max(Counter(t["src"] for t in raw["transitions"]).values())
    out = tmp_path / "m.lts"
    for limit in (100, 1000, doc["states"] - 1):
        r = lesmc("build", scene, "--window", "2..8", "-o", str(out), "--max-states", str(limit))
        assert r.returncode == 3 and not out.exists(), r.stderr
        assert limit < _stopped_at(r.stderr) <= limit + fanout
    r = lesmc(
        "build", scene, "--window", "2..8", "-o", str(out), "--max-states", str(doc["states"])
    )
    assert r.returncode == 0 and out.read_bytes() == full.read_bytes()


def test_build_with_a_spent_deadline_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "m.lts"
    r = lesmc(
        "build", str(SCENES / "rq4_merge.json"), "--window", "2..6", "-o", str(out),
        "--timeout", "1e-9", "--json",
    )  # fmt: skip
    assert r.returncode == 3 and "nothing was written" in r.stderr
    assert no_result_on_stdout(r, "--json" in r.args)
    assert list(tmp_path.iterdir()) == []


def test_verify_with_a_spent_deadline_stops_before_any_work(tmp_path: Path) -> None:
    """The deadline passes while torch is imported (under the watchdog): exit 3, no
    directory created, nothing on stdout."""
    out = tmp_path / "o"
    r = lesmc("verify", "--out", str(out), "--timeout", "1e-9", "--json")
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr
    assert no_result_on_stdout(r, "--json" in r.args)
    assert "--timeout" in r.stderr and "nothing was written" in r.stderr
    assert not out.exists()


_STUCK = """
import time
from lesmc.cli.signals import native_deadline
with native_deadline(time.monotonic() + 0.2):
    sum(range(10**12))  # one C call holding the interpreter for many minutes
print("finished")
"""


def test_the_watchdog_stops_a_command_stuck_in_one_c_call() -> None:
    """No Python signal handler can run inside ``sum`` over a range; the watchdog's SIGQUIT
    reaches libc's _exit directly: exit 3 with the message. Without it this would hang
    (the subprocess timeout would fail the test)."""
    r = subprocess.run(
        [sys.executable, "-c", _STUCK],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode == 3 and "finished" not in r.stdout
    assert "--timeout ran out" in r.stderr and "Traceback" not in r.stderr


def test_the_watchdog_leaves_a_finished_block_alone() -> None:
    code = (
        "import signal, time\n"
        "from lesmc.cli.signals import native_deadline\n"
        "with native_deadline(time.monotonic() + 60):\n"
        "    x = sum(range(1000))\n"
        "assert signal.getsignal(signal.SIGQUIT) == signal.SIG_DFL\n"
        "print('finished', x)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert r.returncode == 0 and r.stdout == "finished 499500\n", r.stderr


def test_schemas_describe_the_result_record_field_for_field() -> None:
    """The check and results schemas describe one record (CheckResult.to_json): the same
    result and path definitions, with every field the record writes and nothing else."""
    from lesmc.engines.check import check
    from lesmc.language.parser import load_spec
    from lesmc.model.lts_format import load_lts
    from lesmc.schemas import schema

    tiny = ROOT / "tests" / "golden" / "tiny"
    results = check(load_lts(tiny / "model.lts"), [load_spec(tiny / "properties.spec")])
    check_defs, results_defs = schema("check")["$defs"], schema("results")["$defs"]
    assert check_defs["path"] == results_defs["path"]
    assert set(check_defs["result"]["properties"]) == set(results_defs["result"]["properties"])
    written = set().union(*(r.to_dict() for r in results))
    required = set(check_defs["result"]["required"])
    assert required <= written <= set(check_defs["result"]["properties"])
    paths = [r.counterexample.to_json() for r in results if r.counterexample is not None]
    assert set(paths[0]) == set(check_defs["path"]["properties"])
