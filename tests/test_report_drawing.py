"""The report's figures drawn by two processes (lesmc/report/drawing.py): the same bytes as
one after the other, whichever process draws a figure, and nothing left behind when the
copy fails or this process is interrupted."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from lesmc.report import drawing, figures

PARENT = os.getpid()


def _children() -> set[int]:
    """This process's child processes (every thread's), zombies included. Earlier tests
    may have left their own (a Dask cluster's, multiprocessing's resource tracker): each
    test compares with the children it started with."""
    out: set[int] = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        try:
            out |= {int(p) for p in (task / "children").read_text().split()}
        except OSError:
            continue
    return out


def _patches(seed: int) -> tuple[list[tuple[str, np.ndarray]]]:
    rng = np.random.default_rng(seed)
    return ([(f"d{i}", rng.uniform(0, 255, size=(21, 21))) for i in range(2)],)


def _parents_only(text: str) -> bytes:
    """A drawing that fails in the forked copy (and only there)."""
    if os.getpid() != PARENT:
        raise RuntimeError("not in the copy")
    return text.encode()


def _copy_dies(text: str) -> bytes:
    """A drawing during which the forked copy dies without a word."""
    if os.getpid() != PARENT:
        os._exit(7)
    return text.encode()


def test_two_processes_draw_the_bytes_of_one(monkeypatch: pytest.MonkeyPatch) -> None:
    if not drawing.may_fork():
        pytest.skip("this machine gives the process one core")
    before = _children()
    jobs = [(figures.patches, _patches(seed)) for seed in range(5)]
    monkeypatch.setenv("LESMC_DRAW_PROCESSES", "1")
    want = drawing.draw_all(jobs)
    monkeypatch.delenv("LESMC_DRAW_PROCESSES")
    assert drawing.draw_all(jobs) == want
    assert len(set(want)) == 5 and _children() <= before


@pytest.mark.parametrize("draw", [_parents_only, _copy_dies])
def test_what_the_copy_cannot_draw_is_drawn_here(draw: object) -> None:
    if not drawing.may_fork():
        pytest.skip("this machine gives the process one core")
    before = _children()
    jobs = [(draw, (f"figure {i}",)) for i in range(4)]
    assert drawing.draw_all(jobs) == [f"figure {i}".encode() for i in range(4)]  # type: ignore[arg-type]
    assert _children() <= before


def _sleeps_in_the_copy(text: str) -> bytes:
    if os.getpid() != PARENT:
        time.sleep(60)
    raise KeyboardInterrupt


def test_an_interrupt_here_kills_and_reaps_the_copy() -> None:
    if not drawing.may_fork():
        pytest.skip("this machine gives the process one core")
    before = _children()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        drawing.draw_all([(_sleeps_in_the_copy, ("a",)), (_sleeps_in_the_copy, ("b",))])
    assert time.monotonic() - t0 < 30 and _children() <= before


def test_one_process_when_asked(monkeypatch: pytest.MonkeyPatch) -> None:
    """LESMC_DRAW_PROCESSES=1, or a thread other than the main one: no fork."""
    monkeypatch.setenv("LESMC_DRAW_PROCESSES", "1")
    assert not drawing.may_fork()
    jobs = [(_parents_only, (f"f{i}",)) for i in range(3)]
    assert drawing.draw_all(jobs) == [b"f0", b"f1", b"f2"]  # type: ignore[arg-type]
    monkeypatch.delenv("LESMC_DRAW_PROCESSES")
    import threading

    seen: list[bool] = []
    worker = threading.Thread(target=lambda: seen.append(drawing.may_fork()))
    worker.start()
    worker.join()
    assert seen == [False]


def _whose(text: str) -> bytes:
    """A drawing that says which process drew it."""
    return f"{text} by {os.getpid()}".encode()


def test_the_copy_draws_every_second_figure() -> None:
    """The copy is really used: jobs 1, 3, ... come back drawn by another process."""
    if not drawing.may_fork():
        pytest.skip("this machine gives the process one core")
    got = [png.decode() for png in drawing.draw_all([(_whose, (f"f{i}",)) for i in range(5)])]
    here = [g.split(" by ")[1] == str(PARENT) for g in got]
    assert here == [True, False, True, False, True]
    assert [g.split(" by ")[0] for g in got] == [f"f{i}" for i in range(5)]


def test_each_figure_is_freed_before_the_next() -> None:
    """A closed figure is a web of reference cycles; left to the collector's schedule,
    a report's figures pile up (about 100 MB for the default report). With automatic
    collection off, none of the figures drawn may be alive afterwards."""
    import gc

    from matplotlib.figure import Figure

    def alive() -> int:
        return sum(type(o) is Figure for o in gc.get_objects())  # no __class__ lookups

    gc.collect()
    before = alive()
    gc.disable()
    try:
        pngs = drawing.draw_each([(figures.patches, _patches(seed)) for seed in range(3)])
        left = alive()
    finally:
        gc.enable()
    assert len(pngs) == 3 and all(p.startswith(b"\x89PNG") for p in pngs)
    assert left == before
