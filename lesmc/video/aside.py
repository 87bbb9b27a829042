"""A video's frames rendered by a child process while the caller does something else.

``lesmc verify`` renders the default video, then imports torch for perception. The
import is about 1.5-2 s of Python that holds the GIL, and rendering's scene drawing
is Python too (:func:`lesmc.video.synth.frames`): on one interpreter the two only
take turns. Here a child process (``python -m lesmc.video.aside``) runs the same
:func:`~lesmc.video.synth.render_into` into the caller's staging directory while the
caller runs ``meanwhile()``, so the files are the same bytes (tests/test_video.py).

The child prints one line on stdout per frame written and exits 0 when the frames
and truth.json are in place; an ``OSError`` (a file it cannot write) is its message
on stderr and exit 2; anything else is an internal error. It runs in a session of
its own, so a terminal's Ctrl-C reaches only the caller: on an interrupt, a signal,
a spent budget or an error the caller stops it (SIGTERM), waits for it to end and
then removes the staging directory itself (:func:`lesmc.video.write.write_video`):
nothing is left behind whatever the child was doing. A child whose caller died
stops at its next line (a closed pipe).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from lesmc.video.synth import SynthConfig, render_into

#: Seconds a stopped child may take to end before it is killed.
STOP_GRACE = 10.0


def render_aside(
    cfg: SynthConfig,
    tmp: Path,
    out_dir: Path,
    progress: Callable[[], None] | None,
    meanwhile: Callable[[], None],
) -> None:
    """:func:`~lesmc.video.synth.render_into` in a child process; ``meanwhile()`` runs
    here in the meantime, then ``progress()`` once per frame the child wrote."""
    config = json.dumps(asdict(cfg))
    with tempfile.TemporaryFile() as errors:
        child = subprocess.Popen(
            [sys.executable, "-m", "lesmc.video.aside", config, str(tmp), str(out_dir)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=errors,
            env=_child_environment(),
            start_new_session=True,
        )
        assert child.stdout is not None
        try:
            with child.stdout:
                meanwhile()
                for _ in child.stdout:
                    if progress is not None:
                        progress()
            status = child.wait()
        except BaseException:
            _stop(child)
            raise
        errors.seek(0)
        message = errors.read().decode("utf-8", "replace").strip()
    if status == 2:
        raise OSError(message)
    if status != 0:
        last = message.splitlines()[-1] if message else f"exit status {status}"
        raise RuntimeError(f"rendering the video in a child process failed: {last}")


def _child_environment() -> dict[str, str]:
    """This environment, with this lesmc's directory first on PYTHONPATH when the child
    would not find it by itself (a checkout put on ``sys.path`` at run time): the child
    then renders with this code. An installed lesmc is left where the interpreter finds
    it, so that site-packages never comes before the standard library."""
    import site

    root = str(Path(__file__).resolve().parents[2])  # the directory that holds lesmc/
    found = {str(Path(p).resolve()) for p in [*site.getsitepackages(), site.getusersitepackages()]}
    env = dict(os.environ)
    if root not in found:
        paths = [root, *filter(None, env.get("PYTHONPATH", "").split(os.pathsep))]
        env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


def _stop(child: subprocess.Popen[bytes]) -> None:
    """End the child (SIGTERM, then SIGKILL after :data:`STOP_GRACE`) and wait for it."""
    if child.poll() is not None:
        return
    child.terminate()
    try:
        child.wait(STOP_GRACE)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()


def main(argv: list[str]) -> int:
    """The child: ``CONFIG_JSON TMP OUT_DIR`` (see the module's docstring)."""
    from lesmc.common.memory import one_arena

    one_arena()  # as the command line does (lesmc/common/memory.py)
    cfg = SynthConfig(**json.loads(argv[0]))

    def written() -> None:
        sys.stdout.write("frame\n")
        sys.stdout.flush()

    try:
        render_into(cfg, Path(argv[1]), Path(argv[2]), written)
    except OSError as exc:
        sys.stderr.write(f"{exc}\n")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
