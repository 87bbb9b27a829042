"""``lesmc campaign``: rows as verify computes them, the same in serial and on a cluster,
durable across a rerun, a SIGKILL of the client and the death of a worker.

One tiny synthetic video is perceived once for the module; every other run
reuses its scene (OUT/scenes/), so each test pays only for checking.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from pipeline_run import design_runs

from lesmc.campaign.run import Video, execute, make_groups, prepare
from lesmc.campaign.store import read_rows
from lesmc.experiment.experiment import bundled_specs, load_specs
from lesmc.tracking.targets import TargetSpec, place_target
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

ROOT = Path(__file__).resolve().parents[1]
WINDOWS = "2..3:0..1"  # 4 windows: l in 2..3, u - l in 0..1
ARGS = ["--windows", WINDOWS, "--targets", "2", "--no-truth"]


def no_trace(r: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A tiny video and a finished serial campaign on it (the reference rows)."""
    tmp = tmp_path_factory.mktemp("campaign")
    video = tmp / "tiny"
    write_video(SynthConfig(frames=11, width=448, height=448, seed=4, density=3.0), video)
    out = tmp / "base"
    r = lesmc("campaign", str(video), "--out", str(out), "--workers", "0", *ARGS)
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    return video, out


def seeded(base: tuple[Path, Path], tmp_path: Path) -> Path:
    """A fresh campaign directory holding only the perceived scene of ``base``."""
    out = tmp_path / "out"
    shutil.copytree(base[1] / "scenes", out / "scenes")
    return out


def content(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Rows by key, without the timings (which differ from run to run)."""
    skip = {"stats", "format", "version"}
    return {r["key"]: {k: v for k, v in r.items() if k not in skip} for r in rows}


def lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_rows_are_what_verify_computes_window_by_window(base: tuple[Path, Path]) -> None:
    """Each row (one model shared by all windows, unfolded lazily) against an eager model
    built for that window alone (the path of lesmc verify)."""
    rows = read_rows(base[1] / "results.jsonl")
    assert len(rows) == 2 * 4 * 3 * 2  # targets x windows x designs x properties
    assert len({r["key"] for r in rows}) == len(rows)
    footage = prepare(Video("tiny", base[0], None, "test"), base[1]).footage
    seen = {}
    for r in rows:
        t, w = r["target"], tuple(r["window"])
        case = (t["x"], t["y"], t["step"], w, r["design"])
        if case not in seen:
            scene = place_target(footage, TargetSpec(t["x"], t["y"], t["step"]))
            run = design_runs(scene, load_specs(bundled_specs(), w), [r["design"]])[0]  # type: ignore[arg-type]
            seen[case] = {x.property: x for x in run.results}
        want = seen[case][r["property"]]
        assert r["verdict"] == want.verdict
        assert r["optimum"] == ("inf" if want.optimum == math.inf else want.optimum)
        assert r["witness_value"] == want.witness_value
        assert r["vacuous"] == want.vacuous
        # a counterexample on a perceived scene is the model's until replayed
        assert r["status"] == {"violated": "violated (not replayed)"}.get(want.status, want.status)


def test_resume_adds_no_row_and_the_summary_counts_the_rows(base: tuple[Path, Path]) -> None:
    before = (base[1] / "results.jsonl").read_bytes()
    r = lesmc("campaign", str(base[0]), "--out", str(base[1]), "--workers", "0", "--json", *ARGS)
    no_trace(r)
    assert (base[1] / "results.jsonl").read_bytes() == before
    html = (base[1] / "campaign.html").read_text()
    from html_tables import table_problems

    assert table_problems(html) == []  # every table's rows as wide as its header
    assert "ECDF" in html and "reproduce with" in html
    assert (base[1] / "figures" / "campaign_violated_by_length.png").stat().st_size > 1000
    doc = json.loads(r.stdout)
    rows = read_rows(base[1] / "results.jsonl")
    assert doc["rows"] == len(rows) and doc["targets"] == 2 and doc["windows"] == 4
    import jsonschema

    from lesmc.schemas import schema

    jsonschema.validate(doc, schema("campaign-summary"))
    for row in rows:
        jsonschema.validate(row, schema("campaign-row"))
    for d, cells in doc["cells"].items():
        for prop, c in cells.items():
            mine = [x for x in rows if x["design"] == d and x["property"] == prop]
            violated = sum(x["verdict"] == "violated" for x in mine)
            assert c["violated"] + c["not_replayed"] == violated == c["not_replayed"]
            vacuous = [x["verdict"] == "holds" and x["vacuous"] for x in mine]
            assert c["vacuous"] == sum(vacuous)
            assert c["holds"] == sum(x["verdict"] == "holds" for x in mine) - sum(vacuous)
            for x in mine:  # only monitored rows can be vacuous: the monitor flags the track
                assert not x["vacuous"] or (d == "improved" and x["original_alarms"])
                words = {"violated": "violated (not replayed)"}  # no replay in campaigns
                want = "holds (vacuous)" if x["vacuous"] else words.get(x["verdict"], x["verdict"])
                assert x["status"] == want
            assert len(c["optima"]) == sum(x["optimum"] != "unknown" for x in mine)
    for prop, imp in doc["improvements"].items():
        bad = {
            (x["target"]["x"], tuple(x["window"]))
            for x in rows
            if x["property"] == prop and x["design"] == "single" and x["verdict"] == "violated"
        }
        assert imp["baseline"] == "single" and imp["baseline_violated"] == len(bad)
        for d, v in imp["designs"].items():
            fixed = {
                (x["target"]["x"], tuple(x["window"]))
                for x in rows
                if x["property"] == prop and x["design"] == d and x["verdict"] == "holds"
            }
            vacuous = {
                (x["target"]["x"], tuple(x["window"]))
                for x in rows
                if x["property"] == prop and x["design"] == d and x.get("vacuous")
            }
            assert v["removed"] == len(bad & (fixed - vacuous))
            assert v["vacuous"] == len(bad & fixed & vacuous)


def test_the_worst_case_command_reproduces_its_row(base: tuple[Path, Path]) -> None:
    from lesmc.campaign.summary import command
    from lesmc.results.campaign_row import read_row

    rows = read_rows(base[1] / "results.jsonl")
    bad = [x for x in rows if x["verdict"] == "violated" and x["design"] == "single"]
    assert bad
    w = min(bad, key=lambda x: (x["optimum"], x["key"]))
    cmd = command(read_row(w), str(base[1] / "scenes")).split()[1:]
    rep = lesmc(*cmd, "--out", str(base[1] / "repro"), "--json")
    no_trace(rep)
    got = {x["property"]: x for run in json.loads(rep.stdout)["runs"] for x in run["results"]}
    assert got[w["property"]]["optimum"] == w["optimum"]
    assert got[w["property"]]["witness_value"] == w["witness_value"]


def test_local_cluster_gives_the_rows_of_the_serial_mode(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    out = seeded(base, tmp_path)
    r = lesmc("campaign", str(base[0]), "--out", str(out), "--workers", "2", *ARGS)
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    got = read_rows(out / "results.jsonl")
    assert len(got) == len(lines(out / "results.jsonl"))
    assert content(got) == content(read_rows(base[1] / "results.jsonl"))


def test_killed_client_then_rerun_ends_complete_without_duplicates(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    out = seeded(base, tmp_path)
    results = out / "results.jsonl"
    cmd = [sys.executable, "-m", "lesmc", "campaign", str(base[0]), "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [*cmd, "--workers", "0", *ARGS],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if results.exists() and results.stat().st_size > 0:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    total = len(read_rows(base[1] / "results.jsonl"))
    kept = len(lines(results))
    assert 0 < kept < total  # killed mid-way
    with open(results, "a") as fh:  # and a line torn by the kill
        fh.write('{"format":"lesmc-campaign-row","version":1,"key":"tor')
    r = lesmc("campaign", str(base[0]), "--out", str(out), "--workers", "0", *ARGS)
    no_trace(r)
    got = [json.loads(x) for x in lines(results)]  # every line whole
    assert len(got) == total == len({x["key"] for x in got})
    assert content(got) == content(read_rows(base[1] / "results.jsonl"))


def groups_of_base(base: tuple[Path, Path], tmp_path: Path) -> tuple[Any, list[Any], Any]:
    """The prepared scene of ``base``, its four groups and the reference rows."""
    from lesmc.campaign.plan import parse_windows
    from lesmc.designs import registry

    out = seeded(base, tmp_path)
    p = prepare(Video("tiny", base[0], None, "test"), out)
    ref = read_rows(base[1] / "results.jsonl")
    for r in ref:
        spec = TargetSpec(r["target"]["x"], r["target"]["y"], r["target"]["step"])
        if spec not in p.targets:
            p.targets.append(spec)
    specs = load_specs(bundled_specs(), None)
    groups, total = make_groups(
        [p], specs, parse_windows(WINDOWS), registry.expand("paper"), set(), 60.0, None
    )
    assert len(groups) == 4 and total == len(ref)
    return p, groups, ref


def run_killing(
    base: tuple[Path, Path], tmp_path: Path, victims: Callable[[Any, int], list[str]]
) -> None:
    """Run the four groups of ``base`` on a 2-worker cluster, under a client of the
    caller's own (as in a notebook); after the first group's rows, SIGKILL the workers
    that ``victims(client, n_groups)`` names. The rows must still be the reference."""
    from distributed import Client, LocalCluster

    p, groups, ref = groups_of_base(base, tmp_path)
    rows: list[dict[str, Any]] = []
    killed: list[int] = []
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):

        def on_rows(batch: list[dict[str, Any]]) -> None:
            rows.extend(batch)
            if killed:
                return
            workers = victims(client, len(groups))
            if workers:
                for pid in client.run(os.getpid, workers=workers).values():
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)

        execute(groups, {p.doc_key: p.doc}, on_rows, 0, cluster.scheduler_address)
    assert killed  # some worker died with a group in flight or a result in memory
    assert content(rows) == content(ref)


def test_a_killed_worker_has_its_group_retried(base: tuple[Path, Path], tmp_path: Path) -> None:
    def one_busy(client: Any, _: int) -> list[str]:
        return [w for w, keys in client.processing().items() if keys][:1]

    run_killing(base, tmp_path, one_busy)


def test_finished_groups_lost_with_their_workers_are_run_again(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """Every group done, then every worker killed before the rows are fetched.

    The caller holds a client of its own, so this also checks that ``execute``
    waits on its own client's event loop.
    """

    def holders_once_all_done(client: Any, n_groups: int) -> list[str]:
        def done() -> dict[str, int]:
            held = client.has_what()
            return {w: sum(str(k).startswith("run_group") for k in ks) for w, ks in held.items()}

        deadline = time.monotonic() + 120
        while sum(done().values()) < n_groups and time.monotonic() < deadline:
            time.sleep(0.05)
        return [w for w, n in done().items() if n]

    run_killing(base, tmp_path, holders_once_all_done)


def test_interval_rows_match_brute_force_over_both_payoff_sets(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """``--payoffs interval`` on a scene perceived by another run (so the video is perceived
    again for its N_dr windows): the detections the units' models can hide get certified
    bounds in OUT/scenes, and each row's two optima and verdict are those of an exhaustive
    search of every attacked path, once with the attack's payoffs and once with the bounds."""
    import math

    from oracle import brute_force

    from lesmc.campaign.plan import design_specs
    from lesmc.common.files import read_json
    from lesmc.language.parser import parse_spec
    from lesmc.model.lts import to_lts
    from lesmc.pipeline.check import bind_scene
    from lesmc.scene import footage_from_dict
    from lesmc.unfold.probe import priced_detections
    from lesmc.unfold.unfold import build_model

    def load_scene(path: Path) -> Any:
        return footage_from_dict(read_json(path), str(path))[0]

    out = seeded(base, tmp_path)
    args = [str(base[0]), "--out", str(out), "--workers", "0", "--payoffs", "interval", *ARGS]
    r = lesmc("campaign", *args)
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    rows = read_rows(out / "results.jsonl")
    assert len(rows) == 2 * 4 * 3 * 2
    attack_keys = {x["key"] for x in read_rows(base[1] / "results.jsonl")}
    assert not attack_keys & {x["key"] for x in rows}  # interval rows are other units
    footage = load_scene(out / "scenes" / "tiny.json")
    assert footage.meta["certified"]["detections"] > 0
    specs = [parse_spec(p.read_text(), str(p)) for p in bundled_specs()]
    verdicts = set()
    truth: dict[Any, tuple[float, str, float]] = {}  # per unit: certified optimum, op, θ
    hidden: set[tuple[int, int]] = set()
    for x in rows:
        t, w = x["target"], (x["window"][0], x["window"][1])
        scene = place_target(footage, TargetSpec(t["x"], t["y"], t["step"]))
        scene = scene.with_tracker(design="single" if x["design"] == "single" else "joint")
        optima = []
        for sc in (scene, scene.priced("certified")):
            bp = next(
                b
                for b in bind_scene(sc, design_specs(specs, w, x["design"]))
                if b.name == x["property"]
            )
            optima.append(brute_force(to_lts(build_model(sc, (bp.l, bp.u), bp.end)), bp).optimum)
        a, c = optima
        op, theta = bp.prop.holds_op, bp.prop.threshold
        proven = c > theta if op == ">" else c >= theta
        broken = not (a > theta if op == ">" else a >= theta)
        expect = "holds" if proven else "violated" if broken else "unknown"
        assert x["verdict"] == expect, (x, a, c)
        assert x["payoffs"] == "interval"
        for key, v in (("optimum_certified", c), ("optimum_attack", a)):
            assert (x[key] == "inf") if math.isinf(v) else math.isclose(x[key], v, rel_tol=1e-9)
        assert not any("carry no certified bound" in n for n in x["notes"])
        verdicts.add(expect)
        assert x["stats"]["certified"]["stopped"] == "finished"
        truth[(str(t), w, x["design"], x["property"])] = (c, op, theta)
        for k, dets in priced_detections(scene, w).items():
            hidden.update((k, int(i)) for i in dets)
    assert "violated" in verdicts
    # the row's command (lesmc verify on the saved scene) gives the row's interval
    from lesmc.campaign.summary import command
    from lesmc.results.campaign_row import read_row

    w = max(rows, key=lambda x: (x["verdict"] != "holds", str(x["optimum_certified"]), x["key"]))
    cmd = command(read_row(w), str(out / "scenes")).split()[1:]
    assert cmd[-2:] == ["--payoffs", "interval"]
    rep = lesmc(*cmd, "--out", str(out / "repro"), "--json")
    no_trace(rep)
    got = {x["property"]: x for run in json.loads(rep.stdout)["runs"] for x in run["results"]}
    for key in ("verdict", "optimum_certified", "optimum_attack"):
        assert got[w["property"]][key] == w[key]
    # every detection a unit's model can hide has its bound in the saved scene
    assert all(footage.frame(k).detections[i].payoff_lower is not None for k, i in hidden)
    # a rerun adds no row and certifies nothing again
    before = (out / "results.jsonl").read_bytes()
    again = lesmc("campaign", *args, "--json")
    no_trace(again)
    assert (out / "results.jsonl").read_bytes() == before
    assert load_scene(out / "scenes" / "tiny.json").meta["certified"] == footage.meta["certified"]
    # --payoffs certified: the certified optimum alone decides (holds, or else violated)
    cert = lesmc("campaign", *[("certified" if a == "interval" else a) for a in args])
    no_trace(cert)
    certified = [x for x in read_rows(out / "results.jsonl") if x.get("payoffs") == "certified"]
    assert len(certified) == len(rows)
    for x in certified:
        c, op, theta = truth[(str(x["target"]), tuple(x["window"]), x["design"], x["property"])]
        assert x["verdict"] == ("holds" if (c > theta if op == ">" else c >= theta) else "violated")
        assert x["optimum"] == ("inf" if math.isinf(c) else pytest.approx(c, rel=1e-9))
        assert "optimum_certified" not in x and "certified" not in x["stats"]
    # the attack's rows on the scene with bounds: the same units (keys) and answers as before
    plain = lesmc("campaign", str(base[0]), "--out", str(out), "--workers", "0", *ARGS)
    no_trace(plain)
    mixed = read_rows(out / "results.jsonl")
    attack_rows = [x for x in mixed if "payoffs" not in x]
    assert content(attack_rows) == content(read_rows(base[1] / "results.jsonl"))
    import jsonschema

    from lesmc.schemas import schema

    for row in rows:
        jsonschema.validate(row, schema("campaign-row"))
    # a window whose probe left detections without a bound: its units (only) say so
    from dataclasses import replace

    from lesmc.campaign.plan import parse_windows
    from lesmc.campaign.work import run_group
    from lesmc.pipeline.certify import PROBE_STOPPED, PROBE_STOPPED_NOTE

    p = prepare(Video("tiny", base[0], None, "test"), out)
    for x in rows:
        spec = TargetSpec(x["target"]["x"], x["target"]["y"], x["target"]["step"])
        if spec not in p.targets:
            p.targets.append(spec)
    groups, _ = make_groups(
        [p], load_specs(bundled_specs(), None), parse_windows(WINDOWS), ("single",), set(),
        60.0, None, "interval",
    )  # fmt: skip
    g = groups[0]
    assert {r["key"] for r in run_group(g, p.doc)} <= {x["key"] for x in rows}
    marked = replace(g, unbounded=(((3, 4), 2), ((2, 3), PROBE_STOPPED)))
    for r in run_group(marked, p.doc):
        inside = r["window"][0] >= 3
        assert any(n.startswith("certified payoffs: 2 detection(s)") for n in r["notes"]) == inside
        assert (PROBE_STOPPED_NOTE in " ".join(r["notes"])) == (not inside)


def test_interval_refuses_to_certify_a_scene_perceived_with_other_networks(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """The video is perceived again for its N_dr windows: with other --nets its detections
    differ from the scene's, and bounds would belong to other detections. Exit 2, and
    neither the scene nor results.jsonl is touched."""
    import torch

    from lesmc.perception.cnn import load_nets, save_nets

    nets = load_nets()
    with torch.no_grad():
        nets.dr.head[-1].bias[1] -= 4.0  # N_dr says "vehicle" far less often
    save_nets(nets, tmp_path / "nets")
    out = seeded(base, tmp_path)
    scene = (out / "scenes" / "tiny.json").read_bytes()
    r = lesmc(
        "campaign", str(base[0]), "--out", str(out), "--workers", "0", "--payoffs", "interval",
        "--nets", str(tmp_path / "nets"), *ARGS,
    )  # fmt: skip
    no_trace(r)
    assert r.returncode == 2, r.stderr
    assert "perceived with other networks" in r.stderr
    assert (out / "scenes" / "tiny.json").read_bytes() == scene
    assert not (out / "results.jsonl").exists() or not lines(out / "results.jsonl")


def test_a_tracker_file_becomes_the_campaigns_tracker(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """--tracker: the scene in OUT/scenes carries it, the rows are new (their scene differs)
    and a row is what the single design computes with that tracker, window by window."""
    out = seeded(base, tmp_path)
    tracker = "examples/trackers/ca2d.toml"
    r = lesmc("campaign", str(base[0]), "--out", str(out), "--workers", "0",
              "--tracker", tracker, "--design", "single", *ARGS)  # fmt: skip
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    scene = json.loads((out / "scenes" / "tiny.json").read_text())
    assert scene["tracker"]["model"] == "ca2d" and len(scene["tracker"]["P0_sd"]) == 6
    rows = read_rows(out / "results.jsonl")
    old = {row["key"] for row in read_rows(base[1] / "results.jsonl")}
    assert rows and not {row["key"] for row in rows} & old
    footage = prepare(Video("tiny", base[0], None, "test"), out).footage
    assert footage.tracker.model == "ca2d"
    r0 = rows[0]
    t = r0["target"]
    sc = place_target(footage, TargetSpec(t["x"], t["y"], t["step"]))
    run = design_runs(sc, load_specs(bundled_specs(), tuple(r0["window"])), ["single"])[0]
    want = {x.property: x for x in run.results}[r0["property"]]
    assert r0["verdict"] == want.verdict
    assert r0["optimum"] == ("inf" if want.optimum == math.inf else want.optimum)


def test_ctrl_c_on_a_two_worker_campaign_prints_the_command_that_resumes_it(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """Issue 29: Ctrl-C (SIGINT to the whole process group, workers included) mid-run:
    no traceback from any process, exit 130, one line with what was kept and the exact
    command that resumes; that command completes the run and does not perceive again."""
    import shlex

    out = tmp_path / "out"  # from scratch: the first run perceives the video
    windows = ["--windows", WINDOWS, "--targets", "all", "--no-truth"]
    cmd = ["lesmc", "campaign", str(base[0]), "--out", str(out), "--workers", "2", *windows]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("LESMC_DEBUG", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", *cmd],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's job
    )
    results = out / "results.jsonl"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if results.exists() and results.stat().st_size > 0:
            break
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C does
    _, err = proc.communicate(timeout=300)
    assert "perceiving" in err  # the first run perceived the video
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted: ") and " results kept in " in last, err
    kept = len(lines(results))
    assert f"interrupted: {kept} results kept in {results}" in last
    resume = shlex.split(last.split("resume with: ", 1)[1])
    assert resume == cmd
    r = subprocess.run(
        [sys.executable, "-m", *resume], cwd=ROOT, env=env, capture_output=True, text=True
    )
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    assert "perceiving" not in r.stderr  # the scene of the first run is reused
    got = [json.loads(x) for x in lines(results)]
    assert 0 < kept < len(got) == len({x["key"] for x in got})


def test_the_summary_gives_the_fewest_frames_exactly_for_count_frames(
    base: tuple[Path, Path], tmp_path: Path
) -> None:
    """A campaign over the bundled robustness spec and one minimising count.frames: each
    count.frames row's attacked frames (counted on its counterexample) equal its optimum,
    the summary's fewest frames is their least (exact) and, for robustness, the least of
    its counterexamples' attacked frames (marked as a bound)."""
    spec = tmp_path / "frames.spec"
    spec.write_text(
        "property frames {\n attack window 6..8\n minimize count.frames\n"
        " subject to dist.sum(0..end) > 120\n holds if optimum > 3\n on x, y\n}\n"
    )
    out = seeded(base, tmp_path)
    r = lesmc("campaign", str(base[0]), "--out", str(out), "--workers", "0", "--design",
              "single", "--spec", str(spec), "--spec", "specs/robustness.spec", "--json",
              *ARGS)  # fmt: skip
    no_trace(r)
    assert r.returncode in (0, 1, 3), r.stderr
    rows = read_rows(out / "results.jsonl")
    frames = [x for x in rows if x["property"] == "frames"]
    robust = [x for x in rows if x["property"] == "robustness"]
    assert frames and robust
    for x in frames:
        assert x["objective_source"] == "frames"
        if x["verdict"] == "violated":
            assert x["attacked_frames"] == x["optimum"]
        else:
            assert x["attacked_frames"] is None
    cells = json.loads(r.stdout)["cells"]["single"]
    got = [x["attacked_frames"] for x in frames if x["attacked_frames"] is not None]
    assert cells["frames"]["fewest_frames"] == min(got, default=None)
    assert cells["frames"]["fewest_frames_exact"] == bool(got)
    got = [x["attacked_frames"] for x in robust if x["attacked_frames"] is not None]
    assert cells["robustness"]["fewest_frames"] == min(got, default=None)
    assert not cells["robustness"]["fewest_frames_exact"]


def test_one_unattacked_track_decides_lasts_and_follows(base: tuple[Path, Path]) -> None:
    """Automatic targets from the truth: with the plain tracker, one unattacked track
    decides both whether it runs through the horizon and whether it stays on the vehicle;
    the answer equals the two separate checks, for the plain tracker and another, and for
    a track that halts before the horizon while its truth track ends earlier still."""
    from collections import Counter

    from lesmc.campaign.targets import _lasts, _lasts_and_follows
    from lesmc.common.errors import UsageError
    from lesmc.experiment.targets import follows, rank_targets
    from lesmc.perception.quality import load_truth
    from lesmc.tracking.targets import rounded
    from lesmc.video.reader import open_frames

    video = base[0]
    footage = prepare(Video("tiny", video, video / "truth.json", "test"), base[1]).footage
    truth = load_truth(str(video / "truth.json"))
    frames = open_frames(video, 5, check=False)
    first = footage.frames[0].step
    tfs = [truth.frames[f.name] for f in frames.paths[first:]]
    seen: Counter[bool] = Counter()
    halted = 0
    for horizon in (2, 4, len(tfs)):  # the last is past the frames: never lasts
        ranked = rank_targets(tfs, (frames.width, frames.height), (1, min(horizon, 5) - 1))
        for c in ranked:
            try:
                scene = place_target(footage, rounded(c.spec.x, c.spec.y, first))
            except UsageError:
                continue
            # the truth track, and one cut short (a vehicle that leaves the frames early)
            for track in (c.truth_track[: horizon + 1], c.truth_track[:2]):
                for design, max_trace in (("single", None), ("joint", None), ("single", 100.0)):
                    s = scene.with_tracker(design=design)
                    if max_trace is not None:  # the track halts after two steps on this video
                        s = s.with_tracker(max_trace=max_trace)
                    want = _lasts(s, horizon) and follows(s, track)
                    got = _lasts_and_follows(s, horizon, track)
                    assert got == want, (c.vid, horizon, len(track), design, max_trace)
                    seen[want] += 1
                    halted += not _lasts(s, horizon) and follows(s, track)
    assert seen[True] and seen[False]
    assert halted  # a track that halts short of the horizon, on the vehicle while it runs
