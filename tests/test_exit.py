"""Exit statuses that cannot lie: a bug exits 4 (never 1, "violated"), Ctrl-C exits 130.

Every case goes through the console entry point ``lesmc.cli.main.main`` with a
command's internals patched to fail; the subprocess cases run it exactly as the
installed ``lesmc`` script does.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import NoReturn

import pytest

from lesmc.cli.main import main
from lesmc.results.exit import EXIT_INTERNAL, EXIT_INTERRUPTED

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"
CHECK = ["check", str(TINY / "model.lts"), str(TINY / "properties.spec")]
KNAPSACK = ["reduce", "knapsack", "items.csv", "--demand", "3", "-o", "k.lts"]
INTERNAL = (
    "lesmc: internal error: RuntimeError: boom in the engine "
    "(please report this, with the command line)"
)


def run_main(argv: list[str]) -> int:
    with pytest.raises(SystemExit) as info:
        main(argv)
    code = info.value.code
    assert isinstance(code, int)
    return code


def _boom(*args: object, **kwargs: object) -> NoReturn:
    raise RuntimeError("boom in\nthe engine")


@pytest.mark.parametrize(
    ("argv", "target"),
    [(CHECK, "lesmc.api.load_spec"), (KNAPSACK, "lesmc.model.knapsack.read_items")],
    ids=["check", "reduce knapsack"],
)
def test_internal_error_exits_4_with_one_line(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    target: str,
) -> None:
    monkeypatch.delenv("LESMC_DEBUG", raising=False)
    monkeypatch.setattr(target, _boom)
    assert run_main(argv) == EXIT_INTERNAL == 4
    out, err = capsys.readouterr()
    assert err.splitlines() == [INTERNAL]
    assert "Traceback" not in out + err


def test_lesmc_debug_adds_the_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("LESMC_DEBUG", "1")
    monkeypatch.setattr("lesmc.api.load_spec", _boom)
    assert run_main(CHECK) == 4
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "_boom" in err
    assert err.splitlines()[-1] == INTERNAL


def test_keyboard_interrupt_exits_130(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def interrupt(*args: object, **kwargs: object) -> NoReturn:
        raise KeyboardInterrupt

    monkeypatch.setattr("lesmc.api.load_spec", interrupt)
    assert run_main(CHECK) == EXIT_INTERRUPTED == 130
    out, err = capsys.readouterr()
    assert err.strip() == "interrupted"
    assert "Traceback" not in out + err


def test_eof_error_is_internal_not_an_interrupt(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """click turns EOFError into Abort; a truncated file is a bug to report, not a Ctrl-C."""

    def eof(*args: object, **kwargs: object) -> NoReturn:
        raise EOFError("Ran out of input")

    monkeypatch.delenv("LESMC_DEBUG", raising=False)
    monkeypatch.setattr("lesmc.api.load_spec", eof)
    assert run_main(CHECK) == 4
    assert "lesmc: internal error: EOFError: Ran out of input" in capsys.readouterr().err


def test_user_errors_still_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_main(["check", "no-such-model.lts", str(TINY / "properties.spec")]) == 2
    assert "internal error" not in capsys.readouterr().err


# The same through a fresh interpreter, as the installed script runs it: patches are
# applied by a preamble before ``main()``.

_PREAMBLE = {
    "raise": (
        "import lesmc.language.parser as p\n"
        "def boom(*a, **k):\n"
        "    raise RuntimeError('boom in the engine')\n"
        "p.load_spec = boom\n"
    ),
    # KeyboardInterrupt while a command imports its pipeline (imports are lazy now)
    "interrupt-import": (
        "import sys\n"
        "class Interrupt:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'lesmc.engines.check':\n"
        "            raise KeyboardInterrupt\n"
        "        return None\n"
        "sys.meta_path.insert(0, Interrupt())\n"
    ),
}


def run_script(
    preamble: str, args: list[str], debug: bool = False
) -> subprocess.CompletedProcess[str]:
    code = (
        f"{_PREAMBLE[preamble]}"
        "import sys\n"
        "from lesmc.cli.main import main\n"
        "sys.argv = ['lesmc', *sys.argv[1:]]\n"
        "sys.exit(main())\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "LESMC_DEBUG"}
    if debug:
        env["LESMC_DEBUG"] = "1"
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=300,
    )


def test_entry_point_internal_error_subprocess() -> None:
    r = run_script("raise", CHECK)
    assert r.returncode == 4, r.stderr
    assert r.stderr.splitlines() == [INTERNAL]
    assert r.stdout == ""


def test_entry_point_internal_error_debug_subprocess() -> None:
    r = run_script("raise", CHECK, debug=True)
    assert r.returncode == 4
    assert r.stderr.startswith("Traceback (most recent call last)")
    assert r.stderr.splitlines()[-1] == INTERNAL


def test_interrupt_during_lazy_imports_exits_130() -> None:
    r = run_script("interrupt-import", CHECK)
    assert r.returncode == 130, r.stderr
    assert r.stderr.strip() == "interrupted"
    assert "Traceback" not in r.stderr
