"""Tracker blocks and tracker files (docs/scene-format.md, "Tracker files"): a scene's
``tracker`` object or a ``--tracker FILE`` (JSON or TOML), validated key by key, every
problem at its key's ``FILE:LINE:COL``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from lesmc.common.errors import InputError, Location, Problems
from lesmc.common.fields import MAX_STEP, is_finite, is_int, positive, show
from lesmc.common.files import read_json, read_text, read_toml
from lesmc.common.locations import error_at_keys, json_location, key_locations
from lesmc.designs import registry
from lesmc.language import monitors
from lesmc.scene.scene import (
    JOINT_KEYS,
    PRESET_ONLY,
    JointConfig,
    TrackerConfig,
    m_of_n_problem,
    tracker_keys,
)
from lesmc.scene.tracker_model import (
    DEFAULT_MODEL,
    PRESET_P0_SD,
    parse_model,
    preset_R,
    singular_innovation,
    state_names,
)

#: Upper limits of the tracker's parameters (all must also be > 0).
TRACKER_LIMITS = {
    "sigma_q": 1e6,
    "sigma_r": 1e6,
    "P0_sd": 1e6,
    "gate": 1e6,
    "max_trace": 1e30,
    "init_radius": 1e7,
    "init_distance": 1e7,
    "prune_radius": 1e7,
}


def _tracker_value(key: str, v: Any, pr: Problems, item: str, values: dict[str, Any]) -> None:
    """One key of a tracker block, checked; kept in ``values`` (a problem goes to ``pr``)."""
    if key == "model":
        values[key] = parse_model(v, pr, item)
    elif key == "design":
        if v not in registry.tracker_names():
            known = " or ".join(f'"{n}"' for n in registry.tracker_names())
            pr.add(item, f"design must be {known}, got {show(v)}")
        values[key] = v
    elif key == "monitor":
        values[key] = _monitor(v, pr, item)
    elif key == "gate_type":
        if v not in ("mahalanobis", "euclidean"):
            pr.add(item, f'gate_type must be "mahalanobis" or "euclidean", got {v!r}')
        values[key] = v
    elif key in ("min_hits", "max_age", "confirm_window"):
        lo = 0 if key == "max_age" else 1
        if not (is_int(v) and lo <= v <= MAX_STEP):
            pr.add(item, f"{key} must be an integer in {lo}..{MAX_STEP}, got {show(v)}")
        values[key] = v
    elif key == "iou_threshold":
        if not positive(v, 1.0):
            pr.add(item, f"iou_threshold must be a number in (0, 1], got {show(v)}")
        values[key] = v
    elif key == "gate_probability":
        if not (is_finite(v) and 0 < v < 1):
            pr.add(item, f"gate_probability must be a number in (0, 1), got {show(v)}")
        values[key] = v
    elif key == "P0_sd":
        hi = TRACKER_LIMITS[key]
        if not (isinstance(v, list) and v and all(positive(x, hi) for x in v)):
            pr.add(item, f"P0_sd must be a list of numbers in (0, {hi:g}], got {show(v)}")
        else:
            values[key] = tuple(float(x) for x in v)
    elif not positive(v, TRACKER_LIMITS[key]):
        hi = TRACKER_LIMITS[key]
        pr.add(item, f"{key} must be a number in (0, {hi:g}], got {show(v)}")
    else:
        values[key] = v


#: Keys that would choose a tracker's parts (docs/trackers.md, "Tracker files and
#: compositions"): a tracker file names a composition by its design instead.
PART_KEYS = ("parts", "predictor", "updater", "hypothesiser", "associator", "initiator", "deleter")
NO_PARTS = (
    "a tracker file does not choose parts; it names a composition by its design "
    '(design = "sort": IoU, global assignment, min_hits, max_age; design = "gnn": '
    "Mahalanobis, GNN, M of N, max_age) and sets that design's parameters"
)


def tracker_block(
    raw: Any, pr: Problems, item: str = "tracker", owners: dict[int, str] | None = None
) -> TrackerConfig | None:
    """A tracker block: the design, the gate, and the model (a preset's parameters or
    declared matrices, lesmc/scene/tracker_model.py). ``owners``, when given, gets the key
    each problem is about, by its index in ``pr.items`` (for a tracker file's lines)."""
    owners = {} if owners is None else owners

    def own(key: str, n: int) -> None:
        owners.update(dict.fromkeys(range(n, len(pr.items)), key))

    if not isinstance(raw, dict):
        pr.add(item, "must be an object")
        return None
    n0 = len(pr.items)
    names = set(tracker_keys())
    values: dict[str, Any] = {}
    for key, v in raw.items():
        n = len(pr.items)
        if key in PART_KEYS:
            pr.add(item, f"{key}: {NO_PARTS}")
        elif key not in names:
            pr.add(item, f"unknown key '{key}'")
        else:
            _tracker_value(key, v, pr, item, values)
        own(key, n)
    model = values.get("model", DEFAULT_MODEL)
    n = len(pr.items)
    _m_of_n(values, pr, item)
    own("min_hits" if "min_hits" in raw else "confirm_window", n)
    if len(pr.items) > n0 or model is None:
        return None
    if isinstance(model, str):
        sd = values.setdefault("P0_sd", PRESET_P0_SD[model])
        d = len(state_names(model))
        if len(sd) != d:
            pr.add(item, f'P0_sd must have {d} entries for model "{model}", got {len(sd)}')
            own("P0_sd", n0)
            return None
        sigma_r = values.get("sigma_r", TrackerConfig.sigma_r)
        if (why := singular_innovation(preset_R(sigma_r))) is not None:
            pr.add(item, f"sigma_r = {sigma_r!r} makes R = sigma_r² I, which {why}")
            own("sigma_r", n0)
            return None
    else:
        for key in sorted(set(PRESET_ONLY) & set(values)):
            n = len(pr.items)
            pr.add(
                item, f"{key} does not apply to a model declared by its matrices (give Q, R, P0)"
            )
            own(key, n)
        if len(pr.items) > n0:
            return None
    joint = JointConfig(**{k: values.pop(k) for k in JOINT_KEYS if k in values})
    return TrackerConfig(**values, joint=joint)


def _m_of_n(values: dict[str, Any], pr: Problems, item: str) -> None:
    """The gnn design's M-of-N (``min_hits`` of ``confirm_window``) needs M ≤ N."""
    if values.get("design") != "gnn":
        return
    m = values.get("min_hits", TrackerConfig.min_hits)
    n = values.get("confirm_window", TrackerConfig.confirm_window)
    if is_int(m) and is_int(n) and (why := m_of_n_problem(m, n)) is not None:
        pr.add(item, why)


def _monitor(raw: Any, pr: Problems, item: str) -> str | None:
    """A tracker's ``monitor``: ``KIND [PARAM] [window K]`` of the monitor registry
    (lesmc/language/monitors.py), written back in one form."""
    if not isinstance(raw, str):
        pr.add(item, f'monitor must be a string such as "nis 0.99", got {show(raw)}')
        return None
    try:
        kind, value, window = monitors.from_text(raw)
    except ValueError as exc:
        pr.add(item, f"monitor: {exc}")
        return None
    return f"{kind} {value!r}" + (f" window {window}" if window > 1 else "")


def tracker_from_dict(
    data: Any,
    path: str = "<tracker>",
    where: dict[str, Location] | None = None,
    text: str | None = None,
) -> TrackerConfig:
    """A tracker file's configuration: the keys of a scene's ``tracker`` block, and an
    optional ``comment``. ``where`` (each key's place in the file) puts each problem at
    its key's ``FILE:LINE:COL``; the JSON ``text`` of the file, at the very field a
    problem names (``model.Q[3][2]``)."""
    pr = Problems()
    if not isinstance(data, dict):
        keys = ", ".join(k for k in tracker_keys() if k != "faults")
        kinds = {list: "a list", str: "a string", bool: "a boolean", int: "a number"}
        got = "null" if data is None else kinds.get(type(data), "a number")
        raise InputError.many(
            path, [("", f"a tracker file must be an object of the keys {keys}; got {got}")]
        )
    owners: dict[int, str] = {}
    if "comment" in data:
        if not isinstance(data["comment"], str):
            pr.add("comment", f"must be a string (a note for people), got {show(data['comment'])}")
            owners[0] = "comment"
        data = {k: v for k, v in data.items() if k != "comment"}
    cfg = tracker_block(data, pr, "", owners)
    if pr.items or cfg is None:
        problems = pr.items or [("", "not a tracker")]
        if where is None:
            raise InputError.many(path, problems)
        raise _at_keys(path, problems, owners, where, text)
    return cfg


def _at_keys(
    path: str,
    problems: list[tuple[str, str]],
    owners: dict[int, str],
    where: dict[str, Location],
    text: str | None = None,
) -> InputError:
    """One error listing each problem at its key's ``FILE:LINE:COL`` (``FILE`` when the
    key is not in the file, as for a missing key); given the file's JSON ``text``, at
    the field under the key that the message starts with (``model.Q[3][2] must ...``)."""
    places: dict[str, Location] = {}
    found = []
    for i, (item, msg) in enumerate(problems):
        key = owners.get(i, "")
        field = _LEADING_FIELD.match(msg)
        if text is not None and key and field and field.group(0).startswith(key):
            places[f"#{i}"] = json_location(path, text, field.group(0))
        elif key in where:
            places[f"#{i}"] = where[key]
        found.append((f"#{i}", f"{item}: {msg}" if item else msg))
    return error_at_keys(path, places, found, name_keys=False)


#: The field a tracker problem's message starts with: ``model.Q[3][2]``, ``gate``.
_LEADING_FIELD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*|\[\d+\])*")


def load_tracker(path: str | Path, design: str | None = None) -> TrackerConfig:
    """Read a tracker file: JSON (``.json``) or TOML (any other name), the keys of a scene's
    ``tracker`` block (``--tracker FILE``; docs/scene-format.md, "Tracker files").
    ``design`` (``--design``, a name of the registry) replaces the file's, so that what
    that design needs of the file's keys (the gnn design's M ≤ N) is checked at them."""
    p = str(path)
    is_json = p.endswith(".json")
    data = read_json(p, InputError) if is_json else read_toml(p)
    if design is not None and isinstance(data, dict):
        data = {**data, "design": design}
    text = read_text(p)
    return tracker_from_dict(data, p, key_locations(p, text, is_json), text if is_json else None)
