"""Batches side by side, each on one torch thread (lesmc/perception/threads.py, in_lanes).

The networks' batches run on one torch thread each, so what perception computes does
not depend on how many cores were free: checked against the batches run one by one
on one thread by the attack's own primitive, and with two threads against one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import torch

from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import deepfool, margin, payoffs
from lesmc.perception.cnn import load_nets
from lesmc.perception.detector import dr_probability, lp_maps
from lesmc.perception.threads import all_torch_threads, in_lanes, torch_lanes
from lesmc.video.synth import SynthConfig


@pytest.fixture
def two_threads() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_lanes_keep_the_order_and_run_each_item_on_one_torch_thread(two_threads: None) -> None:
    seen: list[tuple[int, str, int]] = []
    lock = threading.Lock()

    def item(x: int) -> int:
        time.sleep(0.01 * (7 - x))  # later items finish first
        with lock:
            seen.append((x, threading.current_thread().name, torch.get_num_threads()))
        return x * x

    assert in_lanes(item, range(8)) == [x * x for x in range(8)]
    assert {n for _, _, n in seen} == {1}
    assert len({name for _, name, _ in seen}) == 2  # side by side on two threads
    assert torch.get_num_threads() == 2  # restored


def test_lanes_one_after_the_other_still_on_one_torch_thread(two_threads: None) -> None:
    names: set[str] = set()

    def item(x: int) -> int:
        names.add(threading.current_thread().name)
        assert torch.get_num_threads() == 1
        return x + 2

    assert in_lanes(item, [10, 20, 30], side_by_side=False) == [12, 22, 32]
    assert names == {threading.current_thread().name}
    assert torch.get_num_threads() == 2
    assert in_lanes(item, []) == []


def test_a_call_from_a_lane_runs_in_that_lane(two_threads: None) -> None:
    inner: dict[int, set[str]] = {}

    def item(x: int) -> int:
        here = threading.current_thread().name

        def sub(y: int) -> int:
            inner.setdefault(x, set()).add(threading.current_thread().name)
            return y

        assert in_lanes(sub, range(4)) == [0, 1, 2, 3]
        assert inner[x] == {here}  # no lanes within lanes: the cores are taken
        return x

    assert in_lanes(item, range(4)) == [0, 1, 2, 3]


def test_a_block_holds_one_torch_thread_and_its_calls_keep_their_lanes(two_threads: None) -> None:
    """perceive_all holds the setting over its frames: calls inside do not switch
    torch's thread count, and still run side by side on the cores it had."""
    names: set[str] = set()

    def item(x: int) -> int:
        names.add(threading.current_thread().name)
        time.sleep(0.01)
        return x

    with torch_lanes() as lanes:
        assert lanes == 2 and torch.get_num_threads() == 1
        assert in_lanes(item, range(6)) == list(range(6))
        assert torch.get_num_threads() == 1
    assert len(names) == 2
    assert torch.get_num_threads() == 2


def test_an_item_that_fails_cancels_those_not_started(two_threads: None) -> None:
    started: list[int] = []

    def item(x: int) -> int:
        started.append(x)
        if x == 1:
            raise KeyboardInterrupt
        time.sleep(0.05)
        return x

    with pytest.raises(KeyboardInterrupt):
        in_lanes(item, range(40))
    assert len(started) < 10
    assert torch.get_num_threads() == 2


def _windows() -> np.ndarray:
    """N_dr windows the detector accepts on a small synthetic video (real attack targets)."""
    from lesmc.perception.detector import Detector
    from lesmc.video.synth import frames

    det = Detector(load_nets())
    for img, _ in frames(SynthConfig(frames=8, width=640, height=640, seed=21)):
        res = det.push(img)
        if res is not None:
            return res[1].windows
    raise AssertionError("the detector scored no frame")


def test_payoffs_in_lanes_are_the_batches_attacked_one_by_one_on_one_thread(
    two_threads: None,
) -> None:
    """The oracle runs DeepFool batch by batch on one torch thread, as the attack did
    on a machine with one free core; payoffs() on two threads must give the same bits,
    and the same with torch limited to one thread."""
    nets = load_nets()
    win = np.concatenate([_windows()] * 3)  # several batches of 16
    cfg = AttackConfig(batch=16)
    t = threshold_logit(nets.settings.delta_dr)
    torch.set_num_threads(1)
    expect = []
    for a in range(0, len(win), cfg.batch):
        x0 = torch.from_numpy(win[a : a + cfg.batch])
        x_adv, _ = deepfool(nets.dr, x0, t, cfg)
        with torch.no_grad():
            ok = (margin(nets.dr, x_adv, t) <= 0).numpy()
        d = (x_adv - x0).numpy().astype(np.float64).reshape(len(x0), -1)
        expect.append(np.where(ok, np.sqrt((d**2).sum(axis=1)), np.inf))
    torch.set_num_threads(2)
    got = payoffs(nets.dr, win, nets.settings.delta_dr, cfg)
    assert np.array_equal(got.payoff, np.concatenate(expect))
    torch.set_num_threads(1)
    alone = payoffs(nets.dr, win, nets.settings.delta_dr, cfg)
    assert np.array_equal(alone.payoff, got.payoff)
    assert np.array_equal(alone.perturbation, got.perturbation)


def test_network_scores_do_not_depend_on_the_free_cores(two_threads: None) -> None:
    nets = load_nets()
    rng = np.random.default_rng(5)
    dr = rng.random((900, 4, 21, 21), dtype=np.float32)
    lp = rng.random((140, 4, 45, 45), dtype=np.float32)
    torch.set_num_threads(1)
    with torch.inference_mode():
        p1 = [torch.softmax(nets.dr(torch.from_numpy(dr[a : a + 384])), 1)[:, 1].numpy()
              for a in range(0, 900, 384)]  # fmt: skip
        m1 = [nets.lp(torch.from_numpy(lp[a : a + 64])).numpy() for a in range(0, 140, 64)]
    torch.set_num_threads(2)
    assert np.array_equal(dr_probability(nets, dr), np.concatenate(p1))
    assert np.array_equal(dr_probability(nets, dr, side_by_side=False), np.concatenate(p1))
    assert np.array_equal(lp_maps(nets, lp), np.concatenate(m1))
    assert dr_probability(nets, dr[:0]).shape == (0,)
    assert lp_maps(nets, lp[:0]).shape == (0, 15, 15)


def test_certification_inside_perceptions_block_gets_the_cores_back(two_threads: None) -> None:
    """perceive --certify certifies inside perception's one-thread block: its large
    propagations run on the block's lanes again, then the block's setting returns."""
    seen: list[int] = []
    with torch_lanes():
        with all_torch_threads():
            seen.append(torch.get_num_threads())
        seen.append(torch.get_num_threads())

        def item(_: int) -> int:
            with all_torch_threads():  # on a lane: stays at one thread
                return torch.get_num_threads()

        seen += in_lanes(item, range(2))
    with all_torch_threads():  # outside any block: unchanged
        seen.append(torch.get_num_threads())
    assert seen == [2, 1, 1, 1, 2]


# ---------------------------------------------------------------- free cores


def _readings(busy: list[int], total: int = 10) -> tuple[dict, dict]:
    """Two /proc/stat readings (per core: idle ticks, all ticks) with ``busy`` ticks per
    core out of ``total`` between them."""
    before = {c: (1000, 5000) for c in range(len(busy))}
    after = {c: (1000 + total - b, 5000 + total) for c, b in enumerate(busy)}
    return before, after


@pytest.mark.parametrize(
    ("busy", "own", "free"),
    [
        ([0, 0], 0.0, 2),  # idle
        ([9, 0], 0.0, 1),  # another process on one core
        ([9, 9], 0.0, 1),  # every core busy: still one
        ([9, 0], 9.0, 2),  # the busy core was this process's own thread (OpenCV's at import)
        ([9, 0], 3.0, 1),  # ours a third of it: the rest is another process
        ([9, 8], 9.0, 1),  # ours only on one of the two busy cores
        ([9, 0], 50.0, 2),  # ours above the busy ticks (rounding): never below zero
        ([4, 4], 0.0, 2),  # under half busy counts as free
    ],
)
def test_free_cores_leave_out_this_processs_own_work(
    busy: list[int], own: float, free: int
) -> None:
    """free_cores' arithmetic (threads._free) on given readings: a core is free when it
    was idle half the sample once this process's own CPU time is taken off the busiest."""
    from lesmc.perception.threads import _free

    before, after = _readings(busy)
    assert _free(before, after, list(range(len(busy))), own) == free


def test_free_cores_skip_cores_outside_the_affinity_or_the_readings() -> None:
    from lesmc.perception.threads import _free

    before, after = _readings([9, 0, 0])
    assert _free(before, after, [0, 1], 0.0) == 1  # core 2 is not ours to use
    del after[1]
    assert _free(before, after, [0, 1, 2], 0.0) == 1  # core 1 unreadable: not counted
