"""Benchmark: how far past ``--timeout T`` a ``lesmc verify`` process ends (target: T + 0.5 s).

Run ``python benchmarks/bench_timeout.py [T ...]`` (default: 0.05 to 5 s). Each
run is ``python -m lesmc verify --out DIR --timeout T`` on the embedded default
video, in a fresh process, with the budget's start (``Budget.started``, on the
system-wide monotonic clock) recorded by a wrapper; the overrun is the time from
that start to the process's end, minus T. Small T falls in the import of torch
(the watchdog's case), larger ones in rendering and perception (the alarm's).
The default video is rendered once first, so that every T after that reuses it;
everything else the previous run left in DIR (its cache, scene and report) is
removed before each run, or a rerun would finish from the cache before T.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_WRAPPER = """
import sys
import lesmc.common.budget as b
_init = b.Budget.__init__
def init(self, *a, **k):
    _init(self, *a, **k)
    with open({start!r}, "w") as f:
        f.write(repr(self.started))
b.Budget.__init__ = init
sys.argv = ["lesmc", "verify", "--out", {out!r}, "--timeout", {t!r}]
from lesmc.cli.entry import main
main()
"""


def overrun(t: str, out: str, start: Path) -> tuple[int, float]:
    start.unlink(missing_ok=True)
    for old in Path(out).glob("*"):  # all but the rendered video
        if old.name != "video":
            shutil.rmtree(old) if old.is_dir() else old.unlink()
    code = _WRAPPER.format(start=str(start), out=out, t=t)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    end = time.monotonic()
    return r.returncode, end - float(start.read_text()) - float(t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("timeouts", nargs="*", default=["0.05", "0.2", "0.5", "1", "2", "3", "5"])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out, start = str(Path(tmp) / "v"), Path(tmp) / "start"
        overrun("30", out, start)  # renders the default video once (not measured)
        print("T (s)  exit  process end - (start + T) (s)")
        for t in args.timeouts:
            status, late = overrun(t, out, start)
            print(f"{float(t):5.2f}  {status:4d}  {late:.2f}")


if __name__ == "__main__":
    main()
