"""What the documentation's pages weigh: words and numbers of the prose (fenced blocks and HTML comments left
out; a number is a run of digits with its decimal point or commas), for tests/test_docs.py and for the
reader: ``python docs/_ext/docstats.py [PAGE ...]`` prints each page's words, numbers and numbers per 100
words (every page of docs/ by default)."""
from __future__ import annotations

import re
import sys
from collections import Counter
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1]
NUMBER = re.compile(r"\d+(?:[.,]\d+)*")
#: the parts that teach (issue 57: at most 4 numbers per 100 words, at most 1 500 words a page); reference,
#: validation and benchmark pages carry the measurements and are not held to it
TEACHING = ("tutorials", "howto", "explanation")
MAX_NUMBERS_PER_100_WORDS, MAX_WORDS = 4.0, 1500


def prose(text: str) -> str:
    return re.sub(r"<!--.*?-->", "", re.sub(r"```.*?```", "", text, flags=re.S), flags=re.S)


def weight(page: Path) -> tuple[int, int, float]:
    """(words, numbers, numbers per 100 words) of a page's prose."""
    text = prose(page.read_text())
    words, numbers = len(text.split()), len(NUMBER.findall(text))
    return words, numbers, 100 * numbers / max(words, 1)


def numbers(text: str) -> Counter:
    """Every number of a text, code and all, counted."""
    return Counter(NUMBER.findall(text))


def pages(*parts: str) -> list[Path]:
    """The hand-written pages of docs/ (of ``parts``, its folders, where given)."""
    found = sorted(p for p in DOCS.rglob("*.md") if not {"generated", "_build"} & set(p.relative_to(DOCS).parts)
                   and p.relative_to(DOCS).as_posix() != "figures/README.md")
    return [p for p in found if not parts or p.relative_to(DOCS).parts[0] in parts]


if __name__ == "__main__":
    for page in [Path(p) for p in sys.argv[1:]] or pages():
        w, n, d = weight(page)
        print(f"{page.resolve().relative_to(DOCS)!s:40} {w:6d} words {n:5d} numbers {d:5.1f} per 100 words")
