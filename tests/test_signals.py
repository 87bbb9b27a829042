"""Signals, a closed stdout and budgets: clean exits, nothing left behind, nothing lost.

Each run is the real entry point (``python -m lesmc``) in a fresh process. A
preamble hooks one stage (unfolding, writing the model, writing the report,
importing numpy) to print READY and wait; the test then sends the signal, so
the signal always lands in that stage, whatever the machine's speed.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lesmc.cli.signals import EXIT_BROKEN_PIPE
from lesmc.common.files import atomic_write_text, write_json

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"
TINY = ROOT / "tests" / "golden" / "tiny"

HOOKS = {
    # inside build_model, before a batch once some states exist
    "unfolding": """
import lesmc.unfold.unfold as u
_orig = u.build_model
def build_model(*a, **k):
    outer = k.get("on_batch")
    def on_batch(m):
        if m.n_states > 20:
            ready()
        if outer:
            outer(m)
    k["on_batch"] = on_batch
    return _orig(*a, **k)
u.build_model = build_model
""",
    # after the first chunks of a JSON output went to its temporary file
    "writing": """
import lesmc.common.files as f
_chunks = f._json_chunks
def _json_chunks(value, depth):
    for i, c in enumerate(_chunks(value, depth)):
        yield c
        if i == 3 and depth == 0:
            ready()
f._json_chunks = _json_chunks
""",
    # while the report draws its first frame image
    "report": """
import lesmc.report.html as h
_write = h.write_report
def write_report(doc, out_dir, image_for=None, files=None, store=None):
    def image(i):
        ready()
    return _write(doc, out_dir, image, files, store)
h.write_report = write_report
""",
    # while the staged report is moved into --out (signals are held there for a moment)
    "publishing": """
import contextlib
import lesmc.report.staging as s
_held = s._signals_held
@contextlib.contextmanager
def _signals_held():
    with _held():
        sys.stderr.write("READY\\n")
        sys.stderr.flush()
        time.sleep(1.0)
        yield
s._signals_held = _signals_held
""",
    # while numpy is being imported (before any lesmc work)
    "import": """
class Hold:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            ready()
sys.meta_path.insert(0, Hold())
""",
    # while the default video renders in its child process (verify imports torch then)
    "rendering": """
import lesmc.experiment.default_video as v
def import_perception():
    ready()
v.import_perception = import_perception
""",
    # every batch of the unfolding takes 0.2 s (for the budget tests)
    "slow": """
import lesmc.unfold.unfold as u
_orig = u.build_model
def build_model(*a, **k):
    outer = k.get("on_batch")
    def on_batch(m):
        time.sleep(0.2)
        if outer:
            outer(m)
    k["on_batch"] = on_batch
    return _orig(*a, **k)
u.build_model = build_model
""",
}
_PRELUDE = """import sys, time
def ready():
    sys.stderr.write("READY\\n")
    sys.stderr.flush()
    time.sleep(120)
"""


def start(hook: str, args: list[str], cwd: Path) -> subprocess.Popen[str]:
    code = (
        f"{_PRELUDE}{HOOKS[hook]}"
        "from lesmc.cli.entry import main\n"
        "sys.argv = ['lesmc', *sys.argv[1:]]\n"
        "main()\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("LESMC_DEBUG", None)
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def interrupt(proc: subprocess.Popen[str], signum: int) -> tuple[int, str]:
    """Wait for READY, send ``signum``; the exit status and the rest of stderr."""
    assert proc.stderr is not None
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if line.strip() == "READY":
            break
    else:
        proc.wait(timeout=60)
        pytest.fail(f"the hooked stage was not reached: {''.join(seen)}")
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def files(directory: Path) -> dict[str, str]:
    """Every file under ``directory`` (hidden ones included) and its text."""
    return {
        str(p.relative_to(directory)): p.read_text(errors="replace")
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


STATUS = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated")}


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["INT", "TERM"])
@pytest.mark.parametrize("stage", ["unfolding", "writing"])
def test_build_stops_cleanly_and_leaves_the_old_model(
    tmp_path: Path, stage: str, signum: int
) -> None:
    (tmp_path / "m.lts").write_text("old model\n")
    args = ["build", str(SCENES / "rq1_platoon.json"), "--window", "6..8", "-o", "m.lts"]
    code, err = interrupt(start(stage, args, tmp_path), signum)
    assert (code, err.strip()) == STATUS[signum]
    assert files(tmp_path) == {"m.lts": "old model\n"}


@pytest.mark.parametrize(
    ("signum", "stage"), [(signal.SIGTERM, "unfolding"), (signal.SIGINT, "report")]
)
def test_verify_stops_cleanly_and_leaves_the_old_report(
    tmp_path: Path, signum: int, stage: str
) -> None:
    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)
    old = {"report.html": "old", "results.json": "{}", "figures/a.png": "png"}
    for name, text in old.items():
        (out / name).write_text(text)
    args = ["verify", "--scene", str(SCENES / "rq1_platoon.json"), "--out", "out"]
    code, err = interrupt(start(stage, [*args, "--design", "single"], tmp_path), signum)
    assert code == STATUS[signum][0], err
    assert "Traceback" not in err
    # one line: what was kept, and the command that resumes (this one)
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"{STATUS[signum][1]}: out holds the previous report"), err
    assert last.endswith(f"resume with: lesmc {' '.join(args)} --design single"), err
    assert files(out) == old


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["INT", "TERM"])
def test_a_signal_while_the_video_renders_aside_stops_the_child_and_leaves_no_frame(
    tmp_path: Path, signum: int
) -> None:
    """verify renders the default video in a child process while it imports torch: a signal
    then stops the child, waits for it and removes its staging directory."""
    code, err = interrupt(start("rendering", ["verify", "--out", "out"], tmp_path), signum)
    assert code == STATUS[signum][0], err
    assert "Traceback" not in err
    assert [p for p in (tmp_path / "out").rglob("*") if not p.is_dir()] == []
    assert [p for p in (tmp_path / "out").rglob(".synth.*")] == []
    assert rendering_children(tmp_path) == []


def rendering_children(under: Path) -> list[int]:
    """Processes rendering a video (``lesmc.video.aside``) into a directory under ``under``."""
    found = []
    for pid in Path("/proc").iterdir():
        try:
            cmd = (pid / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if "lesmc.video.aside" in cmd and any(a.startswith(str(under)) for a in cmd):
            found.append(int(pid.name))
    return found


@pytest.mark.parametrize(
    ("signum", "fresh"), [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["INT", "TERM"]
)
def test_a_signal_while_publishing_leaves_all_new_outputs(
    tmp_path: Path, signum: int, fresh: bool
) -> None:
    """Issue 33: the signal waits for the renames; --out is then all new (results.json
    naming a scene that exists), the exit code is the signal's, no traceback. Other
    threads run meanwhile (the progress logger's), so a thread signal mask would not do."""
    out = tmp_path / "out"
    if not fresh:
        (out / "figures").mkdir(parents=True)
        for name in ("report.html", "results.json", "scene.json", "figures/a.png"):
            (out / name).write_text("old")
    args = ["verify", "--scene", str(SCENES / "rq1_platoon.json"), "--out", "out"]
    code, err = interrupt(start("publishing", [*args, "--design", "single"], tmp_path), signum)
    assert code == STATUS[signum][0], err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    results = json.loads((out / "results.json").read_text())
    assert results["format"] == "lesmc-results" and Path(results["meta"]["scene"]).is_file()
    assert (out / "report.html").read_text().startswith("<!DOCTYPE html>")
    assert sorted(p.name for p in (out / "figures").iterdir() if p.name != "a.png")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]  # no staging left


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["INT", "TERM"])
def test_a_signal_during_imports_exits_without_a_traceback(tmp_path: Path, signum: int) -> None:
    args = ["check", str(TINY / "model.lts"), str(TINY / "properties.spec")]
    code, err = interrupt(start("import", args, tmp_path), signum)
    assert (code, err.strip()) == STATUS[signum]


def test_a_closed_stdout_exits_141_not_1() -> None:
    read, write = os.pipe()
    os.close(read)
    try:
        for args in (
            ["check", str(TINY / "model.lts"), str(TINY / "properties.spec")],
            ["check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--json"],
            ["--help"],
        ):
            r = subprocess.run(
                [sys.executable, "-m", "lesmc", *args],
                stdout=write,
                stderr=subprocess.PIPE,
                text=True,
                cwd=ROOT,
                timeout=300,
            )
            assert r.returncode == EXIT_BROKEN_PIPE == 141, (args, r.stderr)
            # progress log lines only (stderr is not a terminal): no error, no traceback
            assert all(line.startswith("lesmc check: ") for line in r.stderr.splitlines())
    finally:
        os.close(write)


# --- budgets --------------------------------------------------------------------------------


def run(hook: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    proc = start(hook, args, cwd)
    out, err = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


@pytest.mark.parametrize(
    ("budget", "message"),
    [
        # on a loaded machine the half second can run out before the unfolding starts
        (["--timeout", "0.5"], "--timeout 0.5 s ran out while "),
        (["--max-states", "30"], "--max-states 30 ran out while unfolding"),
        (["--max-memory", "1M"], "--max-memory 1.0 MiB ran out while loading the scene"),
    ],
)
def test_build_budgets_stop_with_exit_3_and_write_nothing(
    tmp_path: Path, budget: list[str], message: str
) -> None:
    args = ["build", str(SCENES / "rq1_platoon.json"), "--window", "6..8", "-o", "m.lts"]
    r = run("slow", [*args, *budget], tmp_path)
    assert r.returncode == 3, r.stderr
    assert message in r.stderr and "nothing was written" in r.stderr
    assert files(tmp_path) == {}


def test_verify_budget_stops_while_building(tmp_path: Path) -> None:
    args = ["verify", "--scene", str(SCENES / "rq1_platoon.json"), "--out", "out"]
    r = run("slow", [*args, "--design", "single", "--timeout", "0.5"], tmp_path)
    assert r.returncode == 3, r.stderr
    assert "--timeout" in r.stderr and "Traceback" not in r.stderr
    assert files(tmp_path) == {}


@pytest.mark.parametrize("verb", ["build", "verify", "check"])
@pytest.mark.parametrize("value", ["nan", "inf", "-1", "0"])
def test_non_finite_or_non_positive_timeouts_are_refused(verb: str, value: str) -> None:
    args = {
        "build": ["build", str(SCENES / "rq1_platoon.json"), "--window", "6..8", "-o", "x.lts"],
        "verify": ["verify", "--scene", str(SCENES / "rq1_platoon.json")],
        "check": ["check", str(TINY / "model.lts"), str(TINY / "properties.spec")],
    }[verb]
    r = subprocess.run(
        [sys.executable, "-m", "lesmc", *args, "--timeout", value],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert r.returncode == 2 and "--timeout" in r.stderr and "Traceback" not in r.stderr


# --- files ------------------------------------------------------------------------------------


def test_written_files_get_the_umask_or_keep_their_mode(tmp_path: Path) -> None:
    old = os.umask(0o027)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        write_json(tmp_path / "b.json", {"a": [1]})
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o640
    assert (tmp_path / "b.json").stat().st_mode & 0o777 == 0o640
    (tmp_path / "a.txt").chmod(0o604)
    atomic_write_text(tmp_path / "a.txt", "y")
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o604
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.json"]


def test_a_budget_spent_while_the_video_renders_aside_stops_the_child(tmp_path: Path) -> None:
    """--max-memory below what torch's import takes: the budget runs out at the first frame
    the child reports; verify stops the child and exits 3 with nothing written."""
    from cli_run import lesmc

    r = lesmc("verify", "--out", "out", "--max-memory", "150M", cwd=tmp_path, timeout=600)
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    assert "ran out while rendering the default video; nothing was written" in r.stderr
    assert [p for p in (tmp_path / "out").rglob("*") if not p.is_dir()] == []
    assert rendering_children(tmp_path) == []
