"""The verification report, drawn from a results file alone (``lesmc report``).

For each design run of the results document the report draws the paper's
section 8: the frame crop with the original track, counterexample, witness
and ground truth (Figures 6-8), the tree of attacked paths (Figure 9c),
deviation per step against the threshold (Figure 7c-d), the covariance trace
with the monitor's alarms (Figure 10), the per-path measures (Table 3), the
verdicts (Table 4) and, with several runs, the comparison (Table 5); then the
spec text, provenance and timings. Video frames are read only from a
directory the user names (``--frames``); without one the figures have no image.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lesmc.report.design_section import section
from lesmc.report.document_tables import (
    design_search_table,
    false_alarms_table,
    faults_table,
    meta_table,
    monitored,
    provenance_table,
    table5,
    timings_table,
    verdict_lines,
)
from lesmc.report.figure_cache import FigureSet, PngStore
from lesmc.report.figures import COLOURS, ImageFor
from lesmc.report.pages import images, render_page
from lesmc.report.run_view import RunView, payoff_words
from lesmc.report.staging import staged
from lesmc.results.read import ResultsDoc, results_of


def write_report(
    doc: dict[str, Any],
    out_dir: str | Path,
    image_for: ImageFor | None = None,
    files: dict[str, str] | None = None,
    store: PngStore | None = None,
) -> Path:
    """Write report.html, figures/*.png, results.json (``doc``) and ``files`` (name -> text,
    e.g. the scene the results refer to) into ``out_dir``.

    Staged and moved in at the end (lesmc/report/staging.py): nothing the run did
    not create is deleted, two runs into one directory do not mix, and an interrupt
    leaves the old files or the new ones, never a mix.
    ``image_for(frame)`` returns the grey video frame with that index, when known.
    ``store``: figures drawn before, reused when drawn from the same values
    (lesmc/report/figure_cache.py). The figures may be drawn by two processes
    (lesmc/report/drawing.py).
    """
    page, figs = render(results_of(doc), image_for, store)
    with staged(out_dir) as tmp:
        for name, text in (files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
        (tmp / "figures").mkdir()
        for name, png in figs.items():
            (tmp / "figures" / name).write_bytes(png)
        (tmp / "results.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return Path(out_dir) / "report.html"


def render(
    doc: ResultsDoc,
    image_for: ImageFor | None = None,
    store: PngStore | None = None,
) -> tuple[str, dict[str, bytes]]:
    """The report page (templates/report.html.j2; figures as data URIs) and its figures by
    file name (read from ``store`` where drawn before from the same values; drawn
    otherwise, by two processes where :func:`lesmc.report.drawing.may_fork`)."""
    runs = [RunView(r) for r in doc.runs]
    figs = FigureSet(store)
    toc: list[tuple[str, str]] = [("verdicts", "Verdicts")]
    if len(runs) > 1:
        toc.append(("designs", "Designs compared (Table 5)"))
    fa = doc.monitor_false_alarms
    if fa is not None:
        toc.append(("false-alarms", "The monitor on unattacked tracks"))
    ds = doc.design_search
    if ds is not None:
        toc.append(("design-search", "A design that holds"))
    faults = faults_table(doc.runs)
    if faults is not None:
        toc.append(("faults", "Component failures"))
    sections = []
    for run in runs:
        toc.append((f"design-{run.tag}", f"Design: {run.name}"))
        parts = section(run, figs, image_for, payoff_words(doc))
        sections.append({"tag": run.tag, "name": run.name, "parts": parts})
    toc += [("specs", "Properties (spec text)"), ("provenance", "Provenance and timings")]
    cheapest = any(r.cex_role(i) == "cheapest" for r in runs for i in range(len(r.props)))
    page = render_page(
        "report.html.j2",
        legend=[
            (COLOURS[role], text)
            for role, text in (
                ("original", "original (unattacked) track"),
                ("counterexample", "counterexample (dashed, hollow markers)"),
                ("cheapest", CHEAPEST_LEGEND),
                ("witness", "witness ρ*"),
                ("truth", "ground truth (dotted)"),
                ("other", "other attacked tracks"),
            )
            if role != "cheapest" or cheapest
        ],
        window_colour=COLOURS["window"],
        meta=meta_table(doc),
        toc=toc,
        verdicts=verdict_lines(runs),
        table5=table5(runs) if len(runs) > 1 else None,
        false_alarms=None if fa is None else {"what": fa.what, "table": false_alarms_table(fa)},
        design_search=None if ds is None else design_search_table(ds),
        faults=faults,
        sections=sections,
        specs=doc.provenance.specs,
        monitored=monitored(doc),
        provenance=provenance_table(doc),
        timings=timings_table(doc),
        images=images(figs.pngs, scale=2),  # drawn at 2x: shown at half the natural size, sharp
    )
    return page, figs.pngs


#: The legend's words for the cheapest path of a property that holds.
CHEAPEST_LEGEND = (
    "cheapest path that breaks the system, of a property that holds: not a counterexample "
    "(dashed, hollow markers)"
)
