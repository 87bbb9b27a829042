"""The review of round 21's findings in lesmc/replay/ (each test fails on the code before)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from cli_run import ROOT, lesmc

from lesmc.replay.joint_forcing import forcing_costs


def _eq5_by_hand(src: list[int], rank: list[int], payoff: list[float]) -> list[float]:
    """Eq. 5 outcome by outcome: the sum of the payoffs of the same source's strictly
    lower ranks (an independent loop, no cumulative sums)."""
    out = []
    for s, r in zip(src, rank, strict=True):
        lower = [p for s2, r2, p in zip(src, rank, payoff, strict=True) if s2 == s and r2 < r]
        out.append(math.inf if any(math.isinf(p) for p in lower) else math.fsum(lower))
    return out


def _succ(src: list[int], rank: list[int], payoff: list[float]) -> SimpleNamespace:
    return SimpleNamespace(
        src=np.array(src, dtype=np.int64),
        rank=np.array(rank, dtype=np.int64),
        payoff=np.array(payoff, dtype=float),
    )


def test_forcing_costs_with_an_infinite_payoff_is_not_nan() -> None:
    src, rank = [0, 0, 0, 1, 1, 1], [0, 1, 2, 0, 1, 2]
    payoff = [0.3, math.inf, 0.7, 0.2, 0.5, 0.1]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert not np.isnan(got).any()
    assert got.tolist() == [0.0, 0.3, math.inf, 0.0, 0.2, 0.7]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)


def test_forcing_costs_unsorted_ties_and_a_source_without_outcomes() -> None:
    # source 1 has none; source 2's outcomes come out of order; ranks 1 tie (share a sum)
    src, rank = [2, 0, 2, 2, 0, 3], [1, 0, 0, 1, 1, 0]
    payoff = [0.25, 0.5, 0.125, 4.0, math.inf, 1.0]
    got = forcing_costs(_succ(src, rank, payoff))  # type: ignore[arg-type]
    assert got.tolist() == _eq5_by_hand(src, rank, payoff)


def _multi_doc(scene: Path, hidden: list[str]) -> dict[str, object]:
    """A ``lesmc-multi-check`` document of ``sort`` on ``scene`` whose violated result
    hides ``hidden`` at step 1 (frame 1)."""
    steps = [
        {
            "step": k,
            "frame": k,
            "hidden": h,
            "injected": [],
            "target_id": 1,
            "switch": False,
            "reference": None,
            "tracks": [],
            "attacked": [],
        }
        for k, h in ((0, []), (1, hidden))
    ]
    result = {
        "property": "hijack",
        "verdict": "violated",
        "optimum": 1.0,
        "constraint_value": 1,
        "states": 2,
        "transitions": 1,
        "counterexample": steps,
    }
    return {
        "format": "lesmc-multi-check",
        "version": 2,
        "design": "sort",
        "reference": "unattacked",
        "meta": {"scene": str(scene), "window": [1, 2]},
        "results": [result],
    }


def test_a_hidden_id_the_scene_lacks_is_located_at_its_line(tmp_path: Path) -> None:
    """``lesmc replay`` of multi-target results hiding an id the scene lacks: exit 2, no
    traceback, the error at the id's FILE:LINE:COL in the results (review 21, item 2)."""
    odd = tmp_path / "odd.json"
    odd.write_text(
        json.dumps(_multi_doc(ROOT / "examples" / "crossing.json", ["1:0", "1:99"]), indent=1)
    )
    (tmp_path / "frames").mkdir()
    r = lesmc("replay", str(odd), "--frames", str(tmp_path / "frames"), timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = odd.read_text().splitlines()
    line = next(n for n, text in enumerate(lines, 1) if '"1:99"' in text)
    col = lines[line - 1].index('"1:99"') + 1
    assert f"{odd}:{line}:{col}: results[0].counterexample[1].hidden[1]: detection '1:99'" in (
        r.stderr
    ), r.stderr


def _perturbation_problems(record: dict[str, object]) -> list[str]:
    """Where ``record`` breaks the replay schema's ``perturbation`` (empty: it conforms)."""
    from lesmc.schemas import errors, schema

    sch = schema("replay")
    return errors(record, sch["$defs"]["perturbation"], sch)


def test_a_hidden_detection_of_infinite_payoff_is_recorded_as_inf() -> None:
    """The window pipeline's perturbation record (replay/perturbed.py), built by the one
    function all four places call: an infinite recorded payoff is written "inf" (the
    schema's number), not a float JSON cannot hold (review 21, item 3)."""
    from lesmc.perception.cnn import DR_SIZE
    from lesmc.replay.perturbed import perturbation
    from lesmc.results.read import HiddenDoc

    h = HiddenDoc(step=3, frame=7, obs="7:1", x=10.0, y=20.0, payoff=math.inf)
    fd = SimpleNamespace(index=7, positions=np.array([[0.0, 0.0], [10.25, 20.5]]))
    delta = np.full((2, 3, 3), 0.1234567891)
    got = perturbation(h, 1, fd, np.array([10.4, 19.6]), math.inf, False, delta)  # type: ignore[arg-type]
    assert got["payoff"] == "inf" and got["payoff_recomputed"] == "inf"
    assert (got["step"], got["frame"], got["obs"], got["x"], got["y"]) == (3, 7, "7:1", 10.25, 20.5)
    assert got["window_origin"] == [10 - DR_SIZE // 2, 20 - DR_SIZE // 2]
    assert np.array_equal(np.array(got["delta"]), np.full((2, 3, 3), 0.123457))
    assert "action" not in got and got["flipped_alone"] is False
    assert _perturbation_problems(got) == []
    json.dumps(got, allow_nan=False)  # strict JSON


def test_the_perturbation_record_of_an_injected_candidate() -> None:
    from lesmc.replay.case import perturbation_record

    got = perturbation_record(
        (2, 5, "5:c0"),
        (np.float64(1.5), 2),
        np.array([3, 4]),
        (0.5, 0.5),
        True,
        [[[0.0]]],
        inject=True,
    )
    want = {
        "step": 2,
        "frame": 5,
        "obs": "5:c0",
        "x": 1.5,
        "y": 2.0,
        "window_origin": [3, 4],
        "payoff": 0.5,
        "payoff_recomputed": 0.5,
        "flipped_alone": True,
        "action": "inject",
        "delta": [[[0.0]]],
    }
    assert got == want and list(got) == list(want)
    assert all(type(v) is int for v in got["window_origin"])
    assert _perturbation_problems(got) == []


def test_hidden_by_frame_and_group_by_case_serve_both_kinds_of_case() -> None:
    """One grouping of the hidden detections, by frame and then by case, for the single
    cases and the multi-target ones (review 21, item 4)."""
    from lesmc.replay.case import group_by_case, hidden_by_frame
    from lesmc.results.read import HiddenDoc

    def h(frame: int, obs: str) -> HiddenDoc:
        return HiddenDoc(frame - 4, frame, obs, 0.0, 0.0, 1.0)

    a, b, c, d = h(5, "5:0"), h(6, "6:1"), h(5, "5:2"), h(6, "6:0")
    todo = [
        SimpleNamespace(hidden=[a, b]),
        SimpleNamespace(hidden=()),
        SimpleNamespace(hidden=(c, d, h(5, "5:3"))),
    ]
    by_frame = hidden_by_frame(todo)  # type: ignore[arg-type]
    assert by_frame == {5: [(0, a), (2, c), (2, h(5, "5:3"))], 6: [(0, b), (2, d)]}
    assert group_by_case(list(reversed(by_frame[5]))) == [(0, [a]), (2, [h(5, "5:3"), c])]


def _private_imports(path: Path) -> list[str]:
    """The private names ``path`` takes from other modules: ``from M import _x`` and
    ``m._x`` on a name it imported."""
    import ast

    tree = ast.parse(path.read_text())
    imported, found = set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom | ast.Import):
            for alias in node.names:
                name = alias.asname or alias.name.split(".")[0]
                imported.add(name)
                if alias.name.rsplit(".", 1)[-1].startswith("_") and alias.name != "__future__":
                    found.append(f"{path.name}:{node.lineno}: {alias.name}")
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in imported
            and node.attr.startswith("_")
            and not node.attr.startswith("__")
        ):
            found.append(f"{path.name}:{node.lineno}: {node.value.id}.{node.attr}")
    return found


def test_no_private_name_crosses_a_module_in_replay() -> None:
    """lesmc/replay/ uses the other modules' public functions only (review 21, item 5)."""
    files = sorted((ROOT / "lesmc" / "replay").glob("*.py"))
    assert len(files) > 5
    assert [p for f in files for p in _private_imports(f)] == []


def test_private_imports_are_found() -> None:
    """The scan above finds both forms (it can fail)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "m.py"
        f.write_text(
            "from lesmc.replay.run import Outcome, _x\n"
            "import lesmc.engines.multi as em\nem._combine\n"
        )
        assert _private_imports(f) == ["m.py:1: _x", "m.py:3: em._combine"]


def test_replay_help_says_a_multi_target_document_refuses_a_detector_file() -> None:
    """``lesmc replay --help`` no longer promises a detector file's network for every
    results document (review 21, item 6)."""
    r = lesmc("replay", "--help", timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    text = " ".join(r.stdout.split())
    assert "--detector FILE.toml is refused for them" in text
    # round 22: a multi-target injection is replayed, with the recorded front end
    assert "an injected candidate's N_dr window is perturbed until N_dr accepts it" in text
    assert "the settings the results' perception records" in text


def test_one_function_gives_the_replays_front_end_settings() -> None:
    """The point designs' replay and the multi-target one (its recorded settings, else
    the defaults) take their front end from one function (review 21, item 7)."""
    from lesmc.perception import HISTORY
    from lesmc.perception.blobs import BlobConfig
    from lesmc.replay.run import frontend_settings

    fe = frontend_settings(7, 20)
    assert (fe.history, fe.blobs.delta_bc) == (7, 20)
    fe = frontend_settings()
    assert (fe.history, fe.blobs) == (HISTORY, BlobConfig())
    assert "single.recorded_frontend(" in (ROOT / "lesmc" / "replay" / "multi.py").read_text()
