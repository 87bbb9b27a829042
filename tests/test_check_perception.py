"""``lesmc check SCENE SPEC --report DIR`` records the scene's perception (task checkperc).

``lesmc replay`` reruns the front end and the attack with the settings the results'
``perception`` records (lesmc.replay.run.recorded_frontend); ``lesmc verify`` recorded
them, ``check --report`` did not, so a check's results of a scene perceived with
``--history 6 --delta-bc 20`` replayed with the defaults (4 and 12). Now both record the
scene-derived part with one function (lesmc.perception.attack_settings.scene_perception):

1. a scene whose meta records ``frontend`` and ``attack`` settings: results.json's
   ``perception`` has those values (the attack's others at the documented defaults), the
   results' schema accepts it, and ``recorded_frontend`` returns them, both recorded;
2. a scene with neither: the check runs as before and records no front-end setting (the
   replay then says it uses the defaults);
3. a bad ``meta.frontend`` is refused at its line (exit 2) before anything is written;
4. one function: verify's ``perception_facts`` and the check both call it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "merge.json"
SPEC = ROOT / "examples" / "merge.spec"

#: The attack's defaults as docs/cnn.md "Attack settings" lists them (not read from the code).
DEFAULT_ATTACK = {
    "method": "deepfool",
    "overshoot": 0.02,
    "max_iter": 50,
    "norm": "l2",
    "converged": 1e-6,
    "pgd_steps": 25,
    "bisections": 12,
    "eps_start": 0.25,
    "eps_max": 32.0,
    "batch": 128,
}


def _scene(tmp: Path, name: str, **meta: Any) -> Path:
    """examples/merge.json with ``meta`` added, a line per key."""
    data = json.loads(SCENE.read_text())
    data["meta"].update(meta)
    path = tmp / name
    path.write_text(json.dumps(data, indent=1))
    return path


def _check_report(scene: Path, out: Path) -> dict[str, Any]:
    """``lesmc check SCENE merge.spec --report OUT``: its results document, validated."""
    from lesmc.results.load import load_results

    r = lesmc("check", str(scene), str(SPEC), "--report", str(out), timeout=120)
    assert r.returncode in (0, 1), r.stdout + r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    return load_results(str(out / "results.json"))  # the schema accepts it


@pytest.fixture(scope="module")
def perceived(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The check's results of a scene perceived with history 6, delta_bc 20 and a PGD
    attack of 30 iterations (as ``lesmc perceive -o`` records them in its meta)."""
    tmp = tmp_path_factory.mktemp("checkperc")
    scene = _scene(
        tmp,
        "s.json",
        frontend={"history": 6, "delta_bc": 20},
        attack={"method": "pgd", "max_iter": 30},
    )
    return _check_report(scene, tmp / "out")


def test_the_reports_results_record_the_scenes_front_end_and_attack(
    perceived: dict[str, Any],
) -> None:
    p = perceived["perception"]
    assert (p["history"], p["delta_bc"]) == (6, 20)
    assert p["attack"] == {**DEFAULT_ATTACK, "method": "pgd", "max_iter": 30}


def test_the_replay_reads_the_scenes_settings_as_recorded(perceived: dict[str, Any]) -> None:
    from lesmc.replay.run import recorded_frontend
    from lesmc.results.read import results_of

    for perception in (perceived["perception"], results_of(perceived).perception):
        fe, recorded = recorded_frontend(perception)
        assert (fe.history, fe.blobs.delta_bc) == (6, 20)
        assert set(recorded) == {"history", "delta_bc"}
    assert results_of(perceived).perception.attack["method"] == "pgd"


def test_a_scene_without_front_end_settings_records_none(tmp_path: Path) -> None:
    from lesmc.replay.run import recorded_frontend

    doc = _check_report(SCENE, tmp_path / "out")
    p = doc["perception"]
    assert "history" not in p and "delta_bc" not in p, p
    assert p["attack"] == DEFAULT_ATTACK
    assert recorded_frontend(p)[1] == ()  # the replay says it used the defaults


def test_a_bad_front_end_setting_is_refused_at_its_line(tmp_path: Path) -> None:
    scene = _scene(tmp_path, "bad.json", frontend={"history": 6, "delta_bc": 300})
    lines = scene.read_text().splitlines()
    line = next(i for i, t in enumerate(lines) if t.strip().startswith('"delta_bc"')) + 1
    out = tmp_path / "out"
    r = lesmc("check", str(scene), str(SPEC), "--report", str(out), timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stdout + r.stderr
    assert f"{scene}:{line}:" in r.stderr and "meta.frontend.delta_bc" in r.stderr, r.stderr
    assert not out.exists()


def test_one_function_gives_the_scenes_part_of_both_perceptions() -> None:
    texts = {
        p: (ROOT / "lesmc" / p).read_text()
        for p in ("experiment/verify_results.py", "cli/check.py")
    }
    for path, text in texts.items():
        assert "scene_perception(" in text, path
        assert "frontend_of(" not in text and "attack_of(" not in text, path
