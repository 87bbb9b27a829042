"""A scene records which networks made it (issue 60, round 3, item 4).

With a detector file, ``meta.detector_file`` holds the file's and its network's sha256;
on the window pipeline, ``meta.network_files`` holds each role's file (the user's
N_dr where given, the shipped pair's otherwise) with its sha256, computed here with
hashlib from the files' bytes.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from cli_run import ROOT, lesmc

TOML = ROOT / "examples" / "detectors" / "heatmap.toml"
NET = ROOT / "examples" / "detectors" / "heatmap.onnx"
SHIPPED = ROOT / "lesmc" / "perception" / "weights" / "wami"


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_detector_file_scene_records_hashes(tmp_path: Path) -> None:
    frames = tmp_path / "v"
    assert lesmc("synth", str(frames), "--frames", "1", "--size", "96x96").returncode == 0
    out = tmp_path / "s.json"
    r = lesmc("perceive", str(frames), "--detector", str(TOML), "-o", str(out), "--max-iter", "3")
    assert r.returncode == 0, r.stderr
    meta = json.loads(out.read_text())["meta"]["detector_file"]
    assert meta["sha256"] == _sha(TOML)
    assert meta["network_sha256"] == _sha(NET)
    assert Path(meta["network"]).resolve() == NET.resolve()


def test_window_scene_records_each_role(tmp_path: Path) -> None:
    frames = tmp_path / "v"
    assert lesmc("synth", str(frames), "--frames", "6", "--size", "256x256").returncode == 0
    out = tmp_path / "s.json"
    r = lesmc("perceive", str(frames), "-o", str(out), "--max-iter", "3")
    assert r.returncode == 0, r.stderr
    files = json.loads(out.read_text())["meta"]["network_files"]
    assert set(files) == {"settings", "N_dr", "N_lp"}
    for role, name in (("settings", "nets.json"), ("N_dr", "dr.safetensors"),
                       ("N_lp", "lp.safetensors")):  # fmt: skip
        assert Path(files[role]["path"]).resolve() == (SHIPPED / name).resolve()
        assert files[role]["sha256"] == _sha(SHIPPED / name)
