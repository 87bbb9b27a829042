"""Every JSON format and option, mutated structurally: a located exit 2 or a working run.

Hypothesis replaces, deletes and adds fields of valid scenes, .lts models,
truth.json and nets.json documents (wrong types, extreme but finite numbers,
escape sequences, markup) and checks that the loaders raise only LesmcErrors;
an accepted scene must track to a finite state. Then one explicit test per case
of issue 15 (extreme numbers, strict types, options), and a check through the
real entry point that no input makes the CLI exit with a traceback.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import lesmc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lesmc.cli.main import main
from lesmc.cli.options import parse_window
from lesmc.common.errors import InputError, LesmcError, UsageError
from lesmc.model.lts_format import lts_from_dict
from lesmc.perception.cnn import nets_settings
from lesmc.perception.quality import load_truth
from lesmc.scene import scene_from_dict
from lesmc.tracking.monitor import track
from lesmc.tracking.targets import parse_target
from lesmc.tracking.trackers import make_tracker
from lesmc.video.reader import open_frames

ROOT = Path(__file__).resolve().parents[1]
SCENE = json.loads((ROOT / "tests" / "scenes" / "rq1_platoon.json").read_text())
SPEC = ROOT / "tests" / "scenes" / "rq1_platoon.spec"
LTS = json.loads((ROOT / "tests" / "golden" / "tiny" / "model.lts").read_text())
NETS = json.loads((ROOT / "lesmc" / "perception" / "weights" / "wami" / "nets.json").read_text())
TRUTH: dict[str, Any] = {
    "format": "lesmc-truth",
    "dt": 0.8,
    "frames": [
        {
            "step": k,
            "file": f"frame_{k:02d}.png",
            "vehicles": [
                {"id": 1, "x": 10.0 + k, "y": 20.0, "vx": 1.0, "vy": 0.0, "speed_mps": 3.0},
                {"id": 2, "x": 50.0, "y": 60.0 + k, "occluded": True, "speed_mps": 0.0},
            ],
        }
        for k in range(3)
    ],
}

#: Values a mutation puts somewhere: wrong types, extreme but finite numbers, hostile text.
ODD_VALUES = st.sampled_from(
    [
        None,
        True,
        False,
        0,
        -1,
        1,
        2**63 - 1,
        -(2**63),
        1e308,
        -1e308,
        5e-324,
        1e200,
        1e150,
        1e-300,
        0.5,
        "",
        "no",
        "unattackable",
        "\x1b[31mred\x1b]0;title\x07",
        "[/]",
        "[bold]x",
        [],
        {},
        [1, 2],
        [[1e308, 0, 0], [0, 1, 0], [0, 0, 1]],
        {"a": 1},
    ]
)


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:4]):  # the first items are enough
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw: st.DrawFn, base: Any) -> Any:
    """``base`` with one to three fields replaced, deleted or added."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = copy.deepcopy(draw(ODD_VALUES))
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["extra", "x", "id", "meta"]))] = copy.deepcopy(
                draw(ODD_VALUES)
            )
        else:
            parent.append(copy.deepcopy(draw(ODD_VALUES)))
    return doc


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(mutated(SCENE))
def test_mutated_scenes_are_refused_or_track_finitely(doc: Any) -> None:
    try:
        scene = scene_from_dict(doc, "s.json")
    except InputError as err:
        assert err.render().startswith("s.json")
        return
    for p in track(make_tracker(scene), min(4, scene.last_step - scene.target.step)):
        assert np.isfinite(p.x).all()


@FUZZ
@given(mutated(LTS))
def test_mutated_models_raise_only_model_errors(doc: Any) -> None:
    with contextlib.suppress(LesmcError):
        lts_from_dict(doc, "m.lts")


@FUZZ
@given(mutated(NETS))
def test_mutated_nets_json_raises_only_input_errors(doc: Any) -> None:
    with contextlib.suppress(InputError):
        s = nets_settings(doc, "nets.json")
        assert 1 <= s.m <= 16 and 0 <= s.delta_dr <= 1 and 0 <= s.delta_lp <= 1


@FUZZ
@given(mutated(TRUTH))
def test_mutated_truth_raises_only_input_errors(doc: Any) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "truth.json"
        path.write_text(json.dumps(doc))
        try:
            truth = load_truth(str(path))
        except InputError:
            return
    for tf in truth.frames.values():
        assert tf.occluded.dtype == bool and np.isfinite(tf.positions).all()


# --- explicit cases of issue 15 ------------------------------------------------------------


def _scene_with(change: Any) -> dict[str, Any]:
    doc = copy.deepcopy(SCENE)
    change(doc)
    return doc


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.setdefault("tracker", {}).update(sigma_q=1e200), "tracker: sigma_q must be"),
        (lambda d: d.update(dt=1e150), "dt: must be a number of seconds in (0, 3600]"),
        (lambda d: d.setdefault("tracker", {}).update(P0_sd=[1e200, 1, 1, 1]), "P0_sd must be"),
        (lambda d: d["frames"][1]["detections"][0].update(x=1e302), "detection '1:t': x must be"),
        (
            lambda d: d["frames"][0].update(to_next=[[1e308, 0, 0], [0, 1, 0], [0, 0, 1]]),
            "frame 0: to_next must be an invertible 3x3 matrix",
        ),
        (
            lambda d: d["frames"][0].update(to_next=[[1, 0, 0], [0, 1, 0], [-0.01, 0, 1]]),
            "to_next sends detection '0:t' to infinity",
        ),
        (lambda d: d["target"].update(velocity=[1e7, 0]), "target: velocity must be"),
        (lambda d: d["frames"][2]["detections"][0].update(payoff=1e13), "payoff must be"),
        (lambda d: d["target"].update(step=10**7), "target: step must be an integer in"),
        (
            lambda d: d.update(meta={"attack": {"max_iter": 10**12}}),
            "meta.attack.max_iter: must be an integer in 1..10000, got 1000000000000",
        ),
        (
            lambda d: d.update(meta={"attack": {"overshoot": -0.5, "method": "fgsm"}}),
            "meta.attack.overshoot: must be a number in [0, 1], got -0.5",
        ),
        (
            lambda d: d.update(meta={"attack": {"method": "fgsm"}}),
            'meta.attack.method: must be "deepfool" or "pgd", got \'fgsm\'',
        ),
        (
            lambda d: d.update(meta={"attack": {"converged": 1.0}}),
            "meta.attack.converged: must be a number in [0, 1), got 1.0",
        ),
    ],
)
def test_extreme_scene_numbers_are_located_errors(change: Any, message: str) -> None:
    with pytest.raises(InputError) as info:
        scene_from_dict(_scene_with(change), "s.json")
    assert message in info.value.render()


def test_the_largest_allowed_scene_numbers_track_finitely() -> None:
    def largest(d: dict[str, Any]) -> None:
        d["dt"] = 3600.0
        d["tracker"] = {"sigma_q": 1e6, "sigma_r": 1e6, "P0_sd": [1e6] * 4, "max_trace": 1e30}
        d["target"]["velocity"] = [1e6, -1e6]
        for fr in d["frames"]:
            for det in fr["detections"]:
                det["x"], det["payoff"] = 1e7, 1e12

    scene = scene_from_dict(_scene_with(largest), "s.json")
    for p in track(make_tracker(scene)):
        assert np.isfinite(p.x).all() and math.isfinite(p.tau)


def _truth_with(tmp_path: Path, change: Any) -> str:
    doc = copy.deepcopy(TRUTH)
    change(doc)
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(doc))
    return str(path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda d: d["frames"][0]["vehicles"][0].update(occluded="no"),
            "frame 'frame_00.png', vehicles[0]: occluded must be true or false, got 'no'",
        ),
        (lambda d: d["frames"][1]["vehicles"][1].update(x="12"), "vehicles[1]: x must be"),
        (lambda d: d["frames"][0]["vehicles"][0].update(id=True), "id must be an integer"),
        (lambda d: d.update(dt=1e150), "dt: must be a number of seconds"),
        (lambda d: d["frames"].append({"file": 3, "vehicles": []}), "file must be a non-empty"),
    ],
)
def test_truth_types_are_strict(tmp_path: Path, change: Any, message: str) -> None:
    with pytest.raises(InputError) as info:
        load_truth(_truth_with(tmp_path, change))
    assert message in info.value.render()


def test_truth_dt_beyond_float_range_is_refused_when_read(tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(TRUTH).replace('"dt": 0.8', '"dt": 1e400'))
    with pytest.raises(InputError) as info:
        load_truth(str(path))
    assert "1e400 is out of range" in info.value.render()
    assert info.value.render().startswith(f"{path}:1:")


@pytest.mark.parametrize("fmt", ["pickle", "lesmc-nets-pickle", None, 1])
def test_nets_json_must_name_the_safetensors_format(fmt: Any) -> None:
    with pytest.raises(InputError) as info:
        nets_settings({**NETS, "format": fmt}, "nets.json")
    assert 'format: must be "lesmc-nets"' in info.value.render()


@pytest.mark.parametrize(
    "text", ["٦..٨", "6..８", "6.." + "9" * 5000, "6..1000001", "x..y", "8..6", "6 .. \x1b[2J"]
)
def test_bad_windows_are_usage_errors(text: str) -> None:
    with pytest.raises(UsageError) as info:
        parse_window(text)
    assert "\x1b" not in info.value.render() and len(info.value.render()) < 200


def test_windows_within_limits_parse() -> None:
    assert parse_window(" 6 .. 8 ") == (6, 8)
    assert parse_window("0006..1000000") == (6, 10**6)


@pytest.mark.parametrize("text", ["٦,٨", "1e3,4", "1," + "9" * 5000, "1,2@" + "9" * 5000, "1,2@x"])
def test_bad_targets_are_usage_errors(text: str) -> None:
    with pytest.raises(UsageError):
        parse_target(text)


# --- frames directories ----------------------------------------------------------------------


def _frames(directory: Path, side: int, n: int = 5) -> None:
    directory.mkdir()
    rng = np.random.default_rng(0)
    for i in range(n):
        img = rng.integers(0, 255, (side, side), dtype=np.uint8)
        assert cv2.imwrite(str(directory / f"frame_{i:02d}.png"), img)


def test_tiny_frames_are_refused_with_the_file_named(tmp_path: Path) -> None:
    _frames(tmp_path / "f", 1)
    with pytest.raises(InputError) as info:
        open_frames(tmp_path / "f", 2)
    assert "frame_00.png: frame is 1x1 pixels; frames must be at least 8x8" in str(info.value)


def test_symlinks_leading_out_of_the_frames_directory_are_refused(tmp_path: Path) -> None:
    _frames(tmp_path / "f", 40)
    outside = tmp_path / "secret.png"
    cv2.imwrite(str(outside), np.zeros((40, 40), np.uint8))
    (tmp_path / "f" / "frame_09.png").symlink_to(outside)
    with pytest.raises(InputError) as info:
        open_frames(tmp_path / "f", 2)
    assert "frame_09.png: a symbolic link leading out of the frames directory" in str(info.value)
    (tmp_path / "f" / "frame_09.png").unlink()
    (tmp_path / "f" / "frame_09.png").symlink_to("frame_00.png")  # inside: fine
    assert len(open_frames(tmp_path / "f", 2)) == 6


def test_a_target_outside_the_frames_is_refused_before_perception(tmp_path: Path) -> None:
    _frames(tmp_path / "f", 64)
    code, _, err = run_main(
        ["perceive", str(tmp_path / "f"), "--target", "99999,99999", "-o", str(tmp_path / "s")]
    )
    assert code == 2, err
    assert "--target 99999,99999 is outside the frames" in err
    assert not (tmp_path / "s").exists()


# --- the CLI never exits with a traceback ------------------------------------------------------


def run_main(argv: list[str]) -> tuple[int, str, str]:
    """The console entry point in-process: (status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 0
        else:  # pragma: no cover - main always exits
            code = 0
    return code, out.getvalue(), err.getvalue()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated(SCENE), st.sampled_from(["check", "build", "track"]))
def test_no_mutated_scene_makes_the_cli_crash(doc: Any, verb: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        scene = Path(d) / "scene.json"
        scene.write_text(json.dumps(doc))
        args = {
            "check": ["check", str(scene), str(SPEC), "--no-paths"],
            "build": ["build", str(scene), "--window", "6..8", "-o", str(Path(d) / "m.lts")],
            "track": ["track", str(scene)],
        }[verb]
        code, out, err = run_main(args)
        assert code in (0, 1, 2, 3), err
        assert "Traceback" not in err and "internal error" not in err
        assert "\x1b" not in out + err
        if code == 2:
            assert not (Path(d) / "m.lts").exists()
        assert sorted(os.listdir(d)) in (["scene.json"], ["m.lts", "scene.json"])


def _with_version_true(src: Path, dst: Path) -> Path:
    doc = json.loads(src.read_text())
    doc["version"] = True
    dst.write_text(json.dumps(doc))
    return dst


@pytest.mark.parametrize("kind", ["truth", "nets", "results", "lts", "scene"])
def test_a_boolean_version_is_refused_in_every_input(tmp_path: Path, kind: str) -> None:
    """Issue 33: JSON's ``true`` is not the version 1 (Python's True == 1 is no excuse):
    every input file says so with the same located message, exit 2."""
    import shutil

    from lesmc.perception.cnn import DEFAULT_WEIGHTS

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(6):
        cv2.imwrite(str(frames / f"f{i}.png"), np.full((64, 64), 100 + i, dtype=np.uint8))
    tiny = ROOT / "tests" / "golden" / "tiny"
    if kind == "truth":
        truth = tmp_path / "truth.json"
        truth.write_text(json.dumps({"format": "lesmc-truth", "version": True, "frames": [
            {"file": f"f{i}.png", "vehicles": []} for i in range(6)]}))  # fmt: skip
        args, bad, want = ["perceive", str(frames), "--truth", str(truth), "--no-cnn"], truth, 1
    elif kind == "nets":
        nets = tmp_path / "nets"
        shutil.copytree(ROOT / "lesmc" / "perception" / "weights" / DEFAULT_WEIGHTS, nets)
        bad = _with_version_true(nets / "nets.json", nets / "nets.json")
        args, want = ["perceive", str(frames), "--nets", str(nets)], 1
    elif kind == "results":
        res = tmp_path / "res"
        r = lesmc("check", str(tiny / "model.lts"), str(tiny / "properties.spec"),
                  "--report", str(res))  # fmt: skip
        assert r.returncode in (0, 1), r.stderr
        bad = _with_version_true(res / "results.json", tmp_path / "results.json")
        args, want = ["report", str(bad), "--out", str(tmp_path / "out")], 2
    elif kind == "lts":
        bad = _with_version_true(tiny / "model.lts", tmp_path / "m.lts")
        args, want = ["check", str(bad), str(tiny / "properties.spec")], 1
    else:
        bad = _with_version_true(ROOT / "examples" / "merge.json", tmp_path / "s.json")
        args, want = ["track", str(bad)], "1, 2 or 3"  # 2 added boxes, 3 candidates
    r = lesmc(*args)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"version: must be {want}, got true" in r.stderr, r.stderr
    assert str(bad) in r.stderr


def test_the_attack_settings_a_scene_may_record_are_what_perceive_accepts() -> None:
    """The scene loader's table (scene.meta_attack.ATTACK_SETTINGS) and ``lesmc perceive``'s options
    allow the same values: each range's ends and the choices, nothing just outside."""
    import click

    from lesmc.cli.perceive import perceive_cmd as perceive
    from lesmc.scene.meta_attack import ATTACK_SETTINGS

    opts = {p.name: p.type for p in perceive.params}
    for key, option in (("method", "attack"), ("norm", "payoff_norm")):
        choice = opts[option]
        assert isinstance(choice, click.Choice)
        ok = ATTACK_SETTINGS[key][0]
        assert all(ok(c) for c in choice.choices) and not ok("other")
    for key, option, step in (("overshoot", "overshoot", 1e-9), ("max_iter", "max_iter", 1)):
        rng = opts[option]
        assert isinstance(rng, click.FloatRange | click.IntRange)
        ok = ATTACK_SETTINGS[key][0]
        assert ok(rng.min) and ok(rng.max)
        assert not ok(rng.min - step) and not ok(rng.max + step)
