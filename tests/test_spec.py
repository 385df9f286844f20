"""Spec validation: one line naming the field, exit 2, nothing written."""
import subprocess
import sys

import pytest

from opalflow.registry import load_spec
from opalflow.spec import SpecError, apply_overrides, parse_value
from opalflow.resources import WORKFLOWS

from conftest import assert_refused

BAD = [
    (["packing.diameter_nm=-15"], "packing.diameter_nm"),
    (["coating.thickness_nm=200"], "coating.thickness_nm"),
    (["pores.cells_x=1", "pores.diameter_nm=800", "pores.spacing_nm=700"], "pores.diameter_nm"),
    (["pores.arrangement=hcp"], "pores.arrangement"),
    (["pores.arrangement=random", "pores.porosity=1.0"], "pores.porosity"),
    (['name="my opal"'], "name"),
    (['name="opal;shell"'], "name"),
    (['coating.material="titania; shell rm -rf /"'], "coating.material"),
    (["pores.colour=1"], "pores.colour"),
    (["packing.diameter_nm=true"], "packing.diameter_nm"),
]


@pytest.mark.parametrize("sets,field", BAD)
def test_bad_spec_one_line_nothing_written(tmp_path, capsys, sets, field):
    out = tmp_path / "run"
    assert_refused(capsys, ["build", "opal_quick", "--out", str(out)], sets, field, out)


def test_bad_spec_exit_code_from_shell(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "opalflow", "build", "opal_quick", "--out", str(out),
                           "--set", "packing.diameter_nm=-1"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "error: packing.diameter_nm = -1.0: must be in [1e-3, 1e5] nm"]
    assert not out.exists()


def test_unknown_section_key_in_file(tmp_path):
    f = tmp_path / "w.toml"
    f.write_text('name = "x"\n[packing]\ndiameter = 15\n')
    with pytest.raises(SpecError, match=r"^packing.diameter = 15: unknown key"):
        load_spec(f)


def test_overrides_parse_toml_values():
    assert parse_value("0.49") == 0.49
    assert parse_value("3") == 3
    assert parse_value("random") == "random"
    assert parse_value('"a b"') == "a b"
    raw = {}
    apply_overrides(raw, ["pores.arrangement=random", "pores.porosity=0.49"])
    assert raw == {"pores": {"arrangement": "random", "porosity": 0.49}}


def test_set_changes_the_spec():
    spec = load_spec(WORKFLOWS / "opal_random.toml", ["pores.porosity=0.63", "packing.seed=7"])
    assert spec.pores.porosity == 0.63 and spec.packing.seed == 7


def test_every_shipped_workflow_validates():
    for path in WORKFLOWS.glob("*.toml"):
        load_spec(path)


@pytest.mark.parametrize("command, workflow, sets, section, readers", [
    ("run", "tersoff_properties", ["compression.bogus=1"], "compression", "opal, lattice, datafile, aerogel"),
    ("build", "quickstart", ["lattice.spacing_nm=nan", "lattice.bogus=1"], "lattice", "lattice"),
    ("build", "quickstart", ['datafile.path="/nonexistent"'], "datafile", "datafile"),
    ("run", "aerogel_dlca", ['compression.method="quasistatic"'], "compression", "opal, lattice, datafile, aerogel"),
    ("plan", "polycrystal_tension", ['compression.method="quasistatic"'], "compression", "opal")])
def test_a_section_the_kind_does_not_read_is_refused_naming_who_reads_it(tmp_path, capsys, command, workflow, sets,
                                                                         section, readers):
    """A setting in a section the kind does not read did nothing and said nothing (exit 0; the aerogel and
    polycrystal ran for minutes): now one line naming the section and the kinds that read it, exit 2, nothing
    written."""
    from opalflow.cli import main

    out = tmp_path / "x"
    argv = [command, workflow] + (["--out", str(out)] if command != "plan" else [])
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"error: [{section}]: kind ") and readers in err, err
    assert not out.exists()


def test_a_switched_kind_leaves_out_the_files_own_sections_and_executor_is_checked(tmp_path, capsys):
    """--set kind=... switches a workflow file to another kind (its own sections left out); [executor] is every
    kind's and checked for a single run too (`plan quickstart --set 'executor.partition=a;rm -rf /tmp/x'` printed a
    SLURM request with that string)."""
    spec = load_spec(WORKFLOWS / "lattice_sc.toml", ["kind=opal"])
    assert spec.kind == "opal"
    for command in ("plan", "build"):
        argv = [command, "quickstart"] + (["--out", str(tmp_path / "x")] if command == "build" else [])
        assert_refused(capsys, argv, ['executor.partition="a;rm -rf /tmp/x"'], "executor.partition", tmp_path / "x")


def test_a_megabyte_name_is_refused_in_a_short_line(tmp_path, capsys):
    """A 1 MB name went into data.lmp, in.lmp and resume.lmp headers, 2 MB run.json and summary.json and 1 MB on the
    terminal: names are at most 64 characters, a refusal echoes at most 120 of a value, nothing is written."""
    import re

    from opalflow.cli import main

    text = (WORKFLOWS / "lattice_sc.toml").read_text()
    long = tmp_path / "long.toml"
    long.write_text(re.sub(r"^name = .*$", 'name = "' + "a" * 1_000_000 + '"', text, count=1, flags=re.M))
    out = tmp_path / "x"
    assert main(["build", str(long), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err) < 300 and "at most 64 characters" in err and "(1000002 characters)" in err, err[:300]
    assert not out.exists()
    assert main(["build", str(long), "--out", str(out), "--set", 'description="two\\nlines"', "--set", 'name="ok"']) == 2
    assert "one line" in capsys.readouterr().err


def test_a_finished_run_is_not_replaced_and_a_nameless_file_takes_its_stem(tmp_path, capsys):
    """`run` into a finished run's folder replaced it silently while `build` refused; a workflow without `name`
    printed "building opal (datafile)"."""
    import json

    from opalflow.cli import main

    text = "\n".join(line for line in (WORKFLOWS / "lattice_sc.toml").read_text().splitlines()
                     if not line.startswith("name ="))
    (tmp_path / "my_lattice.toml").write_text(text)
    assert main(["build", str(tmp_path / "my_lattice.toml"), "--out", str(tmp_path / "built")]) == 0
    said = capsys.readouterr()
    assert "building my_lattice (lattice)" in said.out + said.err
    out = tmp_path / "run"
    small = ["--set", "compression.method=static"]
    assert main(["run", str(tmp_path / "my_lattice.toml"), "--out", str(out), *small]) == 0
    capsys.readouterr()
    before = (out / "summary.json").read_text()
    assert json.loads(before)["workflow"] == "my_lattice"
    assert main(["run", "lattice_sc", "--out", str(out), *small]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --out = ") and "holds a finished run" in err
    assert (out / "summary.json").read_text() == before
