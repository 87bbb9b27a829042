"""The recorded front-end settings (review 22, task fixfe).

1. A scene's ``meta.frontend`` out of perceive's ranges (history 3..16, delta_bc 1..255)
   is refused at its line (exit 2) by ``verify --scene``, before any work; a results
   document's ``perception`` out of them is refused by its schema; the ranges are one
   definition (lesmc.perception.FRONTEND_RANGES) that perceive and the schemas share.
2. The point designs and the multi-target ones record a scene's front end in their
   results' ``perception`` alike (one function): nothing for a scene without
   ``meta.frontend``, its values for a scene with it.
3. Both replays read the recorded front end with one function; a document recording
   ``history`` but not ``delta_bc`` replays with the recorded history, says "partly" and
   names only ``delta_bc`` as defaulted; the multi-target replay opens history + 1 frames.
4. The multi-target replay in verify checks the clock at every frame.
5. ``verify FRAMES --detector box.toml --payoffs certified`` is refused before perceiving,
   naming ``--payoffs``.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import lesmc
from multi_video import SPEC

from lesmc.common.errors import InputError
from lesmc.common.progress import Reporter

ROOT = Path(__file__).resolve().parents[1]
POINT_SPEC = """property robustness {
    attack window 2..4
    minimize payoff
    subject to dist.sum(0..end) > 5
    holds if optimum > 3.0
    on x, y
}
"""


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A small scene (examples/crossing.json, its networks named in ``meta.detector``)
    without ``meta.frontend``, pretty-printed (a line per key), and 8 small frames."""
    d = tmp_path_factory.mktemp("fe")
    data = json.loads((ROOT / "examples" / "crossing.json").read_text())
    data["meta"] = {"detector": "the networks of a test"}
    bare = d / "bare.json"
    bare.write_text(json.dumps(data, indent=1))
    (d / "m.spec").write_text(SPEC)
    (d / "p.spec").write_text(POINT_SPEC)
    few = d / "few"
    few.mkdir()
    for k in range(8):
        cv2.imwrite(str(few / f"f{k:02d}.png"), np.full((32, 48), 20 + k, np.uint8))
    return {"dir": d, "bare": bare, "few": few}


def _with_frontend(made: dict[str, Path], name: str, fe: dict[str, Any]) -> Path:
    data = json.loads(made["bare"].read_text())
    data["meta"]["frontend"] = fe
    path = made["dir"] / name
    path.write_text(json.dumps(data, indent=1))
    return path


def _line_of(path: Path, key: str) -> int:
    """The line (from 1) of ``"key":`` inside the file's ``"frontend": {`` object."""
    lines = path.read_text().splitlines()
    start = next(i for i, t in enumerate(lines) if t.strip().startswith('"frontend": {'))
    return next(i for i in range(start, len(lines)) if lines[i].strip().startswith(f'"{key}":')) + 1


def test_the_ranges_are_perceives_and_the_schemas_say_the_same() -> None:
    from lesmc.experiment.perceive import _RANGES
    from lesmc.perception import FRONTEND_RANGES

    assert FRONTEND_RANGES == {"history": (3, 16), "delta_bc": (1, 255)}
    assert {k: _RANGES[k] for k in FRONTEND_RANGES} == FRONTEND_RANGES
    schemas = ROOT / "lesmc" / "schemas"
    objs = [
        json.loads((schemas / "results.json").read_text())["properties"]["perception"],
        json.loads((schemas / "multi-check.json").read_text())["properties"]["perception"],
    ]
    replay = (schemas / "replay.json").read_text()
    objs.append(_find_frontend(json.loads(replay)))
    for obj in objs:
        for key, (lo, hi) in FRONTEND_RANGES.items():
            p = obj["properties"][key]
            assert (p["minimum"], p["maximum"]) == (lo, hi), (key, p)


def _find_frontend(doc: Any) -> Any:
    """The schema object of a replay's ``frontend`` (somewhere in replay.json)."""
    if isinstance(doc, dict):
        if isinstance(doc.get("frontend"), dict) and "from" in doc["frontend"].get(
            "properties", {}
        ):
            return doc["frontend"]
        for v in doc.values():
            got = _find_frontend(v)
            if got is not None:
                return got
    if isinstance(doc, list):
        for v in doc:
            got = _find_frontend(v)
            if got is not None:
                return got
    return None


@pytest.mark.parametrize(
    ("fe", "key", "shown"),
    [({"history": 0, "delta_bc": 12}, "history", "0")],  # the others: frontend_of's test
)
def test_verify_refuses_a_scenes_front_end_out_of_range_at_its_line(
    made: dict[str, Path], fe: dict[str, Any], key: str, shown: str
) -> None:
    bad = _with_frontend(made, f"bad_{key}.json", fe)
    out = made["dir"] / f"out_{key}"
    r = lesmc("verify", "--scene", str(bad), "--spec", str(made["dir"] / "p.spec"), "--out",
              str(out))  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    want = f"{bad}:{_line_of(bad, key)}:"
    assert want in r.stderr and f"meta.frontend.{key}: must be an integer in" in r.stderr, r.stderr
    assert f"got {shown}" in r.stderr
    assert not (out / "results.json").exists()


@pytest.mark.parametrize("value", [0, 2, 17, True, "4", 4.5])
def test_frontend_of_refuses_every_value_out_of_range(tmp_path: Path, value: Any) -> None:
    from lesmc.perception.attack_settings import frontend_of

    path = tmp_path / "s.json"
    meta = {"frontend": {"history": value, "delta_bc": 12}}
    path.write_text(json.dumps({"meta": meta}, indent=1))
    with pytest.raises(InputError) as e:
        frontend_of(meta, str(path))
    assert f"{path}:4:" in e.value.render() and "meta.frontend.history" in e.value.render()
    meta = {"frontend": {"history": 4, "delta_bc": 256 if value in (2, 17) else value}}
    path.write_text(json.dumps({"meta": meta}, indent=1))
    with pytest.raises(InputError) as e:
        frontend_of(meta, str(path))
    assert f"{path}:5:" in e.value.render() and "meta.frontend.delta_bc" in e.value.render()
    assert frontend_of({"frontend": {"history": 3, "delta_bc": 255}}) == {
        "history": 3,
        "delta_bc": 255,
    }


@pytest.fixture(scope="module")
def checked(made: dict[str, Path]) -> Path:
    """``verify --scene bare.json --design sort``: its results."""
    d = made["dir"]
    r = lesmc("verify", "--scene", str(made["bare"]), "--design", "sort", "--spec",
              str(d / "m.spec"), "--out", str(d / "multi"))  # fmt: skip
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stdout + r.stderr
    return d / "multi" / "results.json"


def test_point_and_multi_designs_record_a_scenes_front_end_alike(
    made: dict[str, Path], checked: Path
) -> None:
    """The multi-target results verify wrote, and what the point designs' results document
    records of the same scene (its perception, made in process)."""
    from lesmc.experiment.verify_results import _perception_facts
    from lesmc.scene import load_scene

    multi = json.loads(checked.read_text())["perception"]
    src = SimpleNamespace(
        scene=load_scene(str(made["bare"])), nets=None, frames=None, pricing=None,
        detections=None,
    )  # fmt: skip
    req = SimpleNamespace(scene_path=str(made["bare"]), payoffs="attack", out=made["dir"])
    point = _perception_facts(req, src, SimpleNamespace(certified=None))  # type: ignore[arg-type]
    # the scene records no front end: neither says it does (the point designs said 4/12)
    for p in (point, multi):
        assert "history" not in p and "delta_bc" not in p, p
    assert multi["nets"] == point["nets"] == "the networks of a test"
    assert set(multi) <= set(point), (multi, point)
    assert all(multi[k] == point[k] for k in multi)


def test_one_function_makes_both_perceptions() -> None:
    from lesmc.experiment.verify_results import perception_facts

    src = SimpleNamespace(
        scene=SimpleNamespace(meta={"frontend": {"history": 5, "delta_bc": 20}}),
        nets=None,
        frames=None,
    )
    got = perception_facts(src, "<scene>")  # type: ignore[arg-type]
    assert (got["history"], got["delta_bc"]) == (5, 20)
    text = (ROOT / "lesmc" / "experiment" / "multi_verify.py").read_text()
    assert "def perception_facts" not in text and "perception_facts(src, where)" in text


def test_the_replays_read_the_recorded_front_end_with_one_function() -> None:
    from lesmc.perception import DELTA_BC, HISTORY
    from lesmc.replay.multi import frontend_record, perception_settings
    from lesmc.replay.run import frontend_note, recorded_frontend
    from lesmc.results.read import Perception

    fe, rec = perception_settings({"perception": {"history": 6}})
    assert (fe.history, fe.blobs.delta_bc, rec) == (6, DELTA_BC, ("history",))
    typed = Perception(history=6, delta_bc=None, nets=None, frames=None, attack={})
    fe2, rec2 = recorded_frontend(typed)
    assert (fe2.history, fe2.blobs.delta_bc, rec2) == (6, DELTA_BC, ("history",))
    used = frontend_record(fe, rec)
    assert used["from"] == "partly" and used["recorded"] == ["history"]
    note = frontend_note("r.json", used)
    assert note is not None
    assert "perception.delta_bc" in note and "perception.history" not in note
    assert f"delta_bc {DELTA_BC}" in note and "the recorded (history 6)" in note
    both = frontend_record(*perception_settings({"perception": {"history": 6, "delta_bc": 9}}))
    assert both["from"] == "results" and frontend_note("r.json", both) is None
    none = frontend_record(*perception_settings({}))
    assert none["from"] == "defaults" and (none["history"], none["delta_bc"]) == (HISTORY, 12)
    assert "records no front-end settings" in (frontend_note("r.json", none) or "")


def test_the_multi_replay_opens_the_recorded_history_plus_one_frames(
    made: dict[str, Path], checked: Path
) -> None:
    doc = json.loads(checked.read_text())
    doc["perception"]["history"] = 8
    res = made["dir"] / "multi" / "h8.json"
    res.write_text(json.dumps(doc))
    r = lesmc("replay", str(res), "--frames", str(made["few"]))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stdout + r.stderr
    assert "8 frame(s) found, at least 9 are needed" in r.stderr, r.stderr
    # a document out of range is refused by its schema, at the field
    doc["perception"]["history"] = 2
    res.write_text(json.dumps(doc))
    r = lesmc("replay", str(res), "--frames", str(made["few"]))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "perception.history" in r.stderr, r.stderr


def test_the_multi_replay_in_verify_checks_the_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    from lesmc.common.budget import Budget
    from lesmc.common.errors import BudgetError
    from lesmc.experiment import multi_verify
    from lesmc.replay import multi, multi_cases

    frames_seen: list[int] = []

    def fake_replay(*args: Any) -> Any:
        on_frame = args[7]
        for k in range(3):
            frames_seen.append(k)
            on_frame()
        raise AssertionError("the clock was not checked")

    monkeypatch.setattr(multi_cases, "multi_cases", lambda *a, **k: [SimpleNamespace(result=0)])
    monkeypatch.setattr(multi, "replay_multi", fake_replay)
    monkeypatch.setattr(multi_verify, "bound_properties", lambda *a: [])
    monkeypatch.setattr(multi_verify, "_replay_key", lambda *a: None)
    src = SimpleNamespace(
        frames=[0, 1, 2], nets=object(), net_files=None, cache=None, run=None,
        networks=lambda: None,
    )  # fmt: skip
    spent = Budget(timeout=1e-9, started=0.0)
    with pytest.raises(BudgetError, match="replaying the counterexamples"):
        multi_verify._replay({}, None, "s.json", [], src, Reporter("verify", live=False), spent)  # type: ignore[arg-type]
    assert frames_seen == [0]


def test_verify_refuses_a_detector_files_bounds_before_perceiving(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``verify FRAMES --detector F.toml --payoffs certified|interval`` asks the detector
    file whether it is certifiable, naming ``--payoffs``, before perceiving (the check
    itself, campaign's: tests/test_boxes_lazy.py)."""
    from lesmc.common.errors import UsageError
    from lesmc.experiment import detector_verify
    from lesmc.experiment import experiment as ex
    from lesmc.experiment.verify_request import Request

    calls: list[tuple[str, str]] = []

    def refuse(path: str, option: str) -> None:
        calls.append((path, option))
        raise UsageError("refused")

    def perceive(*args: Any, **kw: Any) -> Any:
        calls.append(("perceived", ""))
        raise AssertionError("perceived before refusing")

    monkeypatch.setattr(detector_verify, "refuse_uncertifiable", refuse)
    monkeypatch.setattr(ex, "file_perception", perceive)
    toml = str(tmp_path / "box.toml")
    for payoffs in ("certified", "interval"):
        req = Request(frames_dir=str(tmp_path), target="10,30@0", nets=(None, toml, None),
                      payoffs=payoffs, out=tmp_path / "o")  # fmt: skip
        with pytest.raises(UsageError, match="refused"):
            ex.perceived(req, [], Reporter("verify", live=False), False, False)
    assert calls == [(toml, "--payoffs certified|interval")] * 2


def test_the_point_designs_replay_notes_the_defaulted_settings(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """``lesmc replay`` of a point design's results that record ``history`` only: the
    note names ``delta_bc`` alone as the default (the multi-target replay's note)."""
    from lesmc.cli import replay as cli
    from lesmc.replay import run
    from lesmc.results.read import Perception

    monkeypatch.setattr(run, "replay_file", lambda *a: run.Outcome({(0, 0): {}}, 0.0))
    doc = SimpleNamespace(
        perception=Perception(history=6, delta_bc=None, nets=None, frames=None, attack={})
    )
    cli._replay(doc, "frames", (None, None, None), None, None, "r.json")  # type: ignore[arg-type]
    err = capfd.readouterr().err
    assert "r.json records no front-end settings (perception.delta_bc)" in err, err
    assert "defaults (delta_bc 12) and the recorded (history 6)" in err, err
    full = Perception(history=6, delta_bc=9, nets=None, frames=None, attack={})
    cli._replay(SimpleNamespace(perception=full), "f", (None,) * 3, None, None, "r.json")  # type: ignore[arg-type]
    assert capfd.readouterr().err == ""
