"""The runtime monitors of lesmc/language/monitors.py (issue 59): each monitor's alarms
against an independent implementation written here from the definitions
(docs/semantics.md, "Runtime monitors"); the NIS the trackers put in a model against νᵀS⁻¹ν
recomputed from the model's states and the scene's detections; the checker's optimum
under every per-transition monitor against a brute force over all paths; vacuity for
every monitor kind; the spec clause and ``lesmc alarms``'s bad input (located, exit 2)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from scipy.stats import chi2

from lesmc.common.errors import SpecError
from lesmc.engines.check import check
from lesmc.language import monitors
from lesmc.language.parser import parse_spec
from lesmc.model.arrays import ArrayModel
from lesmc.model.kernel import track_alarms
from lesmc.model.lts import to_arrays
from lesmc.model.lts_format import lts_from_dict
from lesmc.model.random_models import RandomModelConfig, random_lts

# ------------------------------------------------------------------ the definitions


def expected_alarms(kind: str, p: float, k: int, tau: np.ndarray, nis: np.ndarray) -> list[bool]:
    """Each monitor's alarm at steps 0..n of one track, step by step from its definition."""
    out = [False]
    for j in range(1, len(tau)):
        if kind == "tau_rise":
            out.append(bool(tau[j] > tau[j - 1] * (1 + p) + 1e-300))
        elif kind == "trace":
            out.append(bool(tau[j] > p))
        elif kind == "misses":
            lo = j - int(p) + 1
            out.append(lo >= 1 and all(math.isnan(nis[i]) for i in range(lo, j + 1)))
        else:  # nis: the updates of the window j-k+1..j against chi2 of their dof
            window = [nis[i] for i in range(max(1, j - k + 1), j + 1) if not math.isnan(nis[i])]
            out.append(bool(window) and sum(window) > chi2.ppf(p, 2 * len(window)))
    return out


def random_parameter(kind: str, rng: np.random.Generator) -> tuple[float, int]:
    if kind == "tau_rise":
        return float(rng.choice([0.0, 1e-9, 0.01, 0.2])), 1
    if kind == "trace":
        return float(rng.uniform(5, 60)), 1
    if kind == "misses":
        return float(rng.integers(1, 4)), 1
    return float(rng.choice([0.5, 0.9, 0.99])), int(rng.integers(1, 5))


def random_track(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """τ and NIS of a random track: τ shrinks on updates and grows on misses (as a Kalman
    filter's would), sometimes stays exactly; NIS χ²-like, NaN on misses and at step 0."""
    n = int(rng.integers(1, 30))
    updated = rng.random(n + 1) < rng.uniform(0.3, 1.0)
    updated[0] = False
    tau = np.empty(n + 1)
    tau[0] = rng.uniform(10, 50)
    for j in range(1, n + 1):
        step = rng.choice([0.0, rng.uniform(0.6, 1.0)]) if updated[j] else rng.uniform(1.0, 1.5)
        tau[j] = tau[j - 1] * (step if step else 1.0)
    nis = np.where(updated, rng.chisquare(2, n + 1) * rng.uniform(0.5, 3.0), np.nan)
    return tau, nis


@pytest.mark.parametrize("kind", ["tau_rise", "nis", "misses", "trace"])
def test_alarms_equal_the_definitions_on_300_random_tracks(kind: str) -> None:
    rng = np.random.default_rng(59)
    fired = 0
    for _ in range(300):
        tau, nis = random_track(rng)
        p, k = random_parameter(kind, rng)
        got = track_alarms(kind, p, k, tau, nis)
        assert got.tolist() == expected_alarms(kind, p, k, tau, nis)
        fired += int(got.sum())
    assert fired > 0  # the tracks exercise the alarm, not only its silence


def test_every_registered_monitor_is_tested() -> None:
    assert set(monitors.names()) == {"tau_rise", "nis", "misses", "trace"}
    for name in monitors.names():
        kind = monitors.get(name)
        assert kind.summary and kind.parameter and kind.reads in ("tau", "nis")


# ------------------------------------------------------------------ NIS in the model


def _scene(seed: int, design: str):  # type: ignore[no-untyped-def]
    from lesmc.scene.toy import Vehicle, vehicle_scene

    rng = np.random.default_rng(seed)
    vs = [
        Vehicle(
            f"v{i}",
            float(rng.uniform(80, 160)),
            float(rng.uniform(80, 160)),
            float(rng.uniform(-12, 12)),
            float(rng.uniform(-12, 12)),
            float(rng.uniform(0.5, 3)),
            last=int(rng.integers(4, 12)),
        )
        for i in range(int(rng.integers(2, 5)))
    ]
    vs[0] = dataclasses.replace(vs[0], last=10**9)
    return vehicle_scene(vs, 9, vs[0]).with_tracker(design=design)


@pytest.mark.parametrize("design", ["single", "joint"])
def test_model_nis_is_the_innovation_of_the_update(design: str) -> None:
    """Every transition of built models: NaN without an observation, else νᵀS⁻¹ν of its
    detection against the source state's prediction (F, Q, H, R of the scene's model)."""
    from lesmc.tracking.kalman import matrices
    from lesmc.unfold.unfold import build_model

    checked = 0
    for seed in range(6 if design == "joint" else 20):
        scene = _scene(seed, design)
        cm = build_model(scene, (2, 5))
        assert cm.nis is not None and cm.obs is not None and cm.P_table is not None
        m = matrices(scene.tracker, scene.dt)
        dets = {d.id: (d.x, d.y) for f in scene.frames for d in f.detections}
        for t in range(cm.n_transitions):
            if cm.obs[t] < 0:
                assert math.isnan(cm.nis[t])
                continue
            q = int(cm.src[t])
            x_hat = m.F @ cm.S[q]
            P_hat = m.F @ cm.P_table[cm.cov[q]] @ m.F.T + m.Q
            nu = np.array(dets[cm.obs_names[cm.obs[t]]]) - m.H @ x_hat
            S = m.H @ P_hat @ m.H.T + m.R
            assert cm.nis[t] == pytest.approx(float(nu @ np.linalg.solve(S, nu)), rel=1e-9)
            checked += 1
    assert checked > 50


def test_nis_survives_both_model_files(tmp_path: Path) -> None:
    from lesmc.model.lts_format import load_lts, save_lts
    from lesmc.unfold.unfold import build_model

    cm = build_model(_scene(3, "single"), (2, 5))
    assert cm.nis is not None

    def by_ids(model: ArrayModel) -> dict[tuple[str, str], float]:
        ids = [
            model.ids[i] if model.ids is not None else f"k{model.step[i]}.{i}"
            for i in range(model.n_states)
        ]
        assert model.nis is not None
        return {
            (ids[a], ids[b]): v
            for a, b, v in zip(
                model.src.tolist(), model.dst.tolist(), model.nis.tolist(), strict=True
            )
        }

    want = by_ids(cm)
    for name in ("m.lts", "m.npz"):
        save_lts(cm, tmp_path / name)
        got = by_ids(load_lts(tmp_path / name))
        assert got.keys() == want.keys()
        assert all(got[k] == want[k] or (math.isnan(got[k]) and math.isnan(want[k])) for k in want)


# ------------------------------------------------------------------ the checker


def _with_nis(model: ArrayModel, rng: np.random.Generator) -> ArrayModel:
    nis = rng.chisquare(2, model.n_transitions) * rng.uniform(0.5, 4.0)
    nis[rng.random(model.n_transitions) < 0.3] = np.nan
    return dataclasses.replace(model, nis=nis)


def _optimum(value: float | None) -> float:
    """A result's optimum; None: no path meets the constraint (the minimum over none, +inf)."""
    return math.inf if value is None else value


def _brute_optimum(cm: ArrayModel, kind: str, p: float, l: int, bound: float) -> float:
    """min over all paths of payoff.sum (the strict Eq. 5 sum of lower-rank payoffs of each
    taken transition in l..u) subject to dist.at(end) > bound, keeping only paths whose
    transitions entering steps >= l never make the monitor fire (window 1)."""
    e = cm.end
    tau = np.array([np.trace(cm.P_table[c]) for c in cm.cov])
    ref = cm.S[cm.original[e]]
    best = math.inf

    def fires(t: int) -> bool:
        a, b = int(cm.src[t]), int(cm.dst[t])
        nis_t = cm.nis[t] if cm.nis is not None else math.nan
        return expected_alarms(kind, p, 1, np.array([tau[a], tau[b]]), np.array([math.nan, nis_t]))[
            1
        ]

    def walk(q: int, cost: float) -> None:
        nonlocal best
        k = int(cm.step[q])
        if k == e or cm.halted[q]:
            d = math.inf if cm.halted[q] and k < e else float(np.linalg.norm(cm.S[q] - ref))
            if d > bound:
                best = min(best, cost)
            return
        lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
        for t in range(lo, hi):
            inside = l <= k + 1 <= e
            if not inside and cm.rank[t] != cm.rank[lo]:
                continue
            if k + 1 >= l and fires(t):
                continue
            lower = [cm.payoff[s] for s in range(lo, hi) if cm.rank[s] < cm.rank[t]]
            walk(int(cm.dst[t]), cost + (math.fsum(lower) if inside else 0.0))

    walk(cm.initial, 0.0)
    return best


@pytest.mark.parametrize("kind", ["tau_rise", "nis", "misses", "trace"])
def test_checker_under_each_monitor_equals_brute_force(kind: str) -> None:
    rng = np.random.default_rng(7)
    cfg = RandomModelConfig(steps=5, width=4, branching=(1, 3), covariance=True)
    seen_finite = 0
    for seed in range(40):
        cm = _with_nis(to_arrays(random_lts(cfg, 1000 + seed)), rng)
        p = {"tau_rise": 1.0, "nis": 0.9, "misses": 1.0, "trace": 0.0}[kind]
        if kind == "trace":  # a bound some states pass
            p = float(np.median([np.trace(P) for P in cm.P_table]))
        bound = float(rng.uniform(0, 20))
        clause = "uncertainty" if kind == "tau_rise" and seed % 2 else f"{kind} {p!r}"
        text = (
            f"property a {{ attack window 1..end minimize payoff "
            f"subject to dist.at(end) > {bound!r} holds if optimum > 1 monitor {clause} }}"
        )
        if clause == "uncertainty":
            text = text.replace("monitor uncertainty", f"monitor uncertainty tolerance {p!r}")
        spec = parse_spec(text)
        want = _brute_optimum(cm, kind, p, 1, bound)
        for engine in ("levels", "bnb", "enumerate"):
            (res,) = check(cm, [spec], engine)  # type: ignore[arg-type]
            got = _optimum(res.optimum)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-12), (seed, engine)
        seen_finite += math.isfinite(want)
    assert seen_finite > 3


# ------------------------------------------------------------------ vacuity


def _chain(nis_orig: float | None, P_rise: bool) -> dict:  # type: ignore[type-arg]
    """A two-branch model: the original path q0 -> a1 -> a2, an attacked one q0 -> a1 -> b2
    (rank 1, payoff 1 to force). The original's last step misses (no nis) or updates with
    ``nis_orig``; its covariance rises there when ``P_rise``."""
    big = [[40.0, 0.0], [0.0, 40.0]]
    small = [[5.0, 0.0], [0.0, 5.0]]
    t2: dict = {"src": "a1", "dst": "a2", "payoff": 1.0, "rank": 0}  # type: ignore[type-arg]
    if nis_orig is not None:
        t2["nis"] = nis_orig
    return {
        "format": "lesmc-lts",
        "version": 1,
        "components": ["x", "y"],
        "initial": "q0",
        "original": ["q0", "a1", "a2"],
        "states": [
            {"id": "q0", "step": 0, "s": [0, 0], "P": [[10.0, 0.0], [0.0, 10.0]]},
            {"id": "a1", "step": 1, "s": [1, 0], "P": [[8.0, 0.0], [0.0, 8.0]]},
            {"id": "a2", "step": 2, "s": [2, 0], "P": big if P_rise else small},
            {"id": "b2", "step": 2, "s": [9, 9], "P": small},
        ],
        "transitions": [
            {"src": "q0", "dst": "a1", "payoff": 1.0, "rank": 0, "nis": 0.5},
            t2,
            {"src": "a1", "dst": "b2", "payoff": 2.0, "rank": 1, "nis": 0.4},
        ],
    }


@pytest.mark.parametrize(
    ("clause", "nis_orig", "rise"),
    [
        ("monitor uncertainty", 0.3, True),
        ("monitor tau_rise 0.5", 0.3, True),
        ("monitor nis 0.99", 40.0, False),
        ("monitor misses 1", None, False),
        ("monitor trace 30", 0.3, True),
    ],
)
def test_vacuity_is_flagged_for_every_monitor_kind(
    clause: str, nis_orig: float | None, rise: bool
) -> None:
    text = (
        "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
        f"holds if optimum > 0.5 {clause} }}"
    )
    spec = parse_spec(text)
    fires = lts_from_dict(_chain(nis_orig, rise))
    (res,) = check(fires, [spec])
    assert res.vacuous and res.original_alarms == [2] and res.optimum == 1.0  # b2: no alarm
    assert "vacuous" in res.status
    quiet = lts_from_dict(_chain(0.3, False))  # the original path updates, small NIS, τ falls
    (res,) = check(quiet, [spec])
    assert not res.vacuous and res.original_alarms == [] and res.optimum == 1.0


def test_a_model_without_nis_is_refused_under_a_nis_monitor() -> None:
    doc = _chain(0.3, False)
    for t in doc["transitions"]:
        t.pop("nis", None)
    spec = parse_spec(
        "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
        "holds if optimum > 0.5 monitor misses 1 }",
        "r.spec",
    )
    with pytest.raises(SpecError, match=r"r.spec:1:\d+: the misses monitor needs the NIS"):
        check(lts_from_dict(doc), [spec])


# ------------------------------------------------------------------ the language


@pytest.mark.parametrize(
    ("clause", "message"),
    [
        ("monitor nis 1.5", "the nis monitor's quantile must be in (0, 1), got 1.5"),
        ("monitor nis 0", "the nis monitor's quantile must be in (0, 1), got 0"),
        ("monitor nis", "the nis monitor needs its quantile"),
        ("monitor bogus 3", "unknown monitor 'bogus'"),
        ("monitor misses 2.5", "must be a whole number >= 1"),
        ("monitor trace 0", "the trace monitor's bound must be a finite number > 0"),
        ("monitor trace 5 window 2", "the trace monitor takes no window"),
        ("monitor nis 0.9 on x", "'on' belongs to the tau_rise and trace monitors"),
        ("monitor nis 0.9 window 0", "window must be at least 1"),
        ("monitor uncertainty tolerance -1", "tolerance must be a finite number >= 0"),
    ],
)
def test_bad_monitor_clauses_are_located_errors(clause: str, message: str) -> None:
    text = (
        "property r {\n  attack window 1..2\n  minimize payoff\n"
        f"  subject to dist.at(end) > 1\n  holds if optimum > 0.5\n  {clause}\n}}"
    )
    with pytest.raises(SpecError, match=r"^s.spec:6:\d+: ") as err:
        parse_spec(text, "s.spec")
    assert message in str(err.value)


def test_windowed_monitors_are_refused_by_the_checker_located() -> None:
    cm = lts_from_dict(_chain(0.3, False))
    for clause in ("monitor nis 0.9 window 2", "monitor misses 2"):
        spec = parse_spec(
            "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
            f"holds if optimum > 0.5 {clause} }}",
            "w.spec",
        )
        with pytest.raises(SpecError, match=r"w.spec:1:\d+: .* reads 2 steps of a path"):
            check(cm, [spec])


def test_monitor_uncertainty_is_tau_rise() -> None:
    a = parse_spec(
        "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
        "holds if optimum > 0.5 monitor uncertainty tolerance 0.25 }"
    ).properties[0]
    b = parse_spec(
        "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
        "holds if optimum > 0.5 monitor tau_rise 0.25 }"
    ).properties[0]
    assert a.monitor == b.monitor


# ------------------------------------------------------------------ lesmc alarms


def _truth_scene(path: Path) -> Path:
    from lesmc.scene.io import save_scene
    from lesmc.scene.scene import TruthTrack
    from lesmc.scene.toy import Vehicle, vehicle_scene

    vs = [
        Vehicle("a", 100, 100, 10, 0, 2.0),
        Vehicle("b", 104, 130, 10, 0, 1.0),
        Vehicle("c", 130, 90, 10, 2, 1.5, last=6),
        Vehicle("parked", 300, 300, 0, 0, 1.0),
    ]
    sc = vehicle_scene(vs, 12, vs[0])
    truth = tuple(
        TruthTrack(v.id, tuple((k, *v.at(k)) for k in range(12) if v.first <= k <= v.last))
        for v in vs
    )
    save_scene(dataclasses.replace(sc, truth=truth), path)
    return path


@pytest.mark.parametrize(
    ("design", "args"),
    [
        ("single", ()),
        ("single", ("--monitor", "misses", "2")),
        ("improved", ("--monitor", "nis", "0.9", "--window", "3")),
        ("joint", ("--monitor", "trace", "40")),
    ],
)
def test_cli_alarms_document(tmp_path: Path, design: str, args: tuple[str, ...]) -> None:
    import jsonschema

    from lesmc.experiment.alarms import scene_starts
    from lesmc.experiment.false_alarms import unattacked_tracks
    from lesmc.schemas import schema

    scene_path = _truth_scene(tmp_path / "s.json")
    r = lesmc("alarms", str(scene_path), "--design", design, *args, "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    jsonschema.validate(doc, schema("alarms"))
    assert [t["truth_id"] for t in doc["tracks"]] == ["a", "b", "c"]  # "parked" does not move
    kind, p = (args[1], float(args[2])) if args else ("tau_rise", 1e-9)
    k = int(args[4]) if len(args) > 3 else 1
    from lesmc.api import load_scene

    scene = load_scene(str(scene_path))
    starts, _ = scene_starts(scene)
    tracker = {"improved": "joint"}.get(design, design)
    series = unattacked_tracks(scene, starts, tracker, 11)
    total = 0
    for t, s in zip(doc["tracks"], series, strict=True):
        want = expected_alarms(kind, p, k, s.tau, s.nis)[1:]
        assert [x["alarm"] for x in t["steps"]] == want
        assert [x["nis"] is None for x in t["steps"]] == list(np.isnan(s.nis[1:]))
        total += sum(want)
    assert doc["rate"]["alarms"] == total
    assert doc["rate"]["steps"] == sum(len(t["steps"]) for t in doc["tracks"])
    human = lesmc("alarms", str(scene_path), "--design", design, *args)
    assert human.returncode == 0 and "false alarms:" in human.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--monitor", "nis", "1.5"), "quantile must be in (0, 1), got 1.5"),
        (("--monitor", "nis", "abc"), "is not a number"),
        (("--monitor", "spoon", "1"), "unknown monitor 'spoon'"),
        (("--monitor", "misses", "0"), "whole number >= 1"),
        (("--monitor", "trace", "3", "--window", "2"), "takes no window"),
        (("--design", "nonesuch"), "nonesuch"),
    ],
)
def test_cli_alarms_bad_input(tmp_path: Path, args: tuple[str, ...], message: str) -> None:
    scene_path = _truth_scene(tmp_path / "s.json")
    r = lesmc("alarms", str(scene_path), *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert message in r.stderr


def test_cli_alarms_scene_without_truth() -> None:
    r = lesmc("alarms", str(Path(__file__).parent / "scenes" / "rq4_merge.json"))
    assert r.returncode == 2 and "no truth tracks" in r.stderr and "Traceback" not in r.stderr


def test_parameters_domains_are_what_the_docs_say() -> None:
    cases = {
        "tau_rise": ([0.0, 1e-9, 5.0], [-1e-9]),
        "nis": ([1e-6, 0.5, 0.999], [0.0, 1.0, -0.5]),
        "misses": ([1.0, 2.0, 7.0], [0.0, 1.5, -1.0]),
        "trace": ([1e-3, 5e4], [0.0, -1.0]),
    }
    for name, (good, bad) in cases.items():
        d = monitors.get(name).domain
        assert all(d.contains(v) for v in good) and not any(d.contains(v) for v in bad)
        assert not d.contains(math.nan)
    assert list(itertools.islice(monitors.names(), 1)) == ["tau_rise"]


# ------------------------------------------------------------------ tracker files


def _nomon_spec(tmp_path: Path, clause: str = "") -> Path:
    text = (Path(__file__).parent / "scenes" / "rq4_merge.spec").read_text()
    out = tmp_path / f"p{len(clause)}.spec"
    out.write_text(text.replace("monitor uncertainty", clause))
    return out


def _results(r) -> list[tuple]:  # type: ignore[no-untyped-def, type-arg]
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    return [
        (x["verdict"], x["optimum"], x["vacuous"], x["original_alarms"]) for x in doc["results"]
    ]


def test_a_tracker_files_monitor_is_the_monitored_designs(tmp_path: Path) -> None:
    scene = str(Path(__file__).parent / "scenes" / "rq4_merge.json")
    tracker = tmp_path / "t.toml"
    tracker.write_text('monitor = "trace 1"  # tiny: the unattacked track fires at once\n')
    got = _results(
        lesmc("check", scene, str(_nomon_spec(tmp_path)), "--design", "monitor",
              "--tracker", str(tracker), "--json")
    )  # fmt: skip
    want = _results(lesmc("check", scene, str(_nomon_spec(tmp_path, "monitor trace 1")), "--json"))
    assert got == want and all(v for _, _, v, _ in got)  # vacuous: trace 1 fires everywhere
    default = _results(
        lesmc("check", scene, str(_nomon_spec(tmp_path)), "--design", "monitor", "--json")
    )
    assert default != got


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('monitor = "nis 1.5"', "monitor: the nis monitor's quantile must be in (0, 1), got 1.5"),
        ('monitor = "sonar 2"', "monitor: unknown monitor 'sonar'"),
        ("monitor = 3", 'monitor must be a string such as "nis 0.99"'),
    ],
)
def test_bad_tracker_file_monitor(tmp_path: Path, line: str, message: str) -> None:
    tracker = tmp_path / "t.toml"
    tracker.write_text(line + "\n")
    scene = str(Path(__file__).parent / "scenes" / "rq4_merge.json")
    r = lesmc(
        "check", scene, str(_nomon_spec(tmp_path)), "--design", "monitor", "--tracker", str(tracker)
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{tracker}:1:1: {message}" in r.stderr  # at its key's line (round 19)


def test_a_windowed_tracker_monitor_is_refused_by_check_but_run_by_alarms(tmp_path: Path) -> None:
    tracker = tmp_path / "t.toml"
    tracker.write_text('monitor = "misses 2"\n')
    scene = str(Path(__file__).parent / "scenes" / "rq4_merge.json")
    r = lesmc(
        "check", scene, str(_nomon_spec(tmp_path)), "--design", "monitor", "--tracker", str(tracker)
    )
    assert r.returncode == 2 and "reads 2 steps of a path" in r.stderr
    r = lesmc("alarms", str(_truth_scene(tmp_path / "s.json")), "--tracker", str(tracker), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["monitor"] == {"kind": "misses", "parameter": 2.0, "window": 1}


@pytest.mark.parametrize("design", ["single", "joint"])
@pytest.mark.parametrize("clause", ["monitor nis 0.9", "monitor misses 1", "monitor trace 60"])
def test_scene_checked_lazily_equals_its_built_model(
    tmp_path: Path, design: str, clause: str
) -> None:
    """The lazy search on a scene reads the NIS as the unfolder reports them; the model file
    carries the same ones (JSON round trip)."""
    scene = str(Path(__file__).parent / "scenes" / "rq4_merge.json")
    spec = _nomon_spec(tmp_path, clause)
    model = tmp_path / "m.lts"
    r = lesmc("build", scene, "--window", "6..8", "--design", design, "-o", str(model))
    assert r.returncode == 0, r.stderr
    a = _results(lesmc("check", str(model), str(spec), "--json"))
    b = _results(lesmc("check", scene, str(spec), "--design", design, "--json"))
    assert a == b


def test_a_campaigns_property_key_names_the_monitor() -> None:
    """Campaign units are keyed by property_text: two monitors that decide differently must
    not share a key (kind, window, except original), and Eq. 13's keeps its old text."""
    from lesmc.campaign.plan import property_text

    base = (
        "property r { attack window 1..2 minimize payoff subject to dist.at(end) > 1 "
        "holds if optimum > 0.5 "
    )
    clauses = [
        "monitor uncertainty tolerance 0.5",
        "monitor nis 0.5",
        "monitor nis 0.5 window 2",
        "monitor trace 0.5",
        "monitor uncertainty tolerance 0.5 except original",
    ]
    texts = [property_text(parse_spec(base + c + " }").properties[0]) for c in clauses]
    assert len(set(texts)) == len(texts)
    assert texts[0].endswith("|monitor None/0.5")


def test_campaign_refuses_a_tracker_monitor_it_would_ignore(tmp_path: Path) -> None:
    video = tmp_path / "v"
    video.mkdir()
    tracker = tmp_path / "t.toml"
    tracker.write_text('monitor = "nis 0.99"\n')
    r = lesmc("campaign", str(video), "--out", str(tmp_path / "o"), "--tracker", str(tracker))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cannot apply the tracker's monitor (nis 0.99)" in r.stderr
    assert not (tmp_path / "o").exists()


def test_cli_check_locates_a_quantile_outside_its_domain(tmp_path: Path) -> None:
    spec = tmp_path / "q.spec"
    spec.write_text(
        "property r {\n  attack window 6..8\n  minimize payoff\n  subject to dist.at(end) > 1\n"
        "  holds if optimum > 0.5\n  monitor nis 1.5\n}\n"
    )
    scene = str(Path(__file__).parent / "scenes" / "rq4_merge.json")
    r = lesmc("check", scene, str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{spec}:6:15: the nis monitor's quantile must be in (0, 1), got 1.5" in r.stderr
    r = lesmc("check", scene, str(spec), "--json")
    err = json.loads(r.stdout)["error"]
    assert r.returncode == 2 and (err["line"], err["column"]) == (6, 15)


@pytest.mark.parametrize("name", ["rq2_stop", "rq4_merge", "rq1_platoon"])
def test_track_reports_the_nis_of_each_update(name: str) -> None:
    """``lesmc track``'s NIS: νᵀS⁻¹ν recomputed from the previous point's estimate and P."""
    from lesmc.scene import load_scene
    from lesmc.tracking.kalman import matrices
    from lesmc.tracking.monitor import track
    from lesmc.tracking.trackers import make_tracker

    scene = load_scene(Path(__file__).parent / "scenes" / f"{name}.json")
    points = track(make_tracker(scene))
    m = matrices(scene.tracker, scene.dt)
    dets = {d.id: (d.x, d.y) for f in scene.frames for d in f.detections}
    updates = 0
    for prev, p in itertools.pairwise(points):
        if p.obs is None:
            assert p.nis is None
            continue
        x_hat, P_hat = m.F @ prev.x, m.F @ prev.P @ m.F.T + m.Q
        nu = np.array(dets[p.obs]) - m.H @ x_hat
        assert p.nis == pytest.approx(float(nu @ np.linalg.solve(m.H @ P_hat @ m.H.T + m.R, nu)))
        updates += 1
    assert updates > 5
    r = lesmc("track", str(Path(__file__).parent / "scenes" / f"{name}.json"), "--json")
    assert [s["nis"] for s in json.loads(r.stdout)["track"]] == [p.nis for p in points]


@pytest.mark.parametrize("monitor", ["trace inf", "misses 1e300", "nis nan", "trace -inf"])
def test_alarms_refuses_a_parameter_outside_its_finite_domain(monitor: str) -> None:
    """``--monitor trace inf`` wrote a JSON document Python cannot encode (exit 4); every
    parameter is finite and a ``misses`` run at most a scene's length."""
    r = lesmc(
        "alarms",
        str(Path(__file__).parent / "scenes" / "rq4_merge.json"),
        "--monitor",
        *monitor.split(),
        "--json",
    )
    assert r.returncode == 2 and "--monitor" in r.stderr and "Traceback" not in r.stderr
