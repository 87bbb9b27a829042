"""Round 20: the public API is one obvious way to do each thing (docs/api.md).

``lesmc.__all__`` is compared with what the package holds and with docs/api.md, each read
here independently of the API's own lists."""

from __future__ import annotations

import pkgutil
import re
from pathlib import Path

import pytest

import lesmc
from lesmc import api

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny" / "model.lts"


def test_no_public_name_is_a_subpackage() -> None:
    """``lesmc.export`` must stay the function, whatever subpackage is imported."""
    subpackages = {m.name for m in pkgutil.iter_modules(lesmc.__path__)}
    assert subpackages, "the package's modules were not found"
    assert set(lesmc.__all__).isdisjoint(subpackages)


def test_export_is_the_one_way_to_export() -> None:
    """``export_model`` was ``export`` with positional arguments: two public ways to do
    one thing. It is the command line's helper now, not a name of the package."""
    assert "export" in lesmc.__all__
    assert "export_model" not in lesmc.__all__
    assert "export_model" not in api.__all__
    with pytest.raises(AttributeError):
        lesmc.export_model  # noqa: B018


def test_the_package_and_the_api_module_list_the_same_functions() -> None:
    errors = {"LesmcError", "InputError", "SpecError", "ModelError", "UsageError", "BudgetError"}
    assert set(lesmc.__all__) - errors == set(api.__all__)


def test_every_public_name_is_documented() -> None:
    """Each name of ``lesmc.__all__`` appears in docs/api.md as code (in backquotes)."""
    text = (ROOT / "docs" / "api.md").read_text()
    quoted = set(re.findall(r"`(?:lesmc\.)?([A-Za-z_]\w*)", text))
    missing = [n for n in lesmc.__all__ if n not in quoted]
    assert missing == []


def test_an_unknown_format_is_named_by_the_keyword_export_takes(tmp_path: Path) -> None:
    """``lesmc.export(..., format="svg")`` names ``format`` (the argument given), not the
    helper's ``fmt``; nothing is written."""
    model = lesmc.load_model(TINY)
    out = tmp_path / "m.svg"
    with pytest.raises(lesmc.UsageError) as err:
        lesmc.export(model, out, format="svg")
    assert err.value.message.startswith("format: ")
    assert "fmt" not in err.value.message
    assert not out.exists()
