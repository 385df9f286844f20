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
    raw = apply_overrides({}, ["pores.arrangement=random", "pores.porosity=0.49"])
    assert raw == {"pores": {"arrangement": "random", "porosity": 0.49}}


def test_set_changes_the_spec():
    spec = load_spec(WORKFLOWS / "opal_random.toml", ["pores.porosity=0.63", "packing.seed=7"])
    assert spec.pores.porosity == 0.63 and spec.packing.seed == 7


def test_every_shipped_workflow_validates():
    for path in WORKFLOWS.glob("*.toml"):
        load_spec(path)
