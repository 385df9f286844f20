"""docs/validation/papers.md: every number opalflow reports beside a paper's comes from the stored result its row names,
and the error shown is opalflow's against the paper's."""
import json
import re

from opalflow.resources import ROOT

PAGE = ROOT / "docs" / "validation" / "papers.md"


def _lookup(data, path: str):
    for part in path.split("."):
        data = data[int(part)] if isinstance(data, list) else data[part]
    return data


def _number(text: str) -> tuple[float, int]:
    """A shown number and its decimals ("25.23" -> (25.23, 2); "8.28x" -> (8.28, 2); "~10x" -> (10.0, 0))."""
    m = re.search(r"-?\d+(?:\.(\d+))?", text.replace(" ", ""))
    return float(m.group(0)), len(m.group(1) or "")


def rows():
    for line in PAGE.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and len(cells) == 6 and cells[5].startswith("`") and "#" in cells[5]:
            yield cells


def test_every_number_is_its_stored_result_and_the_error_is_against_the_paper():
    checked = 0
    for quantity, paper, ours, error, how, result in rows():
        file, _, path = result.strip("`").partition("#")
        stored = float(_lookup(json.loads((ROOT / file).read_text()), path))
        shown, decimals = _number(ours)
        assert abs(shown - stored) <= 0.5 * 10 ** -decimals + 1e-12, (quantity, shown, stored)
        reference, _ = _number(paper)
        shown_error, error_decimals = _number(error)
        assert abs(shown_error - 100 * (stored / reference - 1)) <= 0.5 * 10 ** -error_decimals + 1e-9, \
            (quantity, shown_error, 100 * (stored / reference - 1))
        assert how.startswith("`run ") and how.strip("`").split()[1] in {p.stem for p in (ROOT / "workflows").glob("*.toml")}
        checked += 1
    assert checked >= 15
