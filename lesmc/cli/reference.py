"""docs/cli-options.md: every verb's arguments and options, read from the click definitions.

``python -m lesmc.cli.reference > docs/cli-options.md`` writes it;
tests/test_cli.py checks that the committed file is what the command line
declares, so the reference cannot drift from the code.
"""

from __future__ import annotations

import click

from lesmc.cli.main import cli


def _choices(p: click.Parameter) -> str:
    t = p.type
    if isinstance(t, click.Choice):
        return ", ".join(f"`{c}`" for c in t.choices)
    return ""


def _row(p: click.Parameter) -> str:
    if isinstance(p, click.Argument):
        name = f"`{p.human_readable_name}`"
        kind = "argument" + (" (repeatable)" if p.nargs == -1 else "")
        return f"| {name} | {kind} | | |"
    assert isinstance(p, click.Option)
    name = ", ".join(f"`{o}`" for o in [*p.opts, *p.secondary_opts])
    if p.required:
        default = "required"
    elif (
        p.is_flag or p.default in (None, False, ()) or not isinstance(p.default, str | int | float)
    ):
        default = ""
    else:
        default = f"`{p.default}`"
    text = " ".join((p.help or "").split()).replace("|", "\\|")
    choices = _choices(p)
    if choices:
        text = f"{text} One of {choices}." if text else f"One of {choices}."
    return f"| {name} | {'flag' if p.is_flag else p.type.name} | {default} | {text} |"


def _commands(group: click.Group, prefix: str) -> list[tuple[str, click.Command]]:
    out: list[tuple[str, click.Command]] = []
    ctx = click.Context(group)
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        assert cmd is not None
        if isinstance(cmd, click.Group):
            out += _commands(cmd, f"{prefix} {name}")
        else:
            out.append((f"{prefix} {name}", cmd))
    return out


def options_markdown() -> str:
    """The reference page, one table per verb."""
    lines = [
        "# Command-line reference",
        "",
        "Generated from the click definitions by `python -m lesmc.cli.reference > "
        "docs/cli-options.md` (tests/test_cli.py checks it is current). "
        "[cli.md](cli.md) explains the verbs, their JSON output and exit statuses.",
    ]
    for name, cmd in _commands(cli, "lesmc"):
        lines += ["", f"## `{name}`", "", " ".join((cmd.help or "").split("\n\n")[0].split()), ""]
        lines += ["| argument / option | type | default | meaning |", "|---|---|---|---|"]
        lines += [_row(p) for p in cmd.params if p.name != "help"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(options_markdown(), end="")
