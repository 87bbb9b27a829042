"""``inject grid D within R payoff P`` (issue 61), a modelling device: at an attacked step
the attacker may also inject a detection at any point of a D-px grid centred on the
tracker's prediction, within R px of it, at payoff P each. Against a brute force written
here: every subset of the attacked frame's detections hidden, every subset of its
candidates and of the grid's points (placed around the prediction of the path so far)
injected, tracked by the independent nearest-neighbour Kalman filter of
tests/test_inject_single.py. Also the clause's located errors and the ``allow`` message."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from inject_scale import cases
from test_inject_single import M, _case, _check, _step

from lesmc import api
from lesmc.common.errors import SpecError
from lesmc.engines import registry as engines
from lesmc.scene import scene_from_dict

CASES = cases(40, 200)  # LESMC_INJECT_FULL=1: the 200 (tests/inject_scale.py)


def _offsets(spacing: float, radius: float) -> list[np.ndarray]:
    """The grid's points around 0, written here from the clause's definition."""
    n = int(radius // spacing) + 1
    return [
        np.array([i * spacing, j * spacing])
        for i in range(-n, n + 1)
        for j in range(-n, n + 1)
        if math.hypot(i * spacing, j * spacing) <= radius
    ]


def _subsets(n: int) -> list[tuple[int, ...]]:
    return [s for r in range(n + 1) for s in itertools.combinations(range(n), r)]


def _brute(case: dict[str, Any], grid: tuple[float, float, float]) -> list[tuple[float, float]]:
    """(cost, dist.max(0..end)) of every hide/inject combination over the window, the
    grid's points around the prediction of the path taken so far."""
    lo, hi = case["window"]
    end = case["end"]
    offs, price = _offsets(grid[0], grid[1]), grid[2]
    x0 = np.array([0.0, 0.0, 10.0, 0.0])

    def original() -> list[np.ndarray]:
        x, P, out = x0, M["P0"], [x0]
        for k in range(1, end + 1):
            d, _ = case["dets"][k]
            x, P = _step(x, P, list(d))
            out.append(x)
        return out

    base = original()
    leaves: list[tuple[float, float]] = []

    def walk(k: int, x: np.ndarray, P: np.ndarray, cost: float, dev: float) -> None:
        if k > end:
            leaves.append((cost, dev))
            return
        (d, dp), (c, cp) = case["dets"][k], case["cands"][k]
        if not lo <= k <= hi:
            choices = [((), (), ())]
        else:
            can = [i for i in range(len(d)) if math.isfinite(dp[i])]
            choices = [
                (h, j, g)
                for h in _subsets(len(can))
                for j in _subsets(len(c))
                for g in _subsets(len(offs))
            ]
            choices = [(tuple(can[i] for i in h), j, g) for h, j, g in choices]
        pred = M["H"] @ M["F"] @ x
        for h, j, g in choices:
            Z = [d[i] for i in range(len(d)) if i not in h] + [c[i] for i in j]
            Z += [pred + offs[i] for i in g]
            x2, P2 = _step(x, P, Z)
            spent = float(sum(dp[list(h)]) + sum(cp[list(j)]) + price * len(g))
            walk(k + 1, x2, P2, cost + spent, max(dev, float(np.linalg.norm(x2 - base[k]))))

    walk(1, x0, M["P0"], 0.0, 0.0)
    return leaves


def _spec(case: dict[str, Any], bound: float, grid: tuple[float, float, float]) -> str:
    lo, hi = case["window"]
    return (
        f"property p {{ attack window {lo}..{hi} allow hide, inject "
        f"inject grid {grid[0]} within {grid[1]} payoff {grid[2]} end {case['end']} "
        f"minimize payoff subject to dist.max(0..end) > {bound} holds if optimum > 100 }}\n"
    )


def _cases(n: int, seed: int) -> list[tuple[dict[str, Any], tuple[float, float, float]]]:
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        case = _case(rng)
        lo, hi = case["window"]
        spacing = float(rng.choice([3.0, 6.0, 9.0]))
        # one point (the prediction) when two steps are attacked, up to five for one
        radius = 0.0 if hi > lo else float(rng.choice([0.0, spacing]))
        out.append((case, (spacing, radius, float(rng.choice([0.0, 0.5, 1.0, 2.5])))))
    return out


def test_every_engine_equals_the_brute_force_with_a_grid() -> None:
    rng = np.random.default_rng(3)
    below = 0
    for case, grid in _cases(CASES, 17):
        leaves = _brute(case, grid)
        devs = sorted({round(d, 6) for _, d in leaves})
        if len(devs) < 2:
            continue
        i = int(rng.integers(0, len(devs) - 1))
        bound = round((devs[i] + devs[i + 1]) / 2, 6)
        want = min((c for c, d in leaves if d > bound), default=math.inf)
        for engine in engines.names():
            got = _check(case["doc"], _spec(case, bound, grid), engine)
            assert got == pytest.approx(want, abs=1e-9), (engine, case["window"], grid, bound)
        plain = _spec(case, bound, grid).replace(
            f"inject grid {grid[0]} within {grid[1]} payoff {grid[2]} ", ""
        )
        without = _check(case["doc"], plain, engines.names()[0])
        assert without >= want - 1e-9  # the grid only adds options
        below += without > want + 1e-9
    assert below  # somewhere the grid made the attack cheaper


def test_grid_points_are_named_in_the_counterexample() -> None:
    case = _cases(1, 1)[0][0]
    doc = case["doc"]
    doc["frames"] = [
        {"step": 0, "detections": []},
        {"step": 1, "detections": [{"id": "1:0", "x": 10.0, "y": 0.5, "payoff": 5.0}]},
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    spec = api.parse_spec(
        "property p { attack window 1..1 allow hide, inject inject grid 4 within 8 payoff 1.5 "
        "minimize payoff subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    r = api.check(scene_from_dict(doc), spec)[0]
    assert r.optimum == pytest.approx(6.5)  # hide 1:0 (5) and inject a grid point 4 px off
    cex = r.counterexample
    assert cex is not None
    assert any(
        n.startswith("inject grid 4 within 8 payoff 1.5 is a modelling device") for n in r.notes
    )
    attacked = [s for s in cex.steps if s.attacked]
    assert [s.step for s in attacked] == [1]
    assert attacked[0].obs is not None and attacked[0].obs.startswith("1:grid")


@pytest.mark.parametrize(
    ("clause", "col", "want"),
    [
        ("inject grid 0 within 20 payoff 1", 15, "the grid spacing must be positive"),
        ("inject grid 5 within -2 payoff 1", 24, "the grid radius must be at least 0"),
        ("inject grid 5 within 20 payoff -1", 34, "an inject payoff must be at least 0"),
        ("inject grid 0.01 within 500 payoff 1", 15, "more than 1000 points"),
    ],
)
def test_bad_grid_is_a_located_error(tmp_path: Path, clause: str, col: int, want: str) -> None:
    scene, spec = _files(tmp_path, f"  attack window 1..1 allow hide, inject\n  {clause}\n")
    r = lesmc("check", str(scene), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:3:{col}:" in r.stderr and want in r.stderr, r.stderr


@pytest.mark.parametrize(
    ("window", "design", "want"),
    [
        ("attack window 1..1", "single", "the attack window must allow inject"),
        ("attack window 1..1 allow hide, inject", "joint", "not supported on the joint design"),
    ],
)
def test_grid_needs_inject_and_a_single_tracker(
    tmp_path: Path, window: str, design: str, want: str
) -> None:
    scene, spec = _files(tmp_path, f"  {window}\n  inject grid 5 within 10 payoff 1\n", design)
    r = lesmc("check", str(scene), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:3:3:" in r.stderr and want in r.stderr, r.stderr


def _files(tmp_path: Path, clauses: str, design: str = "single") -> tuple[Path, Path]:
    import json

    doc = _cases(1, 5)[0][0]["doc"]
    doc["tracker"]["design"] = design
    if design != "single":
        doc["tracker"].pop("model")
    scene, spec = tmp_path / "s.json", tmp_path / "p.spec"
    scene.write_text(json.dumps(doc))
    spec.write_text(
        "property p {\n" + clauses + "  minimize payoff subject to dist.max(0..end) > 3\n"
        "  holds if optimum > 10\n}\n"
    )
    return scene, spec


@pytest.mark.parametrize(
    ("after", "col", "word"),
    [
        ("end 3", 28, "'end' is a keyword"),
        ("minimize", 28, "'minimize' is a keyword"),
        ("}", 28, "no action follows"),
    ],
)
def test_allow_followed_by_a_keyword_needs_an_action(
    tmp_path: Path, after: str, col: int, word: str
) -> None:
    """Before: "unexpected '3'" (the lexer read ``end`` as an action) at the next token."""
    text = f"property p {{\n  attack window 1..1 allow {after}\n  minimize payoff subject to "
    text += "dist.max(0..end) > 3 holds if optimum > 1 }\n"
    with pytest.raises(SpecError) as err:
        api.parse_spec(text, "p.spec")
    msg = str(err.value)
    assert msg.startswith(f"p.spec:2:{col}: allow needs an action"), msg
    assert word in msg and "'hide' or 'inject'" in msg


def test_allow_inject_followed_by_the_grid_clause_parses() -> None:
    """``inject`` is both an action and the grid clause's keyword."""
    spec = api.parse_spec(
        "property p { attack window 1..1 allow inject inject grid 2 within 2.5 payoff 0 "
        "minimize payoff subject to dist.max(0..end) > 3 holds if optimum > 1 }\n"
    )
    prop = spec.properties[0]
    assert prop.actions == ("inject",)
    assert prop.grid is not None and len(prop.grid.offsets()) == 5


def test_a_model_built_with_a_grid_checks_only_that_grid(tmp_path: Path) -> None:
    """A built model records its grid (``meta.inject_grid``): a property with the same
    grid checks it to the scene's optimum; one without a grid, or with another, is a
    located error; ``lesmc export --format drn`` builds the property's grid."""
    from lesmc.pipeline.check import grid_points
    from lesmc.unfold.unfold import build_model

    case, grid = _cases(1, 2)[0]
    grid = (grid[0], grid[0], 1.0)  # five points
    text = _spec(case, 1.0, grid)
    scene = scene_from_dict(case["doc"])
    spec = api.parse_spec(text, "p.spec")
    model = build_model(
        scene, case["window"], inject=True, grid=grid_points(spec.properties[0].grid)
    )
    assert len(model.meta["inject_grid"]["offsets"]) == 5
    assert api.check(model, spec)[0].optimum == api.check(scene, spec)[0].optimum
    for other in (
        text.replace(f"inject grid {grid[0]} within {grid[1]} payoff 1.0 ", ""),
        text.replace("payoff 1.0", "payoff 2.0"),
    ):
        with pytest.raises(SpecError) as err:
            api.check(model, api.parse_spec(other, "p.spec"))
        assert str(err.value).startswith("p.spec:1:") and "inject grid" in str(err.value)
    import json

    (tmp_path / "s.json").write_text(json.dumps(case["doc"]))
    (tmp_path / "p.spec").write_text(text)
    r = lesmc(
        "export",
        str(tmp_path / "s.json"),
        "--format",
        "drn",
        "--spec",
        str(tmp_path / "p.spec"),
        "-o",
        str(tmp_path / "m.drn"),
    )
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    (tmp_path / "q.spec").write_text(
        text.replace(f"inject grid {grid[0]} within {grid[1]} payoff 1.0 ", "")
    )
    r = lesmc(
        "export",
        str(tmp_path / "s.json"),
        "--format",
        "drn",
        "--spec",
        str(tmp_path / "q.spec"),
        "-o",
        str(tmp_path / "q.drn"),
    )
    assert r.returncode == 0, r.stderr
    actions = [(tmp_path / f).read_text().count("\taction") for f in ("m.drn", "q.drn")]
    assert actions[0] > actions[1]  # the grid's options are in the export
