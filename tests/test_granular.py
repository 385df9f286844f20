"""Contact-only scenes on LAMMPS and LIGGGHTS: the same packing, the same plate force."""
import shutil

import pytest

import opalflow

needs_liggghts = pytest.mark.skipif(shutil.which("liggghts") is None,
                                    reason="LIGGGHTS is not installed (Debian package liggghts)")


@needs_liggghts
def test_frictionless_plate_force_is_the_same_on_both_engines(tmp_path):
    """Normal Hertz force and damping are the same model in both: the plate forces agree to 1e-6 over the
    whole compression (measured 2.2e-8; round-off grows chaotically in a longer run)."""
    s = opalflow.run("granular_plate", tmp_path / "g", quiet=True)
    cc = s["cross_check"]
    assert cc["agree"] and cc["max_relative_difference"] < 1e-6 and cc["rows_compared"] > 30
    assert s["plate_force_N"]["lammps"] > 1e-3


@needs_liggghts
def test_with_friction_the_engines_part(tmp_path):
    """With friction the packing's contacts slide with damping, spin and close again on earlier partners
    (each parts the codes: test_impacts_...): the plate forces part by far more than round-off."""
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


@needs_liggghts
def test_impacts_agree_where_the_contact_laws_map_and_part_where_they_differ(tmp_path):
    """Single impacts (Chung and Ooi): normal and sticking non-spinning contacts agree to round-off (this
    needs the tangential damping factor x_gamma,t = sqrt(2 (1-nu) / (2-nu)); sqrt(4 (1-nu) / (2-nu)), the factor
    opalflow used before, parts them by 5.9e-2); spin, damped sliding and a second contact of the same pair part them."""
    s = opalflow.run("granular_impacts", tmp_path / "i", quiet=True)
    d = {r["case"]: r for r in s["cases"]}
    assert d["head_on"]["max_relative_difference"] < 1e-12
    assert d["oblique_sticking"]["max_relative_difference"] < 1e-6
    assert d["oblique_spinning"]["max_relative_difference"] > 1e-4
    assert d["oblique_sliding"]["max_relative_difference"] > 1e-3
    second = d["second_contact"]
    assert second["max_relative_difference"] > 1e-2
    # it parts at the second contact, not before: the first one is oblique_sticking's
    assert second["first_step_over_tolerance"] > 2 * d["oblique_sticking"]["steps"]
    assert abs(s["restitution_error"]) < 0.01


@needs_liggghts
def test_undamped_sliding_agrees(tmp_path):
    """Without damping the Coulomb limit of the elastic and of the total tangential force are the same."""
    s = opalflow.run("granular_impacts", tmp_path / "i", set={"material.restitution": 1.0}, quiet=True)
    d = {r["case"]: r for r in s["cases"]}
    assert d["oblique_sliding"]["max_relative_difference"] < 1e-12
    assert d["second_contact"]["verdict"] == "part"


def test_impacts_are_refused_in_one_line_without_liggghts(tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(opalflow.spec.InputError, match=r"^kind = 'granular_impacts': needs the 'liggghts' executable"):
        opalflow.run("granular_impacts", tmp_path / "i")
    assert not (tmp_path / "i").exists()
