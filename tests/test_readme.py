"""The README and the documentation pages (docs/**/*.md, not the generated reference) run as tests: every fenced
block carries a marker comment right above it that says how it is checked, and this file does it.

Markers (``<!-- test: WHAT -- why -->``):

- ``run``: each opalflow command of the block runs in a fresh folder, exit 0 (``&&`` chains: the venv and
  pip segments are not repeated, .ci/run installs the same way); ``skip "TEXT"`` leaves out the commands
  that hold TEXT and ``set K=V`` adds ``--set K=V`` to each run (small sizes), both said after ``--``;
  ``needs "PART"`` skips the block, with that reason, where an optional part (``liggghts``) is absent;
- ``not-run``: the reason follows ``--``;
- ``output``: the block is what the command after ``--`` prints on stderr;
- ``synopsis``: every verb and option shown exists in the CLI;
- ``python``: the block runs as it is; each ``print`` whose comment holds numbers prints them;
- ``toml``: the block is a valid section of a workflow;
- ``paths``: every path the block names exists.
"""
from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tomllib

import pytest

from opalflow.resources import ROOT

README = ROOT / "README.md"
#: the pages whose blocks run: the README and docs/ (its generated reference and build output left out)
PAGES = [README, *sorted(p for p in (ROOT / "docs").rglob("*.md")
                         if not {"generated", "_build"} & set(p.relative_to(ROOT / "docs").parts))]
MARKER = re.compile(r"<!-- test: (?P<what>[a-z-]+)(?P<args>[^>]*?)(?: -- (?P<why>.*?))? -->")


def page_text() -> str:
    """All the pages, one after the other (a section may live on any of them)."""
    return "\n\n".join(p.read_text() for p in PAGES)


def blocks() -> list[tuple[str, str, dict]]:
    """(page:line, text, marker) of every fenced block of every page; marker {} where the line above has none."""
    out = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        i = 0
        while i < len(lines):
            if lines[i].startswith("```"):
                j = next(k for k in range(i + 1, len(lines)) if lines[k].startswith("```"))
                m = MARKER.fullmatch(lines[i - 1].strip()) if i else None
                out.append((f"{page.relative_to(ROOT)}:{i + 1}", "\n".join(lines[i + 1:j]), m.groupdict() if m else {}))
                i = j + 1
            else:
                i += 1
    return out


def commands(text: str) -> list[list[str]]:
    """The opalflow commands of a shell block, as argument lists for this interpreter."""
    joined = re.sub(r"\\\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        for part in line.split("&&"):
            words = shlex.split(re.sub(r"\[[^\]]*\]", "", part), comments=True)
            if "-m" in words and "opalflow" in words:
                k = words.index("opalflow")
                out.append([sys.executable, "-m", "opalflow", *words[k + 1:]])
    return out


BLOCKS = blocks()
TIME = re.compile(r"(~?)(\d+(?:\.\d+)?) (s|min|h)\b")


def quoted_times(text: str) -> list[tuple[dict, str]]:
    """(time quoted, command line) for each opalflow command of a block whose comment (or the comment line
    above it) quotes a time: {"text": "~10 s", "seconds": 10.0, "approximate": True}."""
    out, pending = [], None
    for line in re.sub(r"\\\n\s*", " ", text).splitlines():
        comment = line.split("#", 1)[1] if "#" in line else ""
        m = TIME.search(comment)
        if line.strip().startswith("#"):
            pending = m
            continue
        m = m or pending
        pending = None
        if m and "-m opalflow" in line:
            seconds = float(m.group(2)) * {"s": 1, "min": 60, "h": 3600}[m.group(3)]
            out.append(({"text": m.group(0), "seconds": seconds, "approximate": bool(m.group(1))}, line))
    return out


def test_every_block_says_how_it_is_tested():
    unmarked = [line for line, _, m in BLOCKS if not m]
    assert not unmarked, f"blocks without a <!-- test: ... --> marker at {unmarked}"
    for line, _, m in BLOCKS:
        if m["what"] in ("not-run", "output") or "skip" in m["args"] or "set" in m["args"]:
            assert (m["why"] or "").strip(), f"{line}: '{m['what']}' needs its reason after --"


def _ids(kind):
    return [pytest.param(text, m, id=line.replace("README.md:", "line").replace("/", "_"))
            for line, text, m in BLOCKS if m.get("what") == kind]


@pytest.mark.parametrize("text,marker", _ids("run"))
def test_readme_commands_run(text, marker, tmp_path):
    from opalflow.regress import available

    for part in re.findall(r'needs "([^"]+)"', marker["args"]):
        if not available(part):
            pytest.skip(f"needs {part}, not found here (optional: the README block runs it)")
    skips = re.findall(r'skip "([^"]+)"', marker["args"])
    sets = re.findall(r"set (\S+=\S+)", marker["args"])
    ran = 0
    for cmd in commands(text):
        if any(s in " ".join(cmd) + " " for s in skips):
            continue
        if cmd[3] == "run" and sets:
            cmd = cmd + [x for s in sets for x in ("--set", s)]
        proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
        assert proc.returncode == 0, f"{' '.join(cmd[1:])}\n{proc.stderr[-3000:]}"
        ran += 1
        if cmd[3:5] == ["run", "quickstart"] and "--set" not in cmd:      # the README's first command
            from opalflow import regress
            from opalflow.io import load_results

            out = tmp_path / cmd[cmd.index("--out") + 1]
            checks = regress.compare("quickstart", regress.read_reference("quickstart"), load_results(out))
            assert not [c for c in checks if c.failed], "\n".join(regress.table(checks, "quickstart"))
    assert ran, "no command of the block ran"


@pytest.mark.parametrize("text,marker", _ids("output"))
def test_readme_output_is_what_the_command_prints(text, marker, tmp_path):
    cmd = commands(marker["why"].replace("DIR", str(tmp_path / "out")))[0]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert proc.stderr.strip() == text.strip()


def test_readme_synopsis_names_real_verbs_and_options():
    from opalflow.cli import parser

    texts = [t for _, t, m in BLOCKS if m.get("what") == "synopsis"]
    assert texts
    sub = next(a for a in parser()._actions if a.dest == "command")
    for line in "\n".join(texts).splitlines():
        words = line.split("#")[0].split()
        verb = words[3]
        assert verb in sub.choices, line
        known = {o for a in sub.choices[verb]._actions for o in a.option_strings}
        for w in re.findall(r"--[a-z-]+", " ".join(words)):
            assert w in known, f"{verb}: {w}"


@pytest.mark.parametrize("text,marker", _ids("python"))
def test_readme_python_prints_what_it_promises(text, marker, tmp_path):
    proc = subprocess.run([sys.executable, "-c", text], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = proc.stdout.strip().splitlines()
    promised = [line.split("#", 1)[1] for line in text.splitlines() if line.startswith("print(") and "#" in line]
    assert len(printed) == sum(1 for line in text.splitlines() if line.startswith("print("))
    number = r"-?\d+(?:\.\d+)?(?:e-?\d+)?"
    for want, got in zip(promised, printed):
        want = want.split("(", 1)[0]
        for w, g in zip(re.findall(number, want), re.findall(number, got)):
            digits = len(w.split(".")[1]) if "." in w else 0
            assert round(float(g), digits) == pytest.approx(float(w)), (want, got)


def test_readme_toml_is_a_valid_section(tmp_path, monkeypatch):
    """Each TOML block is valid in a workflow (its data file, where it names one, is a frame of rods written in
    the same format as LAMMPS's BPM examples)."""
    from opalflow.api import raw_workflow
    from opalflow.registry import spec_from_dict
    from test_datafile import rod_frame

    monkeypatch.chdir(tmp_path)
    for _, text, m in BLOCKS:
        if m.get("what") == "toml":
            raw = raw_workflow("quickstart")
            raw.update(tomllib.loads(text))
            if "datafile" in raw:
                rod_frame(raw["datafile"]["path"], cells=3)
            spec_from_dict(raw, raw_workflow("quickstart"))      # (a block that switches the kind: as --set does)


def test_readme_layout_names_existing_paths():
    (text,) = [t for _, t, m in BLOCKS if m.get("what") == "paths"]
    for line in text.splitlines():
        head = line.split("  ")[0].split()
        if line.startswith(" ") or not head:
            continue
        for p in head:
            assert (ROOT / p).exists(), p



def test_readme_workflows_table_lists_every_workflow():
    """Was: the table left out the four aerogel_* workflows."""
    text = page_text()
    table = text[text.index("### Workflows"):]
    table = table[:table.index("\n\n", table.index("|---|"))]
    listed = set(re.findall(r"^\| `([a-z0-9_]+)` \|", table, re.MULTILINE))
    assert listed == {p.stem for p in (ROOT / "workflows").glob("*.toml")}


def test_readme_command_times_come_from_bench_results():
    """Every time quoted beside a README command is in bench/results/readme.json (bench/bench_readme.py),
    measured there (the whole command) or predicted by plan, within 25 % (50 % where it says "~")."""
    import json

    bench = json.loads((ROOT / "bench" / "results" / "readme.json").read_text())
    rows = {r["command"]: r for r in bench["rows"]}
    for _, text, _ in BLOCKS:
        for quoted, command in quoted_times(text):
            key = command.split("#")[0].strip()
            assert key in rows, f"no bench/results/readme.json row for {key}: run python bench/bench_readme.py"
            row = rows[key]
            assert row["seconds"] and row.get("exit", 0) == 0, row
            slack = 0.5 if quoted["approximate"] else 0.25
            assert abs(quoted["seconds"] / row["seconds"] - 1) <= slack, (key, round(row["seconds"], 1), row["how"])



def test_readme_peer_table_is_the_benchs_json():
    """The README's comparison with the tuned LAMMPS peer quotes bench/results/peer_static.json (bench/bench_peer.py):
    each measured row's steps and loop and whole-command ratios to 1 % and 0.1 %, as the .json has them."""
    import json

    bench = json.loads((ROOT / "bench" / "results" / "peer_static.json").read_text())
    text = page_text()
    section = text[text.index("**Against what a LAMMPS user does instead**"):]
    section = section[:section.index("\n\n", section.index("|---|"))]
    rows = {line.split("|")[1].strip(): line for line in section.splitlines() if re.match(r"^\| \d", line)}
    measured = [r for r in bench["rows"] if "ratio_command_to_1%" in r]
    assert measured and all(r["start"] == "affine" for r in measured)
    for r in measured:
        line = rows[f"{r['diameter_nm']:g}"]
        for cell in (f"{r['steps_to_1%']} / {r['steps_to_0.1%']}",
                     f"{r['ratio_loop_to_1%_over_setup_solve']:.2f}x / {r['ratio_loop_to_0.1%_over_setup_solve']:.1f}x",
                     f"{r['ratio_command_to_1%']:.2f}x / {r['ratio_command_to_0.1%']:.2f}x"):
            assert cell in line, (cell, line)


def test_the_test_commands_time_is_the_test_suites_bench():
    """The minutes the README quotes beside its test command are bench/results/test_suite.json's whole CI run
    (bench/bench_test_suite.py: .ci/run in a fresh clone), within 25 %, and that run passed."""
    import json

    bench = json.loads((ROOT / "bench" / "results" / "test_suite.json").read_text())
    line = next(ln for ln in README.read_text().splitlines() if "install and run the tests" in ln)
    minutes = float(re.search(r"~(\d+) min", line).group(1))
    assert bench["exit"] == 0 and not bench.get("failed") and abs(minutes * 60 / bench["whole_s"] - 1) <= 0.25
