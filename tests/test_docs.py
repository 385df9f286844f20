"""The documentation site (docs/, Sphinx with MyST): it builds with warnings as errors, and its command-line and
workflow reference pages are generated from the parser and the spec classes, so every option and every spec
field is on them without editing a page."""
import dataclasses
import re
import subprocess
import sys
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import opalflow_reference as reference  # noqa: E402

from opalflow import registry  # noqa: E402
from opalflow.cli import parser  # noqa: E402


def test_docs_build_with_warnings_as_errors(tmp_path):
    run = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                          str(ROOT / "docs"), str(tmp_path / "html")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-3000:]
    assert (tmp_path / "html" / "reference" / "workflows.html").exists()
    assert "opalflow.api.run" in (tmp_path / "html" / "api.html").read_text()


def _fields(cls, where=""):
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from _fields(hints[f.name], f"{where}{f.name}.")
        else:
            yield f"{where}{f.name}"


def test_reference_pages_hold_every_option_and_every_spec_field():
    """Every option of every verb, every kind, and every key of every spec class (in its section's table)."""
    cli = reference.cli_page()
    sub = next(a for a in parser()._actions if hasattr(a, "choices") and isinstance(a.choices, dict))
    for verb, p in sub.choices.items():
        assert f"## {verb}" in cli
        for action in p._actions:
            for option in action.option_strings:
                assert option in cli or option in ("-h", "--help"), (verb, option)
    page = reference.workflows_page()
    for kind in registry.kinds().values():
        assert f"`{kind.name}`: {kind.summary}" in page
        for key in _fields(registry.resolve(kind.spec)):
            section, _, name = key.rpartition(".")
            heading = f"### `[{section}]`" if section else "### top level"
            assert heading in page, key
            assert f"| `{name}` |" in page, key


def test_every_spec_field_says_what_it_means():
    """No key of the workflow reference has an empty meaning: each field carries its description in the source
    (the comment beside it or ``#:`` lines above it), which the page shows."""
    rows = [re.split(r"(?<!\\)\|", line.strip()[1:-1]) for line in reference.workflows_page().splitlines()
            if line.startswith("| `")]
    empty = sorted({cells[0].strip() for cells in rows if len(cells) != 4 or not cells[3].strip()})
    assert rows and not empty, f"spec fields without a description: {empty}"
