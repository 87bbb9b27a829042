"""Multi-target models as files (issue 58): ``lesmc build --design sort|gnn`` writes a
``lesmc-multi-npz`` model, ``lesmc check MODEL SPEC`` prints what ``lesmc check SCENE SPEC``
prints, ``lesmc export MODEL --format drn|prism`` writes an MDP whose optimum Storm
computes (an independent solver) equal to lesmc's, and a damaged file is a located error."""

from __future__ import annotations

import hashlib
import json
import math
from fractions import Fraction
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from cli_run import lesmc

import lesmc as api
from lesmc.common.errors import LesmcError, ModelError, UsageError
from lesmc.exporters import formats
from lesmc.exporters.request import Request
from lesmc.language.parser import parse_spec
from lesmc.model.lts_format import load_lts
from lesmc.model.multi import MultiModel
from lesmc.schemas import schema

pytest.importorskip("sort_tracker")
from test_multi_attack import _doc, _frames

SPEC = """property hijack {{
  attack window {l}..{u}
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 3
}}
property lose {{
  attack window {l}..{u}
  minimize payoff
  subject to lost(0..end) > 0
  holds if optimum > 2
}}
property fewest {{
  attack window {l}..{u}
  minimize count.frames
  subject to switches(0..end) > 0
  holds if optimum > 1
}}
property hidden {{
  attack window {l}..{u}
  minimize count
  subject to lost({a}..end) >= 2
  holds if optimum > 1
}}
"""


def _case(seed: int, design: str = "sort") -> tuple[dict[str, Any], str]:
    """A random small scene (three objects crossing, 3 to 6 frames) and a spec whose four
    properties share one attack window of at most 3 steps."""
    rng = np.random.default_rng(5900 + seed)
    n = int(rng.integers(3, 7))
    frames = _frames(rng, n)
    pay = [rng.integers(1, 10, len(f)).astype(float) for f in frames]
    doc = _doc(frames, pay)
    doc["tracker"]["design"] = design
    u = int(rng.integers(1, n))
    l = max(1, u - int(rng.integers(0, 3)))
    return doc, SPEC.format(l=l, u=u, a=int(rng.integers(0, n)))


def _write(tmp: Path, doc: dict[str, Any], spec: str) -> tuple[Path, Path]:
    scene, sp = tmp / "scene.json", tmp / "p.spec"
    scene.write_text(json.dumps(doc))
    sp.write_text(spec)
    return scene, sp


def _clean(r: Any) -> None:
    assert "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize(("seed", "design"), [(0, "sort"), (3, "gnn")])
def test_check_of_the_built_model_prints_what_the_scene_check_prints(
    tmp_path: Path, seed: int, design: str
) -> None:
    doc, spec = _case(seed, design)
    scene, sp = _write(tmp_path, doc, spec)
    model = tmp_path / "m.npz"
    r = lesmc(
        "build", str(scene), "--spec", str(sp), "--property", "hijack", "-o", str(model), "--json"
    )
    _clean(r)
    assert r.returncode == 0 and model.exists(), r.stderr
    built = json.loads(r.stdout)
    jsonschema.validate(built, schema("build"))
    assert built["model_sha256"] == hashlib.sha256(model.read_bytes()).hexdigest()
    assert built["design"] == design and built["window"] == list(api.load_model(model).window)
    on_model = lesmc("check", str(model), str(sp), "--json")
    on_scene = lesmc("check", str(scene), str(sp), "--json")
    _clean(on_model)
    assert on_model.returncode == on_scene.returncode in (0, 1), on_model.stderr
    assert json.loads(on_model.stdout) == json.loads(on_scene.stdout)
    # the table too, line for line
    assert lesmc("check", str(model), str(sp)).stdout == lesmc("check", str(scene), str(sp)).stdout


def test_python_api_builds_saves_loads_and_checks(tmp_path: Path) -> None:
    doc, spec = _case(4)
    scene, sp = _write(tmp_path, doc, spec)
    model = api.build(scene, None, spec=sp, property="lose")
    assert isinstance(model, MultiModel)
    path = tmp_path / "m.npz"
    api.save_model(model, path)
    back = api.load_model(path)
    assert isinstance(back, MultiModel)
    want = [r.to_dict() for r in api.check(scene, sp)]
    assert [r.to_dict() for r in api.check(back, sp)] == want
    assert [r.to_dict() for r in api.check(str(path), sp)] == want
    # a window and no spec: the attacker hides, every detection attackable, up to the end
    spec_l, spec_u = model.window
    by_window = api.build(api.load_scene(scene), (spec_l, spec_u))
    assert isinstance(by_window, MultiModel)
    assert by_window.n_states == model.n_states and by_window.n_transitions == model.n_transitions
    with pytest.raises(UsageError, match=r"\.npz"):
        api.save_model(model, tmp_path / "m.lts")
    with pytest.raises(UsageError, match="engine"):
        api.check(back, sp, engine="bnb")


def _storm(path: Path, fmt: str) -> Fraction | float:
    """Storm's optimum of the exported MDP, in exact rational arithmetic."""
    from test_export import storm_optimum, storm_prism_optimum

    text = path.read_text()
    value = (storm_optimum if fmt == "drn" else storm_prism_optimum)(text, path.parent)
    return value


def _exact(x: float) -> Fraction | float:
    return x if math.isinf(x) else Fraction(x)


#: (seed, design) of the sampled Storm agreement: 24 SORT scenes and 4 GNN scenes.
STORM_CASES = [(s, "sort") for s in range(24)] + [(100 + s, "gnn") for s in range(4)]


@pytest.mark.parametrize(("seed", "design"), STORM_CASES)
def test_storm_agrees_with_lesmc_on_random_scenes(tmp_path: Path, seed: int, design: str) -> None:
    """Every property of the case exported through the registry (DRN for even seeds, PRISM
    for odd) and solved by Storm equals lesmc's optimum on the same model."""
    pytest.importorskip("stormpy")
    doc, text = _case(seed, design)
    scene, sp = _write(tmp_path, doc, text)
    spec = parse_spec(text, str(sp))
    model = api.build(scene, None, spec=spec, property="hijack")
    assert isinstance(model, MultiModel)
    results = {r.property: r for r in api.check(model, spec)}
    fmt = "drn" if seed % 2 == 0 else "prism"
    for name, res in results.items():
        out = tmp_path / f"{name}.{fmt}"
        facts = formats.get(fmt).write(model, out, Request(spec, name))
        assert facts["not_exported"] is None
        assert _storm(out, fmt) == _exact(res.optimum), (name, seed)


def test_cli_export_of_a_model_and_of_its_scene_agree(tmp_path: Path) -> None:
    pytest.importorskip("stormpy")
    doc, spec = _case(7)
    scene, sp = _write(tmp_path, doc, spec)
    model = tmp_path / "m.npz"
    _clean(lesmc("build", str(scene), "--spec", str(sp), "--property", "lose", "-o", str(model)))
    a, b = tmp_path / "a.drn", tmp_path / "b.drn"
    for src, out in ((model, a), (scene, b)):
        r = lesmc("export", str(src), "--format", "drn", "--spec", str(sp), "--property", "lose",
                  "-o", str(out), "--json")  # fmt: skip
        _clean(r)
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["drn"]["states"] > 1
    assert a.read_text() == b.read_text()
    want = json.loads(lesmc("check", str(model), str(sp), "--json", "--property", "lose").stdout)
    opt = want["results"][0]["optimum"]
    assert _storm(a, "drn") == (math.inf if opt is None else Fraction(opt))


def test_what_a_multi_target_model_does_not_take_is_refused(tmp_path: Path) -> None:
    doc, _ = _case(5)
    doc["frames"][1]["detections"][0]["payoff"] = "unpriced"
    scene, sp = _write(tmp_path, doc, SPEC.format(l=1, u=2, a=0))
    model = tmp_path / "m.npz"
    r = lesmc("build", str(scene), "--window", "1..1", "-o", str(model))
    _clean(r)
    assert r.returncode == 0, r.stderr
    runs = {
        "dot": lesmc("export", str(model), "--format", "dot", "-o", str(tmp_path / "x.dot")),
        "json": lesmc(
            "export",
            str(scene),
            "--format",
            "json",
            "--window",
            "1..1",
            "-o",
            str(tmp_path / "x.lts"),
        ),
        "lts": lesmc("build", str(scene), "--window", "1..1", "-o", str(tmp_path / "m.lts")),
        "engine": lesmc("check", str(model), str(sp), "--engine", "bnb"),
        "spec single": lesmc(
            "build",
            str(scene),
            "--design",
            "single",
            "--spec",
            str(sp),
            "-o",
            str(tmp_path / "s.lts"),
        ),
    }
    for what, r in runs.items():
        _clean(r)
        assert r.returncode == 2, (what, r.stderr)
    assert "drn or prism" in runs["dot"].stderr
    assert not (tmp_path / "x.dot").exists() and not (tmp_path / "m.lts").exists()
    # a property of another window: located at its attack window clause
    r = lesmc("check", str(model), str(sp), "--property", "fewest")
    _clean(r)
    assert r.returncode == 2 and f"{sp}:14:" in r.stderr and "built for" in r.stderr, r.stderr
    # a payoff objective on a model whose window holds an unpriced detection
    one = tmp_path / "one.spec"
    one.write_text(SPEC.format(l=1, u=1, a=0))
    r = lesmc("check", str(model), str(one), "--property", "hijack")
    _clean(r)
    assert r.returncode == 2 and "unpriced" in r.stderr, r.stderr
    r = lesmc("check", str(model), str(one), "--property", "fewest")
    _clean(r)
    assert r.returncode in (0, 1), r.stderr
    # a single-target verb reading a multi-target model names what it is
    with pytest.raises(ModelError, match="multi-target"):
        load_lts(model)


def test_window_and_spec_must_agree(tmp_path: Path) -> None:
    doc, _ = _case(6)
    scene, sp = _write(tmp_path, doc, SPEC.format(l=1, u=2, a=0))
    r = lesmc("build", str(scene), "--spec", str(sp), "--property", "lose", "--window", "1..1",
              "-o", str(tmp_path / "m.npz"))  # fmt: skip
    _clean(r)
    assert r.returncode == 2 and f"{sp}:8:" in r.stderr, r.stderr
    assert not (tmp_path / "m.npz").exists()


INJECT = """property sw {{
  attack window {l}..{u} allow hide, inject
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 3
}}
property near {{
  attack window {l}..{u} within 40
  minimize count
  subject to lost(0..end) > 0
  holds if optimum > 1
}}
"""


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_models_of_injection_and_radius_round_trip(tmp_path: Path, seed: int) -> None:
    """A model built for ``allow hide, inject`` (injected candidates among its names) and
    one for ``within 40`` check from their files as their scene does, refuse each other's
    property, and (inject) export what Storm solves to lesmc's optimum."""
    test_inject = pytest.importorskip("test_inject")
    frames, pay, cands, cpay, l, u = test_inject._case(seed)
    doc = test_inject._doc(frames, pay, cands, cpay)
    scene, sp = _write(tmp_path, doc, INJECT.format(l=l, u=u))
    spec = api.load_spec(sp)
    want = {r.property: r.to_dict() for r in api.check(scene, spec)}
    for name, other in (("sw", "near"), ("near", "sw")):
        path = tmp_path / f"{name}.npz"
        api.save_model(api.build(scene, None, spec=spec, property=name), path)
        model = api.load_model(path)
        assert isinstance(model, MultiModel)
        assert [r.to_dict() for r in api.check(model, spec, only=name)] == [want[name]]
        with pytest.raises(LesmcError, match="built for"):
            api.check(model, spec, only=other)
    pytest.importorskip("stormpy")
    out = tmp_path / "sw.drn"
    api.export(tmp_path / "sw.npz", out, format="drn", spec=spec, property="sw")
    opt = want["sw"]["optimum"]
    assert _storm(out, "drn") == (math.inf if opt is None else Fraction(opt))
