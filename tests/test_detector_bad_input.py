"""The issue's "Bad input" list through every verb a detector file reaches (issue 60, round 3,
item 6).

test_detector_file.py checks them on ``lesmc perceive``; here the same files go through
``lesmc verify`` and ``lesmc import mot --detector``, and two more: a ``.pt2`` whose
weights are stored pickled (named in the network's file, never unpickled), and a
``--detector`` that is a directory. Each is exit 2 with a located message, never 4.
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from test_detector_file import _bad_cases, setup, write_toml  # noqa: F401  (a fixture)

BAD = ["output", "stride", "static", "nan", "directory"]


def _refused(r: Any, pattern: str) -> None:
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert re.search(pattern, r.stderr), r.stderr


@pytest.mark.parametrize("case", BAD)
def test_verify_refuses_bad_detector_files(setup: dict[str, Any], case: str) -> None:  # noqa: F811
    d: Path = setup["dir"]
    keys, pattern = _bad_cases(d)[case]
    det = write_toml(d / f"bad_{case}.toml", keys)
    out = d / f"verify_{case}"
    r = lesmc("verify", str(setup["gray"][0]), "--detector", str(det), "--target", "8,8@0",
              "--out", str(out))  # fmt: skip
    _refused(r, pattern)
    assert not (out / "results.json").exists()


@pytest.mark.parametrize("case", ["static", "nan"])
def test_import_mot_refuses_bad_detector_files(setup: dict[str, Any], case: str) -> None:  # noqa: F811
    d: Path = setup["dir"]
    keys, pattern = _bad_cases(d)[case]
    det = write_toml(d / f"mot_{case}.toml", keys)
    txt = d / "det.txt"
    txt.write_text("1,-1,5,5,4,4,1,-1,-1,-1\n")
    out = d / f"mot_{case}.json"
    r = lesmc("import", "mot", str(txt), "--frames", str(setup["gray"][0]), "--detector",
              str(det), "-o", str(out))  # fmt: skip
    _refused(r, pattern)
    assert not out.exists()


def test_pickled_pt2_is_refused(setup: dict[str, Any]) -> None:  # noqa: F811
    d: Path = setup["dir"]
    _, keys, _, pt2 = setup["nets"][0]
    bad = d / "pickled.pt2"
    with zipfile.ZipFile(pt2) as src, zipfile.ZipFile(bad, "w") as dst:
        for info in src.infolist():
            data = src.read(info.filename)
            if info.filename.endswith("model_weights_config.json"):
                data = data.replace(b'"use_pickle": false', b'"use_pickle": true', 1)
            dst.writestr(info, data)
    det = write_toml(d / "pickled.toml", {"kind": "heatmap", "network": "pickled.pt2",
                                          "threshold": 0.5, **keys})  # fmt: skip
    for verb in (["perceive", str(setup["gray"][0])], ["verify", str(setup["gray"][0]),
                 "--target", "8,8@0", "--out", str(d / "pickled_out")]):  # fmt: skip
        r = lesmc(*verb, "--detector", str(det))
        _refused(r, r"pickled\.pt2: .*stored pickled; lesmc never unpickles")


def test_detector_that_is_a_directory(setup: dict[str, Any]) -> None:  # noqa: F811
    d: Path = setup["dir"]
    (d / "adir.toml").mkdir(exist_ok=True)
    for verb in (["perceive", str(setup["gray"][0])], ["verify", str(setup["gray"][0]),
                 "--target", "8,8@0", "--out", str(d / "dir_out")]):  # fmt: skip
        r = lesmc(*verb, "--detector", str(d / "adir.toml"))
        _refused(r, r"adir\.toml")
