"""The synthetic WAMI generator, reading frame directories, and the synth/perceive verbs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from test_signals import rendering_children

from lesmc.cli.main import cli
from lesmc.common.errors import InputError
from lesmc.video.reader import natural_key, open_frames
from lesmc.video.synth import SynthConfig, frames
from lesmc.video.write import write_video

SMALL = SynthConfig(frames=6, width=384, height=320, seed=5, density=3.0)


@pytest.fixture(scope="module")
def small_video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("video")
    write_video(SMALL, out)
    return out


def test_generator_is_deterministic_by_seed() -> None:
    a = [(img.copy(), t) for img, t in frames(SMALL)]
    b = [(img.copy(), t) for img, t in frames(SMALL)]
    assert all(np.array_equal(x[0], y[0]) and x[1] == y[1] for x, y in zip(a, b, strict=True))
    c = next(frames(SynthConfig(frames=1, width=384, height=320, seed=6)))[0]
    assert not np.array_equal(a[0][0], c)


def test_truth_describes_the_frames(small_video: Path) -> None:
    truth = json.loads((small_video / "truth.json").read_text())
    assert truth["format"] == "lesmc-truth" and len(truth["frames"]) == 6
    f0 = truth["frames"][0]
    assert f0["to_prev"] is None and f0["file"] == "frame_00000.png"
    speeds = [v["speed_mps"] for fr in truth["frames"] for v in fr["vehicles"]]
    assert speeds and max(speeds) <= 25.0 + 1e-9 and min(speeds) >= 0.0
    lengths = [v["length_px"] for fr in truth["frames"] for v in fr["vehicles"]]
    assert min(lengths) >= 2.5 and max(lengths) <= 9.5
    for fr in truth["frames"]:
        for v in fr["vehicles"]:
            assert 0 <= v["x"] < SMALL.width and 0 <= v["y"] < SMALL.height


def test_truth_homography_aligns_the_static_ground(small_video: Path) -> None:
    """Warping frame k by ``to_prev`` reproduces frame k-1 away from movers and buildings."""
    truth = json.loads((small_video / "truth.json").read_text())
    k = 3
    cur = cv2.imread(str(small_video / truth["frames"][k]["file"]), 0).astype(np.float32)
    prev = cv2.imread(str(small_video / truth["frames"][k - 1]["file"]), 0).astype(np.float32)
    h = np.array(truth["frames"][k]["to_prev"])
    warped = cv2.warpPerspective(cur, h, cur.shape[::-1])
    inner = (slice(40, -40), slice(40, -40))
    diff = np.abs(warped - prev)[inner]
    # most of the ground agrees to sensor noise; registration by identity would not
    assert np.median(diff) < 3.5
    ident = np.abs(cur - prev)[inner]
    assert np.percentile(ident, 95) > 2 * np.percentile(diff, 95)


def test_sixteen_bit_tiff_and_colour_frames_are_read(tmp_path: Path) -> None:
    cfg = SynthConfig(frames=2, width=128, height=96, seed=2, depth=16)
    paths = write_video(cfg, tmp_path / "v16")
    assert all(p.suffix == ".tif" for p in paths)
    raw = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    fs = open_frames(tmp_path / "v16", 2)
    assert fs.read(0).dtype == np.uint8 and fs.read(0).shape == (96, 128)
    colour = tmp_path / "colour"
    colour.mkdir()
    rgb = np.zeros((20, 30, 3), np.uint8)
    rgb[..., 1] = 200
    cv2.imwrite(str(colour / "a.jpg"), rgb)
    cv2.imwrite(str(colour / "b.jpg"), rgb)
    g = open_frames(colour, 2).read(0)
    assert g.shape == (20, 30) and 100 < g.mean() < 140  # luma of pure green


def test_natural_sort_order(tmp_path: Path) -> None:
    names = ["f10.png", "f2.png", "f1.png", "F3.png"]
    assert sorted(names, key=natural_key) == ["f1.png", "f2.png", "F3.png", "f10.png"]
    img = np.zeros((8, 8), np.uint8)
    for i, n in enumerate(names):
        cv2.imwrite(str(tmp_path / n), img + i)
    assert [p.name for p in open_frames(tmp_path, 4).paths] == [
        "f1.png",
        "f2.png",
        "F3.png",
        "f10.png",
    ]


def test_bad_frame_directories_name_the_file(tmp_path: Path) -> None:
    img = np.zeros((8, 8), np.uint8)
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), img)
    with pytest.raises(InputError, match="at least 5"):
        open_frames(tmp_path, 5)
    cv2.imwrite(str(tmp_path / "f3.png"), np.zeros((9, 8), np.uint8))
    with pytest.raises(InputError, match=r"f3\.png.*one size"):
        open_frames(tmp_path, 2)
    (tmp_path / "f3.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match=r"f3\.png.*cannot decode"):
        open_frames(tmp_path, 2)


@pytest.mark.parametrize("bad", [1, 7, 18])
def test_the_first_bad_frame_in_sort_order_is_the_one_reported(tmp_path: Path, bad: int) -> None:
    """Frames are decoded on threads to be checked, yet the error names the first bad
    file in natural sort order, whichever decode finishes first; 16-bit videos keep the
    first frame's scale."""
    img = (np.arange(64 * 64, dtype=np.uint16).reshape(64, 64) * 7) % 60000
    for i in range(20):
        cv2.imwrite(str(tmp_path / f"frame{i}.png"), img)
    want = 255.0 / float(np.percentile(img, 99.9))
    assert open_frames(tmp_path, 2).scale == want
    (tmp_path / f"frame{bad}.png").write_bytes(b"not an image")
    cv2.imwrite(str(tmp_path / "frame19.png"), np.zeros((9, 8), np.uint16))
    with pytest.raises(InputError, match=rf"frame{bad}\.png: cannot decode"):
        open_frames(tmp_path, 2)


def test_perceive_reports_quality_on_a_synthetic_video(small_video: Path) -> None:
    res = CliRunner().invoke(
        cli, ["perceive", str(small_video), "--truth", str(small_video / "truth.json"), "--json"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)  # stderr: the progress log lines
    assert len(doc["frames"]) == 6 - 4
    fe, det = doc["overall"]["frontend"], doc["overall"]["detector"]
    assert fe["tp"] + fe["fn"] > 5
    assert fe["recall"] >= 0.8 and 0 < fe["precision"] <= 1 and fe["error_px"] < 2.0
    # the CNNs remove most false candidates and keep most vehicles
    assert det["precision"] > fe["precision"] and det["recall"] >= 0.8
    front_only = CliRunner().invoke(
        cli,
        [
            "perceive",
            str(small_video),
            "--truth",
            str(small_video / "truth.json"),
            "--json",
            "--no-cnn",
        ],
    )
    assert json.loads(front_only.stdout)["overall"] == {"frontend": fe}


def test_perceive_errors_exit_2_without_traceback(tmp_path: Path) -> None:
    import subprocess
    import sys

    (tmp_path / "a.png").write_bytes(b"junk")
    r = subprocess.run(
        [sys.executable, "-m", "lesmc", "perceive", str(tmp_path)], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "frame(s) found" in r.stderr


def test_synth_cli_writes_frames_and_truth(tmp_path: Path) -> None:
    res = CliRunner().invoke(
        cli, ["synth", str(tmp_path / "v"), "--frames", "2", "--size", "96x64"]
    )
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == [
        "frame_00000.png",
        "frame_00001.png",
        "truth.json",
    ]
    bad = CliRunner().invoke(cli, ["synth", str(tmp_path / "w"), "--size", "96by64"])
    assert bad.exit_code != 0 and not (tmp_path / "w").exists()


def test_pipelined_rendering_equals_rendering_one_frame_after_the_other() -> None:
    """frames() draws frame k+1 while a second thread runs frame k's sensor: the frames and
    truth are those of the world rendered and quantised frame by frame (an oracle written
    from World's public steps), for 8- and 16-bit videos."""
    from lesmc.video import FPS
    from lesmc.video.synth import World

    for cfg in (SMALL, SynthConfig(frames=4, width=256, height=192, seed=3, depth=16)):
        world = World(cfg)
        want = []
        for k in range(cfg.frames):
            img, _, vehicles = world.render(k)
            if cfg.depth == 16:
                img = np.clip(img * 257.0, 0, 65535).astype(np.uint16)
            else:
                img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
            want.append((img, vehicles))
            world.traffic.step(1.0 / FPS)
        got = list(frames(cfg))
        assert len(got) == len(want)
        for (img, truth), (w_img, w_vehicles) in zip(got, want, strict=True):
            assert img.dtype == w_img.dtype and np.array_equal(img, w_img)
            assert truth.vehicles == w_vehicles


def test_an_interrupted_video_leaves_nothing_behind(tmp_path: Path) -> None:
    """progress() raising (a budget spent, Ctrl-C) stops the writer thread and removes the
    staging directory: the output directory holds nothing the run wrote."""
    out = tmp_path / "v"
    calls = []

    def stop() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_video(SMALL, out, progress=stop)
    assert list(out.iterdir()) == []


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.floats(0.0, 50.0), min_size=1, max_size=8),
    ys=st.lists(st.floats(-100.0, 100.0), min_size=9, max_size=9),
    pick=st.floats(-0.2, 1.2),
    on_knot=st.integers(0, 8),
    knot=st.booleans(),
)
def test_edge_at_equals_the_vectorised_interpolation_bit_for_bit(
    steps: list[float], ys: list[float], pick: float, on_knot: int, knot: bool
) -> None:
    """Edge.at works on Python floats (numpy's per-call cost on one value was most of the
    traffic's time); it must give the bits of the vectorised numpy interpolation it
    replaced (written out here), knots, repeated knots and clamping included."""
    from lesmc.video.roads import Edge

    xs = np.concatenate([[0.0], np.cumsum(steps)])
    points = np.stack([xs, np.array(ys[: len(xs)])], axis=1)
    arclen = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    edge = Edge(points, arclen)
    s = float(arclen[min(on_knot, len(arclen) - 1)]) if knot else pick * float(arclen[-1])
    pos, tan = edge.at(s)
    s_arr = np.clip(np.asarray([s]), 0.0, arclen[-1])
    i = np.clip(np.searchsorted(arclen, s_arr, side="right") - 1, 0, len(arclen) - 2)
    seg = points[i + 1] - points[i]
    seg_len = np.maximum(arclen[i + 1] - arclen[i], 1e-9)
    want_pos = points[i] + seg * ((s_arr - arclen[i]) / seg_len)[..., None]
    want_tan = seg / seg_len[..., None]
    assert pos.tobytes() == want_pos[0].tobytes() and tan.tobytes() == want_tan[0].tobytes()


def test_a_frame_shows_exactly_the_vehicles_projected_inside_it() -> None:
    """The scene skips vehicles far outside the frame by one projection of them all; the
    truth still lists exactly the vehicles whose own projection lands in the frame."""
    from lesmc.video.synth import World, _apply

    cfg = SynthConfig(frames=3, width=320, height=240, seed=5, density=3.0)
    world = World(cfg)
    for k in range(cfg.frames):
        H, _ = world.camera(k)
        want = []
        for v in world.traffic.vehicles:
            pos, _ = world.traffic.pose(v)
            p = _apply(H, pos[None])[0]
            if 0 <= p[0] < cfg.width and 0 <= p[1] < cfg.height:
                want.append(v.vid)
        _, _, vehicles = world.scene(k)
        assert [v["id"] for v in vehicles] == want and want
        world.traffic.step(0.5)


def test_a_video_rendered_aside_is_the_same_bytes(tmp_path: Path) -> None:
    """write_video(meanwhile=...) renders in a child process while meanwhile() runs here:
    the same files, byte for byte, as rendering in this process, and progress() once a
    frame."""
    here, aside = tmp_path / "here", tmp_path / "aside"
    want = write_video(SMALL, here)
    ran, counted = [], []
    got = write_video(SMALL, aside, lambda: counted.append(1), lambda: ran.append(1))
    assert ran == [1] and len(counted) == SMALL.frames
    assert [p.name for p in got] == [p.name for p in want]
    for name in [p.name for p in want] + ["truth.json"]:
        assert (aside / name).read_bytes() == (here / name).read_bytes(), name
    assert sorted(p.name for p in aside.iterdir()) == sorted(p.name for p in here.iterdir())


@pytest.mark.parametrize("where", ["meanwhile", "progress"])
def test_an_interrupted_video_aside_leaves_nothing_and_no_process(
    tmp_path: Path, where: str
) -> None:
    """Ctrl-C while the caller runs meanwhile() or counts the child's frames: the child is
    stopped and waited for, the staging directory removed, nothing written."""
    out = tmp_path / "v"
    calls = []

    def stop() -> None:
        calls.append(1)
        if where == "meanwhile" or len(calls) == 2:
            raise KeyboardInterrupt

    job = (lambda: None, stop) if where == "meanwhile" else (stop, lambda: None)
    with pytest.raises(KeyboardInterrupt):
        write_video(SMALL, out, *job)
    assert list(out.iterdir()) == []
    assert rendering_children(tmp_path) == []


def test_a_frame_the_child_cannot_write_is_an_os_error_with_its_name(tmp_path: Path) -> None:
    """The child's OSError (here: its staging directory is gone) comes back as an OSError
    that names the file, as rendering in this process would raise."""
    from lesmc.video.aside import render_aside

    gone = tmp_path / "gone"
    with pytest.raises(OSError, match=r"cannot write .*frame_00000\.png"):
        render_aside(SMALL, gone, tmp_path / "shown", None, lambda: None)
    assert rendering_children(tmp_path) == []


def test_the_noise_band_changes_no_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Noise is drawn NOISE_BAND rows at a time to bound the memory in flight: the ground
    and the frames are the same bits whatever the band (one row, a band that does not
    divide the height, a band larger than the image)."""
    from lesmc.video import synth

    cfg = SynthConfig(frames=2, width=256, height=192, seed=4)
    got = {}
    for band in (1, 50, 4096):
        monkeypatch.setattr(synth, "NOISE_BAND", band)
        got[band] = (synth.World(cfg).ground, [img for img, _ in frames(cfg)])
    for band in (50, 4096):
        assert np.array_equal(got[band][0], got[1][0])
        for a, b in zip(got[band][1], got[1][1], strict=True):
            assert np.array_equal(a, b)


def test_a_frames_front_end_output_is_freed_before_the_next_is_made(
    small_video: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """perceive holds one frame's aligned history and background at a time: when the front
    end makes frame k+1's output, nothing refers to frame k's any more."""
    import gc
    import weakref

    from lesmc.perception.frontend import FrontEnd
    from lesmc.perception.run import PerceiveOptions, perceive
    from lesmc.video.reader import open_frames

    made: list[weakref.ref[Any]] = []
    alive_at_push: list[bool] = []
    push = FrontEnd.push

    def watched(self: FrontEnd, *args: Any, **kwargs: Any) -> Any:
        gc.collect()
        alive_at_push.append(any(r() is not None for r in made))
        out = push(self, *args, **kwargs)
        if out is not None:
            made.append(weakref.ref(out))
        return out

    monkeypatch.setattr(FrontEnd, "push", watched)
    frames = open_frames(small_video, 5)
    perceive(frames, PerceiveOptions())
    assert len(made) == len(frames) - 4
    assert alive_at_push == [False] * len(frames)
