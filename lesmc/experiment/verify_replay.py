"""``lesmc verify``'s replay step: every violated property's counterexample replayed
through the real detector (lesmc/replay), or read from OUT/cache when the same
counterexamples on the same frames and networks were replayed before.
"""

from __future__ import annotations

import time
from typing import Any

from lesmc.common.budget import Budget
from lesmc.common.progress import Reporter
from lesmc.experiment import detector_verify
from lesmc.experiment.cache import code_digest, digest, file_digests, net_files
from lesmc.experiment.verify_request import Source, spent
from lesmc.replay.run import apply, cases, replay
from lesmc.results.read import results_of
from lesmc.results.record import Results


def replay_counterexamples(
    doc: dict[str, Any],
    results: Results,
    src: Source,
    timings: dict[str, float],
    rep: Reporter,
    budget: Budget,
) -> None:
    """Replay every violated property through the real detector (lesmc/replay); the
    results and the document record what each replay found. The same counterexamples on
    the same frames and networks replay from OUT/cache."""
    from lesmc.replay.run import Outcome

    typed = results_of(doc)
    todo = cases(typed)
    if not todo or src.frames is None or (src.nets is None and src.net_files is None):
        return
    t0 = time.monotonic()
    key = _replay_key(doc, src, todo)
    hit = None if src.cache is None or key is None else src.cache.get("replay", key)
    outcome = _cached_replay(hit, doc)
    if outcome is not None:
        rep.log(f"reusing the replay of {len(outcome.replays)} counterexamples from the cache")
    else:
        outcome = _replay_now(typed, src, rep, budget)
        if src.cache is not None and key is not None:
            rows = [[i, j, obj] for (i, j), obj in outcome.replays.items()]
            src.cache.put("replay", key, {"replays": rows, "seconds": outcome.seconds})
    assert isinstance(outcome, Outcome)
    apply(doc, outcome, results)
    timings["replay"] = time.monotonic() - t0


def _replay_now(typed: Any, src: Source, rep: Reporter, budget: Budget) -> Any:
    """The counterexamples of ``typed`` replayed now: through the detector file, or the
    window pipeline's networks (only the attacked frames redone when this run perceived)."""
    assert src.frames is not None
    by_file = detector_verify.detector_file_of(src.net_files or (None, None, None))
    if by_file is not None:  # through the detector file (lesmc/replay/detector_file.py)
        frames_dir = str(src.frames.paths[0].parent)
        return detector_verify.replay(typed, frames_dir, by_file, rep)
    frames, nets = src.frames, src.networks()
    # this run's perception made the clean detections: only attacked frames are redone
    clean = None if src.run is None else {fd.index: fd for fd in src.run.detections}
    known = None if src.run is None else src.run.registrations
    with rep.bar("replaying", len(frames) if clean is None else None) as bar:

        def advance() -> None:
            bar.advance()
            spent(budget, "replaying the counterexamples")

        return replay(
            typed, frames, nets, on_frame=advance, clean=clean, registrations=known,
            scene=src.scene,
        )  # fmt: skip


#: The packages whose code decides a cached replay object: the replay through the detector
#: and tracker, and its ``on_frames`` judgement (lesmc/results/replay_measures.py, folded by
#: lesmc/model/kernel.py with the measures of lesmc/language/measures/).
REPLAY_CODE = (
    "replay", "perception", "video", "tracking", "scene", "designs", "results", "model",
    "language",
)  # fmt: skip


def _replay_key(doc: dict[str, Any], src: Source, todo: list[Any]) -> str | None:
    """The digest of what the replay reads: each case's run (its scene, paths and results
    without their timings), the frames, the networks and the code; None: not cacheable
    (networks given as loaded objects)."""
    if src.net_files is None or src.frames is None:
        return None
    runs = []
    for i in sorted({c.run for c in todo}):
        run = {k: v for k, v in doc["runs"][i].items() if k != "faults"}  # not replayed
        run["results"] = [
            {k: v for k, v in r.items() if k not in ("stats", "certified_stats")}
            for r in run["results"]
        ]
        runs.append([i, run])
    perception = doc.get("perception", {})
    return digest(
        {
            "code": code_digest(*REPLAY_CODE),
            "frames": file_digests(src.frames.paths),
            "nets": file_digests(net_files(src.net_files)),
            **detector_verify.replay_key(src.net_files),
            "settings": {k: perception.get(k) for k in ("history", "delta_bc", "attack")},
            "runs": runs,
            "cases": [[c.run, c.result] for c in todo],
        }
    )


def _cached_replay(hit: Any, doc: dict[str, Any]) -> Any:
    """A cache entry as the replay's Outcome, if it is one for these cases; else None."""
    from lesmc.replay.run import Outcome
    from lesmc.results.load import replay_ok

    if not isinstance(hit, dict) or not isinstance(hit.get("replays"), list):
        return None
    replays: dict[tuple[int, int], dict[str, Any]] = {}
    for row in hit["replays"]:
        if not (isinstance(row, list) and len(row) == 3 and isinstance(row[2], dict)):
            return None
        i, j, obj = row
        ok = isinstance(i, int) and isinstance(j, int) and 0 <= i < len(doc["runs"])
        if not ok or not 0 <= j < len(doc["runs"][i]["results"]) or not replay_ok(obj, "results"):
            return None
        replays[(i, j)] = obj
    seconds = hit.get("seconds")
    return Outcome(replays, float(seconds) if isinstance(seconds, (int, float)) else 0.0)
