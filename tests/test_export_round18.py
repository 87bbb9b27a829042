"""Issue 56 items 16, 17, 19, 20 and issue 57's export-format registry, through the real
entry point (tests/cli_run.py) where a user meets them.

Storm (stormpy) is the independent oracle for the PRISM export, as in tests/test_export.py;
the brute force of tests/oracle.py is the independent optimum.
"""

from __future__ import annotations

import dataclasses
import math
import random
from fractions import Fraction
from pathlib import Path

import pytest
from cli_run import lesmc
from oracle import brute_force
from test_engines import MEASURES, _bound_property, _spec

from lesmc.engines.check import check_bound
from lesmc.model.lts import LTS, to_arrays
from lesmc.model.lts_format import save_lts
from lesmc.model.random_models import RandomModelConfig, random_lts

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"

#: The smallest normal double.
SMALLEST_NORMAL = 2.0**-1022


def _no_traceback(r: object) -> None:
    assert "Traceback" not in getattr(r, "stderr", ""), getattr(r, "stderr", "")


# ----------------------------------------------------------- item 16: PRISM rewards


def _shrunk(payoff: float, rng: random.Random, shift: int | None) -> float:
    """``payoff`` times a power of two, never below the smallest normal double: ``shift``
    for every transition, or (None) one drawn per transition among 1, 2^-64, 2^-300 and
    the smallest power that keeps the payoff normal."""
    if payoff == 0.0:
        return 0.0
    deepest = math.frexp(payoff)[1] - 1 + 1022  # payoff * 2^-deepest in [2^-1022, 2^-1021)
    e = min(shift, deepest) if shift is not None else rng.choice([0, 64, 300, deepest])
    out = math.ldexp(payoff, -e)
    assert out >= SMALLEST_NORMAL
    return out


def _tiny_model(seed: int) -> tuple[LTS, tuple]:
    """A random model whose payoffs reach down to the smallest normal double, and a
    property (objective payoff or payoff.mean, any constraint) bound on it."""
    rng = random.Random(seed)
    cfg = RandomModelConfig(
        steps=rng.randint(3, 6),
        width=rng.randint(2, 4),
        branching=(1, rng.randint(2, 4)),
        dim=rng.randint(1, 2),
        halt_prob=rng.choice([0.0, 0.1]),
        covariance=True,
        tree=rng.random() < 0.5,
        integer_values=rng.random() < 0.3,
    )
    lts = random_lts(cfg, seed)
    low = min((t.payoff for t in lts.transitions() if t.payoff > 0), default=1.0)
    shift = rng.choice([None, math.frexp(low)[1] - 1 + 1022, 63, 1000])
    trans = [
        dataclasses.replace(t, payoff=_shrunk(t.payoff, rng, shift)) for t in lts.transitions()
    ]
    model = LTS.from_parts(list(lts.states()), trans, lts.initial, lts.original, lts.components)
    e = model.end
    lo = rng.randint(1, 2)
    hi = rng.randint(lo, e)
    end = rng.randint(hi, e)
    b = rng.randint(0, end)
    obj = rng.choice(["payoff", "payoff", "payoff.mean"])
    con = rng.choice(MEASURES).format(a=rng.randint(0, b), b=b)
    op = rng.choice([">", ">=", "<", "<="])
    norm = rng.choice(["1", "2", "inf"])
    monitor = rng.choice(["", "", "monitor uncertainty tolerance 0.2"])
    return model, (lo, hi, end, obj, con, op, norm, monitor)


def _storm_prism(program: Path) -> Fraction | float:
    """Storm's R{"payoff"}min=? [F "violated"] on the PRISM file, exact rational mode."""
    stormpy = pytest.importorskip("stormpy", reason="stormpy (Storm's bindings) is a test extra")
    prism = stormpy.parse_prism_program(str(program))
    props = stormpy.parse_properties('R{"payoff"}min=? [F "violated"]', prism)
    model = stormpy.build_model[stormpy.Rational](prism, props)
    value = stormpy.model_checking(model, props[0]).get_value(model.initial_states[0])
    return value if isinstance(value, float) else Fraction(str(value))


def _assert_storm_is(storm: Fraction | float, want: float, steps: int) -> None:
    """Storm's exact optimum against a float one: equal up to the rounding of the float's
    path sums (at most ``steps`` roundings, each within 2^-53 of the sum, or 2^-1074
    absolute where the sums are subnormal)."""
    if math.isinf(want) or isinstance(storm, float):
        assert isinstance(storm, float) and math.isinf(storm) and math.isinf(want)
        return
    slack = Fraction(steps + 1, 2**53) * max(storm, Fraction(want)) + Fraction(steps + 1, 2**1074)
    assert abs(storm - Fraction(want)) <= slack, (storm, want)


def _export_and_read(tmp: Path, seed: int) -> tuple[str, Fraction | float, float, float]:
    """The random model ``seed`` saved as .lts, exported with `lesmc export --format prism`
    through the CLI, read by Storm; also the brute force's and lesmc check's optima."""
    model, params = _tiny_model(seed)
    bp = _bound_property(model, params, random.Random(seed).random())
    truth = brute_force(model, bp).optimum
    got = check_bound(to_arrays(model), bp).optimum
    mine = math.inf if got is None else got
    lts, spec, out = tmp / f"m{seed}.lts", tmp / f"p{seed}.spec", tmp / f"m{seed}.prism"
    save_lts(model, lts)
    spec.write_text(_spec(params, bp.bound) + "\n")
    r = lesmc("export", str(lts), "--format", "prism", "--spec", str(spec), "-o", str(out))
    _no_traceback(r)
    assert r.returncode == 0, r.stderr
    return out.read_text(), _storm_prism(out), truth, mine


def test_prism_rewards_down_to_the_smallest_normal_double_read_by_storm(tmp_path: Path) -> None:
    """Item 16 through the CLI: a reward whose exact fraction needs a denominator of 2^63 or
    more (Storm: "expecting <no 64-bit integer overflow>" on the old export) is read by
    Storm's PRISM parser, in exact mode, to the brute force's optimum and lesmc check's."""
    smallest, wide = math.inf, 0
    for seed in (1002, 1003, 1005, 1007):  # optima 0.87, 0, 5e-302, 2e-307
        text, storm, truth, mine = _export_and_read(tmp_path, seed)
        assert mine == pytest.approx(truth, rel=1e-12) or mine == truth
        _assert_storm_is(storm, truth, 8)
        rewards = [r for r in _rewards(text) if r != 0]
        smallest = min([smallest, *rewards])
        wide += sum(q.denominator >= 2**63 for q in rewards)
    assert wide > 0 and smallest < 2 * Fraction(SMALLEST_NORMAL)  # the cases are exercised


def _rewards(program: str) -> list[Fraction]:
    """Each reward of a PRISM program, evaluated exactly here (p/q, m*pow(2.0,e), decimals)."""
    import re

    out = []
    for lit in re.findall(r"\[a\d+\] s=\d+ : ([^;]*);", program):
        m = re.fullmatch(r"(-?\d+)\*pow\(2\.0,(-?\d+)\)", lit)
        if m:
            out.append(Fraction(int(m[1])) * Fraction(2) ** int(m[2]))
        else:
            num, _, den = lit.partition("/")
            out.append(Fraction(num) / Fraction(den or "1"))
    return out


def test_sixty_random_prism_exports_with_tiny_rewards_are_storms_optimum(
    tmp_path: Path,
) -> None:
    """Item 16's done-when: 60 random models whose rewards reach down to 2^-1022, exported
    to PRISM (the export's own function: the CLI's startup sixty times would dominate; the
    test above runs the CLI), all read by Storm in exact mode to the brute force's optimum
    and to lesmc check's; their DRN too."""
    from test_export import storm_optimum

    from lesmc.exporters.drn import to_drn
    from lesmc.exporters.prism import to_prism

    smallest, wide, finite = math.inf, 0, 0
    for seed in range(1000, 1060):
        model, params = _tiny_model(seed)
        bp = _bound_property(model, params, random.Random(seed).random())
        truth = brute_force(model, bp).optimum
        got = check_bound(to_arrays(model), bp).optimum
        assert (math.isinf(truth) and got is None) or got == pytest.approx(truth, rel=1e-12)
        text, _ = to_prism(to_arrays(model), bp)
        path = tmp_path / f"m{seed}.prism"
        path.write_text(text)
        _assert_storm_is(_storm_prism(path), truth, model.end + 1)
        drn, _ = to_drn(to_arrays(model), bp)  # the DRN keeps p/q: Storm reads it exactly
        _assert_storm_is(storm_optimum(drn, tmp_path), truth, model.end + 1)
        rewards = [r for r in _rewards(text) if r != 0]
        smallest = min([smallest, *rewards])
        wide += sum(q.denominator >= 2**63 for q in rewards)
        finite += 0 < truth < math.inf
    assert smallest < 2 * Fraction(SMALLEST_NORMAL) and wide > 100 and finite >= 10


def test_prism_number_writes_what_storm_reads_exactly() -> None:
    """The literal's value is the double's, and no integer in it exceeds 64 bits."""
    import re

    from lesmc.exporters.prism import prism_number

    for x in (2.0, 0.5, 0.1, 3401241647976839 / 2**63, SMALLEST_NORMAL, 5e-324, 1e300, 2.0**70):
        lit = prism_number(x)
        assert _rewards(f"[a0] s=0 : {lit};") == [Fraction(x)]
        assert all(int(n) < 2**63 for n in re.findall(r"\d+", lit))


# ----------------------------------------------------------- item 19: fault checks counted


def test_too_many_fault_checks_are_refused_before_any_check(tmp_path: Path) -> None:
    """Item 19: 40 faults with budget 2 on a window of 3 steps (specs/resilience.spec: 6..8)
    need 40*3 + C(40,2)*3*3 = 7140 checks, more than 5000: refused at once with the count,
    located at the faults block (the old code ran for two minutes before saying so)."""
    import time

    faults = tmp_path / "f40.spec"
    lines = [f"  fault f{i}: outage {1 + i % 3}" for i in range(40)]
    faults.write_text("faults {\n  budget 2\n" + "\n".join(lines) + "\n}\n")
    want = 40 * 3 + math.comb(40, 2) * 3 * 3
    t0 = time.monotonic()
    r = lesmc("check", "tests/scenes/rq1_platoon.json", "specs/resilience.spec",
              "--faults", str(faults), timeout=60)  # fmt: skip
    _no_traceback(r)
    assert r.returncode == 2 and time.monotonic() - t0 < 30, r.stderr
    assert f"{faults}:1:1: these 40 faults with budget 2 need {want} checks" in r.stderr
    # a from A..B range narrows the count: 40 single faults at 1 step each are 40 checks
    one = [f"  fault f{i}: outage 1 from 6..6" for i in range(40)]
    faults.write_text("faults {\n  budget 1\n" + "\n".join(one) + "\n}\n")
    from lesmc.language.parser import parse_spec
    from lesmc.language.semantics import bind
    from lesmc.pipeline.faults import count_checks

    both = parse_spec((ROOT / "specs" / "resilience.spec").read_text() + faults.read_text())
    bp = bind(both, both.properties[0], 10, ("x", "y", "vx", "vy"), True)
    assert both.faults is not None and count_checks(both.faults, bp) == 40


# ----------------------------------------------------------- item 20: .npz details


def _npz_members(tmp: Path) -> list[tuple[str, bytes]]:
    """The tiny model's binary form, as (member name, .npy bytes) in archive order."""
    import zipfile

    from lesmc.model.lts_binary import save_lts_npz
    from lesmc.model.lts_format import load_lts

    good = tmp / "good.npz"
    save_lts_npz(load_lts(TINY / "model.lts"), good)
    with zipfile.ZipFile(good) as z:
        return [(i.filename, z.read(i)) for i in z.infolist()]


def _zip(path: Path, members: list[tuple[str, bytes]]) -> Path:
    import warnings
    import zipfile

    with warnings.catch_warnings():  # zipfile warns about a duplicate name; it is the point
        warnings.simplefilter("ignore")
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
            for name, data in members:
                z.writestr(name, data)
    return path


def _npy(array: object) -> bytes:
    import io

    import numpy as np

    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _check_npz(path: Path) -> object:
    return lesmc("check", str(path), str(TINY / "properties.spec"))


def test_npz_duplicate_members_big_endian_and_crafted_shapes_are_named(tmp_path: Path) -> None:
    """Item 20 through the CLI: an archive holding payoff.npy twice (all NaN, then valid:
    the last used to win) is refused; a big-endian payoff is named as such (not "must be
    float64, got float64"); a crafted shape names the member, not numpy's parser."""
    import io

    import numpy as np

    members = _npz_members(tmp_path)
    payoff = dict(members)["payoff.npy"]
    n = len(np.load(io.BytesIO(payoff)))
    nan = _npy(np.full(n, np.nan))
    at = [m for m, _ in members].index("payoff.npy")
    dup = _zip(tmp_path / "dup.npz", [*members[:at], ("payoff.npy", nan), *members[at:]])
    r = _check_npz(dup)
    _no_traceback(r)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert f"{dup}: array 'payoff': the archive holds it twice" in r.stderr
    # the same archive without the duplicate checks (the fault was the duplicate)
    assert _check_npz(_zip(tmp_path / "ok.npz", members)).returncode in (0, 1)

    big = np.load(io.BytesIO(payoff)).astype(">f8")
    swapped = [(m, _npy(big) if m == "payoff.npy" else d) for m, d in members]
    r = _check_npz(_zip(tmp_path / "big.npz", swapped))
    _no_traceback(r)
    assert r.returncode == 2 and "got float64 big-endian (" in r.stderr, r.stderr
    assert "must be float64 little-endian" in r.stderr or "must be float64 big" in r.stderr

    for shape in ("(f(),)", "(2**70,)", "(-1,)"):
        h = "{'descr': '<f8', 'fortran_order': False, 'shape': " + shape + ", }"
        h += " " * (-(10 + len(h) + 1) % 64) + "\n"
        npy = b"\x93NUMPY\x01\x00" + len(h).to_bytes(2, "little") + h.encode() + bytes(8)
        crafted = [(m, npy if m == "payoff.npy" else d) for m, d in members]
        r = _check_npz(_zip(tmp_path / "shape.npz", crafted))
        _no_traceback(r)
        assert r.returncode == 2 and "array 'payoff': its .npy header is not numpy's" in r.stderr
        assert "ast." not in r.stderr and "0x" not in r.stderr, r.stderr


# ----------------------------------------------------------- item 17: export's words


def _storm_drn(path: Path, query: str) -> Fraction | float:
    """Storm's answer to ``query`` on a DRN file, exact rational mode."""
    stormpy = pytest.importorskip("stormpy", reason="stormpy (Storm's bindings) is a test extra")
    model = stormpy.build_model_from_drn[stormpy.Rational](str(path))
    value = stormpy.model_checking(model, stormpy.parse_properties(query)[0])
    got = value.get_value(model.initial_states[0])
    return got if isinstance(got, float) else Fraction(str(got))


def test_help_and_behaviour_agree_on_objectives_that_are_no_sum(tmp_path: Path) -> None:
    """Item 17: the help no longer says such properties "are refused"; it says what the
    command does (writes the MDP without the reward model, with a note; --strict
    refuses), and the query the command then names is one Storm answers on the file: the
    tiny model's resilience optimum is 5 by hand (tests/golden/README.md), finite, so
    some path violates: Pmax > 0. (The reward query fails there: no reward model.)"""
    import json

    help_text = lesmc("export", "--help").stdout
    assert "are refused" not in help_text
    flat = " ".join(help_text.split())
    assert "written without the reward model" in flat and "--strict refuses it" in flat
    out = tmp_path / "r.drn"
    r = lesmc("export", str(TINY / "model.lts"), "--format", "drn", "--spec",
              str(TINY / "properties.spec"), "--property", "resilience", "-o", str(out),
              "--json")  # fmt: skip
    _no_traceback(r)
    assert r.returncode == 0 and "the reward model is not" in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    assert doc["storm_property"] == doc["prism_property"] == 'Pmax=? [F "violated"]'
    assert doc["storm_property"] in r.stderr and doc["storm_property"] in out.read_text()
    assert _storm_drn(out, doc["storm_property"]) > 0
    r = lesmc("export", str(TINY / "model.lts"), "--format", "drn", "--spec",
              str(TINY / "properties.spec"), "--property", "resilience", "-o",
              str(tmp_path / "s.drn"), "--strict")  # fmt: skip
    _no_traceback(r)
    assert r.returncode == 2 and not (tmp_path / "s.drn").exists()


def test_a_scene_is_exported_for_its_propertys_window(tmp_path: Path) -> None:
    """Item 17: with --spec, a scene needs no --window (the property's attack window is
    used: the same file as with --window 6..8); a --window that contradicts the property
    is refused, located at its attack-window clause, and nothing is written."""
    scene = ROOT / "tests" / "scenes" / "rq4_merge.json"
    spec = ROOT / "tests" / "scenes" / "rq4_merge.spec"
    line = next(
        i for i, t in enumerate(spec.read_text().splitlines(), 1) if "attack window 6..8" in t
    )
    column = spec.read_text().splitlines()[line - 1].index("attack") + 1
    args = ["export", str(scene), "--format", "prism", "--spec", str(spec),
            "--property", "robustness"]  # fmt: skip
    r = lesmc(*args, "-o", str(tmp_path / "a.prism"))
    _no_traceback(r)
    assert r.returncode == 0, r.stderr
    r = lesmc(*args, "--window", "6..8", "-o", str(tmp_path / "b.prism"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "a.prism").read_bytes() == (tmp_path / "b.prism").read_bytes()
    r = lesmc(*args, "--window", "5..8", "-o", str(tmp_path / "c.prism"))
    _no_traceback(r)
    assert r.returncode == 2 and not (tmp_path / "c.prism").exists()
    assert f"{spec}:{line}:{column}: --window 5..8 contradicts the attack window 6..8" in r.stderr
    # without --spec a scene still needs --window
    r = lesmc("export", str(scene), "--format", "dot", "-o", str(tmp_path / "d.dot"))
    assert r.returncode == 2 and "give --window" in r.stderr


def test_the_states_printed_are_the_files(tmp_path: Path) -> None:
    """Item 17: "wrote tiny.drn (drn, N states" with N the file header's @nr_states (the
    MDP's), and for PRISM the number of values of its variable s."""
    import re

    for fmt in ("drn", "prism"):
        out = tmp_path / f"tiny.{fmt}"
        r = lesmc("export", str(TINY / "model.lts"), "--format", fmt, "--spec",
                  str(TINY / "properties.spec"), "--property", "robustness",
                  "-o", str(out))  # fmt: skip
        _no_traceback(r)
        assert r.returncode == 0, r.stderr
        text = out.read_text()
        if fmt == "drn":
            n = int(text.split("@nr_states\n")[1].split()[0])
        else:
            n = int(re.search(r"s : \[0\.\.(\d+)\]", text)[1]) + 1  # type: ignore[index]
        assert f"wrote {out} ({fmt}, {n} states" in r.stdout + r.stderr
        assert n != 13  # the model's states: the test tells the two apart


# ----------------------------------------------------------- issue 57: the format registry


def test_the_docs_table_is_the_registry() -> None:
    from lesmc.exporters import formats

    page = (ROOT / "docs" / "export.md").read_text()
    marker = "<!-- generated: lesmc.exporters.formats.docs_table() -->\n"
    assert marker in page
    table = page.split(marker, 1)[1].split("\n\n", 1)[0]
    assert table == formats.docs_table()
    rows = [r for r in table.splitlines()[2:]]
    assert [r.split("`")[1] for r in rows] == list(formats.names())


#: Where the format names were spelled before the registry (issue 57): the command line,
#: the API, the package's names, the schemas.
_SPELLED = [
    *sorted((ROOT / "lesmc" / "cli").glob("*.py")),
    ROOT / "lesmc" / "api.py",
    ROOT / "lesmc" / "__init__.py",
    *sorted((ROOT / "lesmc" / "schemas").glob("*")),
]


def test_format_names_appear_nowhere_but_the_registry() -> None:
    """No module of the command line, the API or the schemas spells a format name (the
    format writers' own modules, lesmc/exporters/*.py, speak of their format)."""
    import re

    from lesmc.exporters import formats

    names = "|".join(map(re.escape, formats.names()))
    pattern = re.compile(rf"(?<![\w-])['\"]?({names})['\"]?(?![\w-])", re.IGNORECASE)
    found = []
    for path in _SPELLED:
        if path.is_dir() or path.suffix not in (".py", ".json"):
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            for m in pattern.finditer(line):
                word = m.group(0)
                if word.strip("'\"").lower() == "json" and not (
                    word.startswith(("'", '"')) and word.endswith(("'", '"'))
                ):
                    continue  # --json, .json, JSON the word: not the format's name
                found.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert found == []


def test_the_count_can_fail() -> None:
    """The scan above finds a name where one is spelled."""
    import re

    from lesmc.exporters import formats

    names = "|".join(map(re.escape, formats.names()))
    pattern = re.compile(rf"(?<![\w-])['\"]?({names})['\"]?(?![\w-])", re.IGNORECASE)
    assert pattern.search('FORMATS = ("dot", "graphml")')
    assert pattern.search("--format drn|prism")
    assert not pattern.search("prism_property and lesmc.exporters.graphs")


def test_a_registered_format_reaches_the_cli_schema_and_api(tmp_path: Path) -> None:
    """Adding a format is one module and one registry line: a toy format registered in a
    fresh interpreter is a --format choice, takes only what it declares, writes through
    the real entry point, and is in the schema's enum."""
    import json
    import os
    import subprocess
    import sys

    module = tmp_path / "toyformat.py"
    module.write_text(
        "def write(model, path, request):\n"
        "    open(path, 'w').write(f'{model.n_states} states\\n')\n"
        "    return {}\n"
    )
    run = (
        "import sys\n"
        "from lesmc.exporters import formats\n"
        "formats.register(formats.ExportFormat('toy', '.toy', 'a test', 'states counted', "
        "'toyformat:write'))\n"
        "from lesmc.cli.entry import main\n"
        "sys.argv = ['lesmc', *sys.argv[1:]]\n"
        "main()\n"
    )
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}

    def toy(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-c", run, *args], capture_output=True,
                              text=True, env=env, cwd=ROOT, timeout=120)  # fmt: skip

    out = tmp_path / "m.toy"
    r = toy("export", str(TINY / "model.lts"), "--format", "toy", "-o", str(out), "--json")
    _no_traceback(r)
    assert r.returncode == 0, r.stderr
    assert out.read_text() == "13 states\n"
    doc = json.loads(r.stdout)
    assert doc["export_format"] == "toy"
    check = run.split("from lesmc.cli")[0] + (
        "import json\n"
        "from lesmc.schemas import schema, errors\n"
        "s = schema('export')\n"
        "print(json.dumps(errors(json.loads(sys.stdin.read()), s, s)))\n"
    )
    got = subprocess.run([sys.executable, "-c", check], input=r.stdout, capture_output=True,
                         text=True, env=env, cwd=ROOT, timeout=120)  # fmt: skip
    assert got.returncode == 0 and json.loads(got.stdout) == [], got.stderr + got.stdout
    r = toy("export", "--help")
    assert "toy" in r.stdout and "a test: states counted" in r.stdout
    r = toy("export", str(TINY / "model.lts"), "--format", "toy", "-o", str(out),
            "--max-nodes", "3")  # fmt: skip
    assert r.returncode == 2 and "--max-nodes limits dot, drn or prism only" in r.stderr
    from lesmc.schemas import errors, schema

    plain = schema("export")  # here, without the toy: the same document is refused
    assert errors(doc, plain, plain) != []
    enum = plain["$defs"]["export_formats"]["enum"]
    assert enum == ["dot", "graphml", "json", "drn", "prism"]
