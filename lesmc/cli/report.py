"""``lesmc report RESULTS.json --out DIR [--frames DIR]``: the report, from a results file alone."""

from __future__ import annotations

import click

from lesmc.cli.options import frames_option


@click.command("report")
@click.argument("results", type=click.Path(dir_okay=False, exists=True))
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="Directory for report.html, figures/ and a copy of results.json.",
)
@frames_option("The video's frames, for the report's images (read from nowhere else).")
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON on stdout.")
def report_cmd(results: str, out_dir: str, frames_dir: str | None, as_json: bool) -> None:
    """Draw the verification report from RESULTS (results.json of lesmc verify or of
    lesmc check ... --report DIR; a multi-target design's: of lesmc verify --design sort,
    or lesmc check --design sort --json's output), without checking anything again.

    \b
    Writes OUT/report.html (self-contained), OUT/figures/*.png and OUT/results.json.
    Files are staged and moved in at the end; nothing else in OUT is touched.
    Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
    """
    import json
    from pathlib import Path

    from lesmc.report.html import write_report
    from lesmc.report.publish import frames_reader
    from lesmc.results.load import load_results

    doc = load_results(results)
    if doc["format"] == "lesmc-multi-check":  # a multi-target design (lesmc/report/multi.py)
        from lesmc.report.multi import write_multi_report

        out = write_multi_report(doc, out_dir, frames_reader(frames_dir))
    else:
        out = write_report(doc, out_dir, frames_reader(frames_dir))
    if as_json:
        click.echo(
            json.dumps(
                {
                    "format": "lesmc-report",
                    "version": 1,
                    "results": results,
                    "report": str(out),
                    "results_copy": str(Path(out_dir) / "results.json"),
                    "frames": frames_dir,
                    "runs": [r["design"] for r in doc["runs"]]
                    if "runs" in doc
                    else [doc["design"]],
                },
                indent=1,
            )
        )
    else:
        click.echo(f"report: {out}")
