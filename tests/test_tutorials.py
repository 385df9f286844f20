"""The tutorials (docs/tutorials/*.md) run as a reader runs them: every block marked ``tutorial`` of a page, in
order, in one fresh folder: shell blocks run their opalflow commands, ``python`` blocks run as they are, a block
marked ``file NAME`` is saved as NAME (a workflow the reader writes).  Each page ends with its pictures: every
``runs/....png`` the page names exists afterwards.  ``set K=V`` on a marker adds ``--set K=V`` to the block's
``run`` commands (a smaller case, said after ``--``), as in tests/test_readme.py."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest

from opalflow.resources import ROOT
from test_readme import MARKER, commands

PAGES = sorted(p for p in (ROOT / "docs" / "tutorials").glob("*.md") if "tutorial" in p.read_text())


def steps(page) -> list[tuple[str, str, dict]]:
    """(fence language, text, marker) of each block of the page, in order."""
    lines, out, i = page.read_text().splitlines(), [], 0
    while i < len(lines):
        if lines[i].startswith("```"):
            j = next(k for k in range(i + 1, len(lines)) if lines[k].startswith("```"))
            m = MARKER.fullmatch(lines[i - 1].strip())
            if m and m["what"] == "tutorial":
                out.append((lines[i][3:].strip(), "\n".join(lines[i + 1:j]), m.groupdict()))
            i = j + 1
        else:
            i += 1
    return out


def test_every_tutorial_has_steps():
    assert len(PAGES) >= 3 and all(steps(p) for p in PAGES)


@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_tutorial_runs_from_a_fresh_folder_to_its_pictures(page, tmp_path):
    for language, text, marker in steps(page):
        name = re.search(r"file (\S+)", marker["args"])
        if name:
            (tmp_path / name.group(1)).write_text(text + "\n")
        elif language == "python":
            proc = subprocess.run([sys.executable, "-c", text], cwd=tmp_path, capture_output=True, text=True)
            assert proc.returncode == 0, f"{page.name}: python block\n{proc.stderr[-3000:]}"
        else:
            sets = re.findall(r"set (\S+=\S+)", marker["args"])
            cmds = commands(text)
            assert cmds, f"{page.name}: a shell block without an opalflow command"
            for cmd in cmds:
                if cmd[3] == "run" and sets:
                    cmd = cmd + [x for s in sets for x in ("--set", s)]
                proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
                assert proc.returncode == 0, f"{page.name}: {' '.join(cmd[1:])}\n{proc.stderr[-3000:]}"
    pictures = sorted(set(re.findall(r"runs/[A-Za-z0-9_./-]+\.png", page.read_text())))
    assert pictures, f"{page.name} names no picture"
    missing = [p for p in pictures if not (tmp_path / p).exists()]
    assert not missing, f"{page.name}: not made: {missing}"
