"""Compression runs with real LAMMPS: analytic lattice, deck contents, run.sh, resume, failure."""
import json

import math
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from opalflow.runs.record import RunRecord
from opalflow.bpm.facts import SampleFacts

from opalflow.cli import main
from opalflow.bpm.deck import compression_deck
from opalflow.materials import material
from opalflow.bpm.pipeline import build_structure
from opalflow.bpm.run import run_workflow
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec
from opalflow.bpm.loading import LOADINGS
from opalflow.spec import SpecError


def lattice_spec(*sets):
    return load_spec(WORKFLOWS / "lattice_sc.toml", list(sets))


@pytest.fixture(scope="module")
def lattice_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("lattice")
    spec = lattice_spec()
    summary = run_workflow(spec, out, say=lambda *_: None)
    return spec, out, summary


def test_simple_cubic_modulus_matches_bond_stiffness(lattice_run):
    """Acceptance 3: E = k_axial L0 / a^2 = E_b pi r_b^2 / a^2 = pi/4 E_b for r_b = a/2."""
    spec, out, summary = lattice_run
    E_b = material("silica").bond_youngs_modulus_GPa
    analytic = math.pi / 4 * E_b
    assert summary.youngs_modulus_specimen_GPa == pytest.approx(analytic, rel=0.02)
    assert summary.elastic_fit_r2 > 0.999


def test_simple_cubic_particle_stress_equals_applied(lattice_run):
    """Bulk particles' sigma_zz (eq. 21 with V_p, times the solid fraction pi/6) = applied stress."""
    spec, out, summary = lattice_run
    with h5py.File(out / "results.h5") as h:
        (step, snap), = h["snapshots"].items()
        z = snap["position_nm"][:, 2]
        sigma_zz = snap["sigma_MPa"][:, 2]
        strain = snap.attrs["strain"]
        applied = np.interp(strain, h["curve/strain"][:], h["curve/stress_MPa"][:])
    a = spec.lattice.spacing_nm
    bulk = (z > z.min() + 1.5 * a) & (z < z.max() - 1.5 * a)
    phi = math.pi / 6
    assert bulk.sum() > 50
    assert -phi * sigma_zz[bulk].mean() == pytest.approx(applied, rel=0.02)


def test_outputs_of_a_run(lattice_run):
    spec, out, summary = lattice_run
    for f in ("results.h5", "summary.json", "report.md", "stress_strain.png", "stress_hist.png",
              "bond_strain.png", "run.sh", "in.lmp", "data.lmp"):
        assert (out / f).stat().st_size > 0, f
    keys = {"youngs_modulus_GPa", "strength_MPa", "strain_at_peak", "timestep_s", "steps", "wall_s",
            "lammps_s", "broken_bonds", "stress_by_material"}
    assert keys <= set(json.loads((out / "summary.json").read_text()))
    with h5py.File(out / "results.h5") as h:
        assert json.loads(h["provenance"].attrs["spec"])["name"] == "lattice_sc"
        assert h["provenance"].attrs["git_commit"]
    assert summary.broken_bonds == 0


# --- acceptance 4: which scene options add which LAMMPS commands
DECK_TABLE = [
    # (sets, commands that must appear, commands that must not)
    ([], ["bond_style      bpm/rotational normalize yes smooth no break no", "fix             damping"],
     ["pair_style", "granular ${", "titania"]),
    (["contacts.enabled=true"], ["pair_style      granular", "hertz/material"], []),
    (["bonds.breakable=true"], ["smooth yes break yes"], ["break no"]),
    (["compression.snapshot_strains=[]"], [], ["compute         stress", "dump"]),
    (["compression.global_damping=0.0"], [], ["fix             damping"]),
]


@pytest.mark.parametrize("sets,present,absent", DECK_TABLE)
def test_deck_holds_what_the_scene_needs(sets, present, absent):
    spec = lattice_spec(*sets)
    text = compression_deck(spec, build_structure(spec)).in_lmp
    for cmd in present:
        assert cmd in text, cmd
    for cmd in absent:
        assert cmd not in text, cmd


def test_uncoated_unbreakable_contact_free_opal_deck(quick_spec):
    spec = load_spec(WORKFLOWS / "opal_quick.toml", ["contacts.enabled=false", "bonds.breakable=false"])
    deck = compression_deck(spec, build_structure(spec))
    text = deck.in_lmp
    assert "pair_style" not in text and "break no" in text and "titania" not in text
    assert deck.structure.type_names == ["silica", "substrate"]
    assert set(deck.bins.materials) == {"silica"}
    coated = load_spec(WORKFLOWS / "opal_quick.toml", ["coating.thickness_nm=60.0"])
    deck = compression_deck(coated, build_structure(coated))
    assert set(deck.bins.materials) == {"silica", "titania"} and "titania" in deck.structure.type_names


def test_timestep_above_limit_is_refused():
    spec = lattice_spec("compression.timestep_s=1e-9")
    with pytest.raises(Exception, match=r"compression.timestep_s = 1e-09: above the stability limit"):
        compression_deck(spec, build_structure(spec))


def test_run_sh_gives_the_same_modulus_as_in_process(tmp_path, lattice_run):
    """Acceptance 6: bash run.sh (LAMMPS alone) + analyze == the in-process run."""
    _, _, summary = lattice_run
    out = tmp_path / "alone"
    assert main(["build", "lattice_sc", "--out", str(out)]) == 0
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    proc = subprocess.run(["bash", str(out / "run.sh")], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert main(["analyze", str(out)]) == 0
    alone = json.loads((out / "summary.json").read_text())
    assert alone["youngs_modulus_GPa"] == pytest.approx(summary.youngs_modulus_GPa, rel=1e-6)
    assert alone["peak_stress_MPa"] == pytest.approx(summary.peak_stress_MPa, rel=1e-6)   # unbreakable bonds


def test_killed_run_resumes(tmp_path, lattice_run):
    """Acceptance 7: a run killed halfway finishes with --resume within 1 % of an uninterrupted one."""
    _, _, summary = lattice_run
    out = tmp_path / "killed"
    assert main(["build", "lattice_sc", "--out", str(out), "--set", "compression.restart_every_strain=0.0005"]) == 0
    proc = subprocess.Popen(["bash", str(out / "run.sh")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 60
    while time.time() < deadline and len(list(out.glob("restart.*.bin"))) < 2:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    steps_done = max(int(p.name.split(".")[1]) for p in out.glob("restart.*.bin"))
    info = SampleFacts.read(RunRecord.read(out))
    assert 0 < steps_done < info.steps
    assert main(["run", "--out", str(out), "--resume"]) == 0
    resumed = json.loads((out / "summary.json").read_text())
    assert resumed["youngs_modulus_GPa"] == pytest.approx(summary.youngs_modulus_GPa, rel=0.01)
    assert resumed["peak_stress_MPa"] == pytest.approx(summary.peak_stress_MPa, rel=0.01)
    assert resumed["steps"] == summary.steps


def test_failed_run_keeps_earlier_results(tmp_path, capsys):
    """Acceptance 7: a LAMMPS failure exits with the error and log tail and keeps its folder; a finished run's
    results are never replaced (a second run into its folder is refused before anything is written)."""
    out = tmp_path / "run"
    assert main(["run", "lattice_sc", "--out", str(out)]) == 0
    before = (out / "results.h5").read_bytes()
    # a scene that loses an atom: one particle lies outside the (fixed-z) box, so LAMMPS
    # cannot assign it to any process and stops
    from opalflow.lammps.datafile import write_data

    spec = lattice_spec()
    s = build_structure(spec)
    s.positions[-1, 2] = 3 * s.box_hi[2]
    write_data(tmp_path / "bad.lmp", s)
    capsys.readouterr()
    bad = ["--set", "kind=datafile", "--set", f'datafile.path="{tmp_path / "bad.lmp"}"',
           "--set", 'datafile.materials=["silica","substrate"]', "--set", "contacts.enabled=true"]
    assert main(["run", "lattice_sc", "--out", str(out), *bad]) == 2
    assert "holds a finished run" in capsys.readouterr().err
    assert (out / "results.h5").read_bytes() == before
    failed = tmp_path / "failed"
    code = main(["run", "lattice_sc", "--out", str(failed), *bad])
    err = capsys.readouterr().err
    assert code == 1
    assert "LAMMPS failed" in err and "ERROR" in err and "log tail" in err
    assert f"run folder kept: {failed}" in err and (failed / "log.lammps").exists()


def test_rate_check_switch_reports_the_half_speed_run(tmp_path):
    """Acceptance 2 (mechanics of the switch; the quickstart figures are in the closing note)."""
    out = tmp_path / "rate"
    summary = run_workflow(lattice_spec("compression.check_rate=true"), out, say=lambda *_: None)
    rc = summary.rate_check
    assert (out / "rate_half" / "summary.json").exists()
    # the lattice's bonds do not break: no strength, so only E is compared
    assert abs(rc.youngs_modulus_change) < 0.02 and rc.strength_change is None
    assert "Rate check (half plate speed): E changes by" in (out / "report.md").read_text()


def test_datafile_scene_runs_a_users_file(tmp_path, lattice_run):
    """kind = "datafile": a bpm/sphere file from elsewhere goes through the same deck and analysis."""
    from opalflow.lammps.datafile import write_data

    _, _, summary = lattice_run
    s = build_structure(lattice_spec())
    write_data(tmp_path / "mine.lmp", s)
    out = tmp_path / "run"
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "kind=datafile",
                 "--set", f'datafile.path="{tmp_path / "mine.lmp"}"',
                 "--set", 'datafile.materials=["silica","substrate"]']) == 0
    mine = json.loads((out / "summary.json").read_text())
    assert mine["youngs_modulus_GPa"] == pytest.approx(summary.youngs_modulus_GPa, rel=1e-6)


def test_mpi_run_matches(tmp_path, lattice_run):
    """--np 2 runs lmp under mpiexec (the mpich wheel) and gives the same modulus."""
    _, _, summary = lattice_run
    out = tmp_path / "mpi"
    assert main(["run", "lattice_sc", "--out", str(out), "--np", "2"]) == 0
    mpi = json.loads((out / "summary.json").read_text())
    assert mpi["youngs_modulus_GPa"] == pytest.approx(summary.youngs_modulus_GPa, rel=1e-3)


def test_opal_run_carries_its_structure_statistics(tmp_path, quick_spec, quick_structure):
    """Studies plot E against porosity and density: prepare stores them for the run summary."""
    from opalflow.opal.scene import structure_statistics
    from opalflow.bpm.pipeline import prepare
    from opalflow.opal.result import OpalResult

    _, record = prepare(quick_spec, tmp_path)
    info = SampleFacts.read(RunRecord.read(tmp_path))
    assert RunRecord.read(tmp_path).deck == json.loads(json.dumps(record.deck, default=float))  # the record is the file
    stats = structure_statistics(quick_structure)
    assert info.structure == pytest.approx({k: getattr(stats, k) for k in OpalResult.structure_keys()})
    assert OpalResult.structure_keys() == ("porosity", "total_porosity", "density_kg_m3")
    assert 0.3 < info.structure["porosity"] < 0.9


# ----------------------------------------------------------------------------- resume while bonds break
#: opal_quick with weak bonds: about 30 bonds broken at the middle restart file, 130 more after it
BREAKING = ["compression.strain_max=0.012", "compression.restart_every_strain=0.004",
            "compression.snapshot_strains=[0.01]", "materials.silica.bond_strength_MPa=30.0"]


@pytest.fixture(scope="module")
def breaking_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("breaking") / "whole"
    argv = ["run", "opal_quick", "--out", str(out)]
    for s in BREAKING:
        argv += ["--set", s]
    assert main(argv) == 0
    return out


def interrupted(whole, dest, rows_past_restart: int = 7):
    """``whole`` as a kill leaves it: the inputs, the restart files up to the middle one, and the curve
    rows some way past it (written before the kill, after the restart file)."""
    dest.mkdir()
    (dest / "snapshots").mkdir()
    for name in ("data.lmp", "in.lmp", "resume.lmp", "run.sh", "run.json"):
        (dest / name).write_bytes((whole / name).read_bytes())
    record = RunRecord.read(dest)               # as a SIGKILL leaves it: running, its last session not ended
    record.state, record.sessions[-1].ended = "running", ""
    record.write(dest)
    steps = sorted(int(p.name.split(".")[1]) for p in whole.glob("restart.*.bin"))
    restart = steps[len(steps) // 2]
    for step in steps:
        if step <= restart:
            (dest / f"restart.{step}.bin").write_bytes((whole / f"restart.{step}.bin").read_bytes())
    every = SampleFacts.read(RunRecord.read(whole)).output_every_steps
    lines = (whole / "curve.txt").read_text().splitlines(keepends=True)
    (dest / "curve.txt").write_text("".join(
        line for line in lines if line.startswith("#") or int(line.split()[0]) <= restart + rows_past_restart * every))
    return restart


def assert_same_curve(whole, resumed, restart):
    a = np.loadtxt(whole / "curve.txt", comments="#")
    b = np.loadtxt(resumed / "curve.txt", comments="#")
    assert np.all(np.diff(b[:, 0]) > 0), "each step once, in order"
    assert np.array_equal(a[:, 0], b[:, 0])
    before = a[:, 0] <= restart
    assert np.array_equal(a[before], b[before])
    # restarts of granular runs are not bit-exact (velocities at the half step); the curve after the
    # restart agrees to 1e-3 of each column's range
    scale = np.ptp(a, axis=0) + 1e-30
    assert np.all(np.abs(a - b) <= 1e-3 * scale)


def test_breaking_run_resumes_to_the_same_curve(breaking_run, tmp_path):
    """A run killed while bonds break resumes (--resume) to the uninterrupted curve, point by point."""
    whole = breaking_run
    out = tmp_path / "resumed"
    restart = interrupted(whole, out)
    curve = np.loadtxt(whole / "curve.txt", comments="#")
    bonds = SampleFacts.read(RunRecord.read(whole)).n_bonds
    broken_at_restart = bonds - np.interp(restart, curve[:, 0], curve[:, 4])
    assert broken_at_restart >= 10 and bonds - curve[-1, 4] >= broken_at_restart + 50
    assert main(["run", "--out", str(out), "--resume"]) == 0
    assert_same_curve(whole, out, restart)
    a = json.loads((whole / "summary.json").read_text())
    b = json.loads((out / "summary.json").read_text())
    assert b["complete"] and b["youngs_modulus_GPa"] == pytest.approx(a["youngs_modulus_GPa"], rel=0.01)
    assert b["strength_MPa"] == pytest.approx(a["strength_MPa"], rel=0.01)
    assert abs(b["broken_bonds"] - a["broken_bonds"]) <= 0.02 * a["broken_bonds"]


def test_breaking_run_resumes_with_run_sh(breaking_run, tmp_path):
    """bash run.sh resume (LAMMPS alone) continues the same way; analyze reads the whole curve."""
    out = tmp_path / "alone"
    restart = interrupted(breaking_run, out)
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    proc = subprocess.run(["bash", str(out / "run.sh"), "resume"], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert_same_curve(breaking_run, out, restart)
    assert main(["analyze", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["complete"]


def test_analyze_marks_a_run_that_stopped_early(breaking_run, tmp_path, capsys):
    out = tmp_path / "stopped"
    interrupted(breaking_run, out)
    assert main(["analyze", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["steps"] < summary["steps_planned"]
    assert capsys.readouterr().out.startswith("INCOMPLETE run (stopped at step ")
    assert "**Incomplete run**" in (out / "report.md").read_text()


# ----------------------------------------------------------------------------- stability check
def test_stability_check_passes_at_the_estimated_timestep(tmp_path, capsys):
    out = tmp_path / "check"
    assert main(["check", "opal_quick", "--out", str(out), "--steps", "1500"]) == 0
    summary = json.loads((out / "stability.json").read_text())
    assert summary["passed"] and set(summary["run"]["criteria"]) == {
        "finite", "no lost particles", "energy account", "kinetic energy bounded"}
    assert "| energy account | pass |" in (out / "stability.md").read_text()


def test_stability_check_catches_a_timestep_three_times_the_estimate(tmp_path, capsys):
    """A deliberately unstable run (--timestep-factor 3) fails, naming the criterion and its figures."""
    out = tmp_path / "check"
    assert main(["check", "opal_quick", "--out", str(out), "--steps", "1500", "--timestep-factor", "3"]) == 1
    summary = json.loads((out / "stability.json").read_text())
    assert not summary["passed"] and "energy account" in summary["failed"]
    assert "FAIL  energy account: max(KE - W_in) = " in capsys.readouterr().err


def test_stability_check_to_a_strain(tmp_path, capsys):
    """--strain: the check runs until the plate has compressed the sample that far (a dense state), the
    step count from the deck (height / speed / dt); a bad strain is one line."""
    out = tmp_path / "check"
    sets = ["--set", "compression.plate_speed_m_s=50.0", "--set", "lattice.cells_z=6"]
    assert main(["check", "lattice_sc", "--out", str(out), "--strain", "0.2", *sets]) == 0
    summary = json.loads((out / "stability.json").read_text())
    info = summary["run"]
    assert summary["passed"] and summary["strain"] == 0.2
    dt_ns = summary["timestep_s"] * 1e9
    planned = math.ceil(0.2 * 100.0 / 50.0 / dt_ns)        # 6 cells of 20 nm: the mobile part is 100 nm high
    assert planned <= info["steps"] < planned * 1.05
    assert "(to strain 0.2)" in summary["headline"]
    assert main(["check", "lattice_sc", "--out", str(tmp_path / "x"), "--strain", "2"]) == 2
    assert "--strain = 2.0" in capsys.readouterr().err


def test_stability_matrix_writes_one_row_per_case(tmp_path, capsys):
    """The matrix machinery on a small lattice: each row checked at the deck's dt and bisected."""
    wf = tmp_path / "m.toml"
    wf.write_text('name = "m"\nkind = "stability_matrix"\n[matrix]\nsteps = 300\n[matrix.rows]\n'
                  'lattice = { workflow = "lattice_sc", set = ["lattice.cells_z=6"] }\n'
                  'bad = { workflow = "lattice_sc", set = ["lattice.cells_z=1"] }\n')
    out = tmp_path / "out"
    assert main(["run", str(wf), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    good, bad = summary["rows"]
    assert good["passed"] and 0.3 < good["ratio"] <= 1.0 and good["timestep_stable_max_s"] > good["timestep_s"]
    assert bad["error"].startswith("lattice.cells_z = 1")
    report = (out / "report.md").read_text()
    assert "| lattice | `lattice_sc` `lattice.cells_z=6` |" in report and "refused: lattice.cells_z" in report
    wf.write_text('name = "m"\nkind = "stability_matrix"\n[matrix.rows]\nx = { workflow = "a;b" }\n')
    assert main(["run", str(wf), "--out", str(tmp_path / "refused")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("error: matrix.rows.x.workflow = 'a;b'")


@pytest.mark.parametrize("how", ["--resume", "run.sh resume"])
def test_resume_skips_a_restart_file_cut_short_by_the_kill(breaking_run, tmp_path, how):
    """A run killed while writing a restart file leaves it truncated: --resume and run.sh resume set it
    aside (restart.N.damaged) and continue from the one before, to the same curve."""
    out = tmp_path / "cut"
    restart = interrupted(breaking_run, out)
    newest = out / f"restart.{restart}.bin"
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])
    earlier = max(int(p.name.split(".")[1]) for p in out.glob("restart.*.bin") if p != newest)
    if how == "--resume":
        assert main(["run", "--out", str(out), "--resume"]) == 0
    else:
        env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
        proc = subprocess.run(["bash", str(out / "run.sh"), "resume"], capture_output=True, text=True, env=env)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (out / f"restart.{restart}.damaged").exists()
    assert_same_curve(breaking_run, out, earlier)


def kill_at_random_step(argv, out, info, seed, env=None) -> int:
    """Start ``argv`` and SIGKILL it (its whole process group) once curve.txt in ``out`` reaches a
    seeded random step after the first restart file; returns the last curve step written."""
    import random

    kill_at = random.Random(seed).randint(info.restart_every_steps + 1, info.steps - info.output_every_steps)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True)
    deadline, last = time.time() + 120, 0
    while time.time() < deadline and proc.poll() is None and last < kill_at:
        time.sleep(0.05)
        rows = [line for line in (out / "curve.txt").read_text().splitlines() if line[:1].isdigit()] \
            if (out / "curve.txt").exists() else []
        last = int(rows[-1].split()[0]) if rows else 0
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert 0 < last < info.steps, "killed before the end"
    return last


@pytest.mark.parametrize("seed", [1, 2])
def test_run_killed_at_a_random_step_resumes_to_the_same_curve(breaking_run, tmp_path, seed):
    """SIGKILL of 'python -m opalflow run' at a seeded random point while bonds break, then --resume."""
    info = SampleFacts.read(RunRecord.read(breaking_run))
    out = tmp_path / "killed"
    argv = [sys.executable, "-m", "opalflow", "run", "opal_quick", "--out", str(out)]
    for s in BREAKING:
        argv += ["--set", s]
    kill_at_random_step(argv, out, info, seed)
    assert main(["run", "--out", str(out), "--resume"]) == 0
    assert_same_curve(breaking_run, out, info.restart_every_steps)
    a = json.loads((breaking_run / "summary.json").read_text())
    b = json.loads((out / "summary.json").read_text())
    assert b["strength_MPa"] == pytest.approx(a["strength_MPa"], rel=0.01)
    assert b["youngs_modulus_GPa"] == pytest.approx(a["youngs_modulus_GPa"], rel=0.01)


def test_run_sh_killed_at_a_random_step_resumes_with_run_sh(breaking_run, tmp_path):
    """SIGKILL of 'bash run.sh' (LAMMPS alone) at a seeded random point while bonds break, then
    'bash run.sh resume' and analyze: the same curve."""
    import shutil

    info = SampleFacts.read(RunRecord.read(breaking_run))
    out = tmp_path / "alone"
    out.mkdir()
    (out / "snapshots").mkdir()
    for name in ("data.lmp", "in.lmp", "resume.lmp", "run.sh", "run.json"):
        shutil.copy(breaking_run / name, out / name)
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    kill_at_random_step(["bash", str(out / "run.sh")], out, info, 3, env=env)
    resumed = subprocess.run(["bash", str(out / "run.sh"), "resume"], capture_output=True, text=True, env=env)
    assert resumed.returncode == 0, resumed.stdout[-2000:]
    assert_same_curve(breaking_run, out, info.restart_every_steps)
    assert main(["analyze", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["complete"]


def test_lattice_headline_gives_the_checked_modulus_and_no_strength_for_unbreakable_bonds(tmp_path):
    """Was: ``lattice_sc`` printed ``E = 3.627 GPa, strength = 12.75 MPa``: the plate-strain E, 29 % under the
    analytic 5.129 GPa the workflow is about, and a strength for bonds that cannot break."""
    from opalflow.api import run

    s = run("lattice_sc", tmp_path / "sc", quiet=True)
    assert s["headline"].startswith("E (top-layer strain) = ") and "no strength" in s["headline"], s["headline"]
    E = float(s["headline"].split("= ")[1].split()[0])
    ref = s["reference"]["youngs_modulus_specimen_GPa"]
    assert abs(E / ref["value"] - 1) < 0.02 and s["strength_MPa"] is None and s["peak_stress_MPa"] > 0
    assert "none: bonds unbreakable" in (tmp_path / "sc" / "report.md").read_text()


def test_three_point_bending_of_a_lattice_beam_meets_beam_theory(tmp_path, capsys):
    """A loading that is not the top layer pushed (opalflow.bpm.loading.ThreePointBending): the simple-cubic
    beam's flexural modulus from the static solve and from the LAMMPS run against Timoshenko's beam with the
    lattice's EI and GA (LatticeWorkflow.flexural_modulus); its deck holds the supports and the nose, not the
    plate; a sample on a substrate or with periodic sides is refused before anything is written."""
    spec = load_spec(WORKFLOWS / "lattice_bending.toml", [])
    static = run_workflow(load_spec(WORKFLOWS / "lattice_bending.toml", ["compression.method=static"]),
                          tmp_path / "static", say=lambda *_: None)
    reference = static.reference["youngs_modulus_GPa"]["value"]
    assert "Timoshenko" in static.reference["youngs_modulus_GPa"]["source"]
    assert static.youngs_modulus_GPa == pytest.approx(reference, rel=0.01)
    # Euler-Bernoulli alone (no shear) is 2.4 % stiffer: the check tells the two apart
    assert abs(static.youngs_modulus_GPa / reference - 1) < 0.3 * 0.024
    dynamic = run_workflow(spec, tmp_path / "dynamic", say=lambda *_: None)
    assert dynamic.youngs_modulus_GPa == pytest.approx(reference, rel=0.02)
    deck = (tmp_path / "dynamic" / "in.lmp").read_text()
    assert "fix             pin pin setforce 0.0 0.0 0.0" in deck and "v_substrate_fz" in deck
    assert "wall/gran" not in deck and "boundary        m m m" in deck
    assert main(["run", "lattice_bending", "--out", str(tmp_path / "bad"), "--set", "boundary.sides=periodic"]) == 2
    assert "compression.loading = 'bending': needs boundary.sides" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    standing = build_structure(lattice_spec("boundary.sides=open"))      # the lattice on its substrate
    with pytest.raises(SpecError, match="needs a sample without a substrate"):
        LOADINGS["bending"].place(standing, 20.0)
