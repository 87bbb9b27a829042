"""A scene's ``meta.attack`` is checked whole: not an object, or a misspelt setting, is a
located error (exit 2), where it was silently read as "no settings recorded" and the
scene priced and replayed with the default attack; the notes ``lesmc perceive -o`` writes
beside the settings still load."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.cli_run import ROOT, lesmc

SPEC = ROOT / "examples" / "merge.spec"


def _scene(tmp_path: Path, attack: Any) -> Path:
    doc = json.loads((ROOT / "examples" / "merge.json").read_text())
    doc["meta"]["attack"] = attack
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc, indent=1))
    return path


def _line_of(path: Path, text: str) -> int:
    return next(i for i, ln in enumerate(path.read_text().splitlines(), 1) if text in ln)


@pytest.mark.parametrize(
    ("attack", "field", "anchor"),
    [
        ("deepfool", "meta.attack", '"attack"'),
        ([1, 2], "meta.attack", '"attack"'),
        ({"methd": "pgd"}, "meta.attack.methd", '"methd"'),
        ({"method": "pgd", "max_iters": 5}, "meta.attack.max_iters", '"max_iters"'),
    ],
)
def test_a_bad_meta_attack_is_located(tmp_path: Path, attack: Any, field: str, anchor: str) -> None:
    scene = _scene(tmp_path, attack)
    got = lesmc("check", str(scene), str(SPEC))
    assert got.returncode == 2, got.stderr
    assert "Traceback" not in got.stderr
    assert f"{scene}:{_line_of(scene, anchor)}:" in got.stderr
    assert field in got.stderr


def _written_attacks() -> list[dict[str, Any]]:
    """``meta.attack`` as ``lesmc perceive -o`` writes it: the window pipeline's
    (``scene_meta``) and a detector file's (``file_attack_meta``), from the writers."""
    from lesmc.experiment.perceive import PerceiveRequest, file_attack_meta, scene_meta

    req = PerceiveRequest("frames", attack="pgd", max_iter=40)
    window: dict[str, Any] = scene_meta(req, "synthetic")["attack"]
    return [window, file_attack_meta(req, (0.0, 255.0), "the whole frame")]


@pytest.mark.parametrize("which", [0, 1], ids=["window", "detector-file"])
def test_the_notes_perceive_writes_still_load(tmp_path: Path, which: int) -> None:
    """Each field the writers write is a setting or a note the reader knows, and a scene
    with them checks as the example does."""
    from lesmc.scene.meta_attack import ATTACK_NOTES, ATTACK_SETTINGS

    attack = _written_attacks()[which]
    assert set(attack) <= set(ATTACK_SETTINGS) | set(ATTACK_NOTES), attack
    assert set(attack) - set(ATTACK_SETTINGS)  # it does write notes
    scene = _scene(tmp_path, attack)
    got = lesmc("check", str(scene), str(SPEC), "--json")
    plain = lesmc("check", str(ROOT / "examples" / "merge.json"), str(SPEC), "--json")
    assert got.returncode == plain.returncode == 1, got.stderr
    assert _verdicts(got.stdout) == _verdicts(plain.stdout)


def _verdicts(out: str) -> list[tuple[str, str, Any]]:
    return [(r["property"], r["verdict"], r["optimum"]) for r in json.loads(out)["results"]]
