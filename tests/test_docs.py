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

import docstats  # noqa: E402
import opalflow_reference as reference  # noqa: E402

from opalflow import registry  # noqa: E402
from opalflow.cli import parser  # noqa: E402


def test_docs_build_with_warnings_as_errors(tmp_path):
    run = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                          str(ROOT / "docs"), str(tmp_path / "html")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-3000:]
    assert (tmp_path / "html" / "reference" / "generated" / "workflows.html").exists()
    assert "opalflow.api.run" in (tmp_path / "html" / "reference" / "api.html").read_text()


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


PARTS = ["Tutorials", "How-to guides", "Explanation", "Reference", "Validation", "Benchmarks"]


def test_the_site_is_in_its_six_parts_and_every_page_is_in_one():
    """The table of contents: tutorials, how-to guides, explanation, reference, validation, benchmarks (in that
    order), and no hand-written page left out of it."""
    index = (ROOT / "docs" / "index.md").read_text()
    assert re.findall(r":caption: (.+)", index) == PARTS
    listed = set(re.findall(r"^([a-z]+/[A-Za-z0-9_/-]+)$", index, flags=re.M))
    pages = {p.relative_to(ROOT / "docs").with_suffix("").as_posix() for p in docstats.pages()} - {"index"}
    assert pages == listed - {"reference/generated/cli", "reference/generated/workflows"}


def test_teaching_pages_are_short_and_light_on_numbers():
    """Tutorials, how-to guides and explanation teach: at most 1 500 words a page and 4 numbers per 100 words
    (the measurements live in validation and benchmarks)."""
    heavy = {p.relative_to(ROOT / "docs").as_posix(): docstats.weight(p) for p in docstats.pages(*docstats.TEACHING)}
    assert len(heavy) >= 15
    assert not {k: v for k, v in heavy.items() if v[0] > docstats.MAX_WORDS
                or v[2] > docstats.MAX_NUMBERS_PER_100_WORDS}


def test_no_number_left_the_docs_with_the_topic_pages():
    """Every number the topic pages held before the split (data/docs/topic_numbers.json, counted) is still in
    the pages they went to, or in a validation or benchmark page: nothing measured was lost on the way."""
    import json

    moved = json.loads((ROOT / "data" / "docs" / "topic_numbers.json").read_text())["pages"]
    homes = {p for page in moved.values() for p in page["now"]}
    now = sum((docstats.numbers(p.read_text()) for p in docstats.pages("validation", "benchmarks")
               if p.relative_to(ROOT / "docs").as_posix() not in homes), docstats.Counter())
    now += sum((docstats.numbers((ROOT / "docs" / p).read_text()) for p in homes), docstats.Counter())
    before = sum((docstats.Counter(page["numbers"]) for page in moved.values()), docstats.Counter())
    lost = before - now
    assert not lost, f"numbers of the topic pages found nowhere now: {dict(lost)}"
