"""Contact-only scenes on LAMMPS and LIGGGHTS: the same packing, the same plate force."""
import shutil

import pytest

import opalflow

needs_liggghts = pytest.mark.skipif(shutil.which("liggghts") is None,
                                    reason="LIGGGHTS is not installed (Debian package liggghts)")


@needs_liggghts
def test_frictionless_plate_force_is_the_same_on_both_engines(tmp_path):
    """Normal Hertz force and damping are the same model in both: the plate forces agree to 1e-6 over the
    whole compression (measured 7.7e-8; round-off grows chaotically in a longer run)."""
    s = opalflow.run("granular_plate", tmp_path / "g", quiet=True)
    cc = s["cross_check"]
    assert cc["agree"] and cc["max_relative_difference"] < 1e-6 and cc["rows_compared"] > 30
    assert s["plate_force_N"]["lammps"] > 1e-3


@needs_liggghts
def test_with_friction_the_engines_part(tmp_path):
    """The tangential history differs between the codes: with friction the plate forces part by far more."""
    s = opalflow.run("granular_plate", tmp_path / "g", set={"material.friction": 0.5, "plate.steps": 2000},
                     quiet=True)
    assert s["cross_check"]["max_relative_difference"] > 1e-3


def test_lammps_engine_alone_compresses_the_packing(tmp_path):
    s = opalflow.run("granular_plate", tmp_path / "g", set={"engine": "lammps"}, quiet=True)
    assert s["engines"] == ["lammps"] and s["plate_force_N"]["lammps"] > 1e-3


def test_liggghts_engine_is_refused_in_one_line_where_absent(tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(opalflow.spec.InputError, match=r"^engine = 'liggghts': needs the 'liggghts' executable"):
        opalflow.run("granular_plate", tmp_path / "g", set={"engine": "liggghts"})
    assert not (tmp_path / "g").exists()
