"""Studies: sweep cache (real LAMMPS on small lattices), kill and rerun, fits, the Newton calibration."""
import json
import os
import signal
import subprocess
import time
import sys

import numpy as np
import pytest

from opalflow.opal.result import OpalResult
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec
from opalflow.studies import run as studies
from opalflow.studies import sweep
from opalflow.runs import executors
from opalflow.runs import jobs as jobs_mod
from opalflow.runs.executors import run_jobs
from opalflow.runs.result import table_of
from opalflow.runs.spec import ExecutorSpec

LOCAL1 = ExecutorSpec(workers=1)
from opalflow.analysis.fits import fit_exponential, fit_power, fit_power_law

LATTICE = ["compression.strain_max=0.002", "compression.snapshot_strains=[0.001]", "lattice.cells_z=6"]


def lattice_jobs(spacings=(20.0, 22.0, 24.0)):
    return [sweep.Job(f"a{a:g}", load_spec(WORKFLOWS / "lattice_sc.toml", [*LATTICE, f"lattice.spacing_nm={a}"]))
            for a in spacings]


def test_rerun_of_a_finished_sweep_does_no_lammps_work(tmp_path, monkeypatch):
    jobs = lattice_jobs()
    first = run_jobs(jobs, tmp_path, LOCAL1, say=lambda m: None)
    assert list(first) == ["a20", "a22", "a24"] and all(o.state == "finished" for o in first.values())
    assert all((tmp_path / "jobs" / f"{j.label}-{j.key[:12]}" / "log.lammps").exists() for j in jobs)

    def no_lammps(*args):
        raise AssertionError("a finished job was run again")

    monkeypatch.setattr(executors, "run_job", no_lammps)
    again = run_jobs(jobs, tmp_path, LOCAL1, say=lambda m: None)
    assert again == first


def test_a_changed_spec_is_a_new_job(tmp_path):
    a, b = lattice_jobs((20.0, 20.0))
    b.spec.compression.plate_speed_m_s *= 0.5
    assert a.key != b.key and a.folder(tmp_path) != b.folder(tmp_path)
    assert jobs_mod.spec_hash(a.spec) == jobs_mod.spec_hash(lattice_jobs((20.0,))[0].spec)


DRIVER = """
import sys
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec
from opalflow.studies import sweep
from opalflow.runs.executors import run_jobs
from opalflow.runs.spec import ExecutorSpec
LATTICE = {lattice!r}
jobs = [sweep.Job(f"a{{a:g}}", load_spec(WORKFLOWS / "lattice_sc.toml", [*LATTICE, f"lattice.spacing_nm={{a}}"]))
        for a in (20.0, 22.0, 24.0)]
if __name__ == "__main__":
    run_jobs(jobs, sys.argv[1], ExecutorSpec(workers=1), say=lambda m: print(m, flush=True))
"""


def test_killed_sweep_completes_only_the_missing_jobs(tmp_path):
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER.format(lattice=LATTICE))
    root = tmp_path / "study"
    proc = subprocess.Popen([sys.executable, str(driver), str(root)], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    for line in proc.stdout:
        if line.startswith("job a20 done"):
            os.killpg(proc.pid, signal.SIGKILL)
            break
    proc.wait()
    done = sorted(p.parent.name for p in root.glob("jobs/*/summary.json"))
    assert done == [j.folder(root).name for j in lattice_jobs()[:1]]
    stamp = (lattice_jobs()[0].folder(root) / "summary.json").stat().st_mtime_ns
    log = subprocess.run([sys.executable, str(driver), str(root)], capture_output=True, text=True, check=True).stdout
    assert "3 jobs: 1 finished before, 2 to run" in log
    assert (lattice_jobs()[0].folder(root) / "summary.json").stat().st_mtime_ns == stamp
    assert len(list(root.glob("jobs/*/summary.json"))) == 3


TERM_DRIVER = """
import sys
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec
from opalflow.studies import sweep
from opalflow.runs.executors import run_jobs
from opalflow.runs.spec import ExecutorSpec
LATTICE = {lattice!r}
jobs = [sweep.Job(f"a{{a:g}}", load_spec(WORKFLOWS / "lattice_sc.toml", [*LATTICE, "compression.strain_max=0.5",
                                                                       f"lattice.spacing_nm={{a}}"]))
        for a in (20.0, 22.0)]
if __name__ == "__main__":
    run_jobs(jobs, sys.argv[1], ExecutorSpec(workers=2), say=lambda m: print(m, flush=True))
"""


def test_a_study_killed_stops_its_jobs(tmp_path):
    """Was: a study's process killed (SIGTERM) left its local jobs running, one holding its folder's lock against
    the next study; now its jobs are asked to stop and end with it."""
    import time

    from opalflow.runs.record import RunRecord

    driver = tmp_path / "driver.py"
    driver.write_text(TERM_DRIVER.format(lattice=LATTICE))
    root = tmp_path / "study"
    proc = subprocess.Popen([sys.executable, str(driver), str(root)], stdout=subprocess.DEVNULL)
    pids, t0 = {}, time.time()
    while len(pids) < 2 and time.time() - t0 < 120:          # both jobs' processes running
        for rec_file in root.glob("jobs/*/run.json"):
            rec = RunRecord.read_or_none(rec_file.parent)
            if rec is not None and rec.state == "running" and rec.sessions and rec.sessions[-1].pid:
                pids[rec_file.parent.name] = rec.sessions[-1].pid
        time.sleep(0.05)
    assert len(pids) == 2 and proc.poll() is None
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) != 0
    for pid in pids.values():
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert not list(root.glob("jobs/*/summary.json"))


def test_a_study_of_one_worker_stops_with_its_job(tmp_path):
    """Was: with executor.workers = 1 (then the jobs in the study's own process) SIGTERM stopped the running job
    and the study went on with the next one, to "too few jobs finished" and exit 0.  The study stops with the job:
    exit 143, the line that says how to go on, the stopped job resumable and the next one not started."""
    import time

    from opalflow.runs.record import RunRecord

    out = tmp_path / "study"
    cmd = [sys.executable, "-m", "opalflow", "run", "porosity", "--out", str(out), "--set", "study.base=opal_quick",
           "--set", "study.porosities=[0.3, 0.4]", "--set", "study.seeds=[1]", "--set", "executor.workers=1",
           "--set", 'study.set=["pores.porosity_tolerance=0.1","compression.strain_max=0.01",'
                    '"compression.snapshot_strains=[]"]']
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    t0 = time.time()
    while not list(out.glob("jobs/*/progress.json")) and time.time() - t0 < 120:    # the first job's LAMMPS runs
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143, err[-2000:]
    assert err.strip().splitlines()[-1].startswith("terminated (SIGTERM)"), err[-2000:]
    states = sorted(RunRecord.read(p.parent).state for p in out.glob("jobs/*/run.json"))
    assert states == ["pending", "requeued"], states


# ----------------------------------------------------------------------------- fits
def test_power_and_exponential_fits_recover_their_laws():
    rng = np.random.default_rng(3)
    eps = np.repeat([0.3, 0.36, 0.42, 0.49, 0.55, 0.62], 5)
    e = 22.06 * (1 - eps) ** 1.92 * np.exp(rng.normal(0, 0.03, eps.size))
    power, expo = fit_power(eps, e), fit_exponential(eps, e)
    assert power.exponent_ci[0] < 1.92 < power.exponent_ci[1]
    assert power.prefactor_ci[0] < 22.06 < power.prefactor_ci[1]
    sig = 576.3 * np.exp(-3.85 * eps) * np.exp(rng.normal(0, 0.03, eps.size))
    s = fit_exponential(eps, sig)
    assert s.exponent_ci[0] < 3.85 < s.exponent_ci[1]
    assert power.r2 > 0.9 and expo.n == 30
    cost = fit_power_law([80.0, 60.0, 45.0], [40.0 * (80 / d) ** 4 for d in (80.0, 60.0, 45.0)])
    assert cost.exponent == pytest.approx(-4.0, abs=1e-9)


# ----------------------------------------------------------------------------- calibration
def test_newton_calibration_on_a_known_model(tmp_path, monkeypatch):
    """The iteration of eqs. 18-19 alone (the DEM runs replaced by a known smooth response,
    E = 0.26 E_b, sigma = 0.44 sigma_b (1 + 0.02 E_b / 6.53)): it must meet 0.5 % in <= 8 runs."""
    calls = []

    def fake_sweep(spec, out, jobs, say):
        out_ = {}
        for job in jobs:
            mat = job.spec.materials["silica"]
            e_b, s_b = mat["bond_youngs_modulus_GPa"], mat["bond_strength_MPa"]
            calls.append((e_b, s_b))
            out_[job.label] = OpalResult(youngs_modulus_GPa=0.26 * e_b,
                                         strength_MPa=0.44 * s_b * (1 + 0.02 * e_b / 6.53), wall_s=0.0)
        return out_

    monkeypatch.setattr(studies, "sweep", fake_sweep)
    for jacobian in ("decoupled", "full"):
        calls.clear()
        spec = load_spec(WORKFLOWS / "calibrate_silica.toml", [f'study.jacobian="{jacobian}"'])
        cal = studies.calibration(spec, tmp_path, lambda m: None)
        assert cal.converged and cal.dem_runs <= 8 and cal.dem_runs == len(calls)
        assert abs(cal.youngs_modulus_GPa / 1.7 - 1) <= 0.005
        assert abs(cal.strength_MPa / 41.3 - 1) <= 0.005
        assert any("| 1 |" in line for line in studies.calibration_render(spec, cal, tmp_path))
        summary = table_of(cal)          # summary.json's keys, as before the result was a class
        assert set(summary) == {"youngs_modulus_GPa", "strength_MPa", "dem_runs", "bond_E_GPa", "bond_strength_MPa",
                                "converged", "history", "jacobian", "targets", "headline"}
        assert set(summary["history"][0]) == {"iteration", "bond_E_GPa", "bond_strength_MPa", "youngs_modulus_GPa",
                                              "strength_MPa", "error_E", "error_strength", "dem_runs", "fd_points",
                                              "wall_s"}


def test_study_specs_validate_and_build_their_jobs():
    spec = load_spec(WORKFLOWS / "porosity.toml")
    job = studies.job_spec(spec, {"pores.arrangement": "random", "pores.porosity": 0.49})
    assert job.pores.cells_x == 2 and job.packing.diameter_nm == 110.0 and job.pores.porosity == 0.49
    paper = load_spec(WORKFLOWS / "calibrate_silica.toml", ["study.paper_scale=true"])
    assert studies.job_spec(paper).packing.diameter_nm == 15.0


@pytest.mark.parametrize("name", ["porosity", "porosity_strength", "coating_strength", "coating", "convergence",
                                  "bulk_silica", "calibrate_silica", "fracture_sides"])
def test_a_study_at_paper_scale_runs_the_papers_sample_not_the_coarse_one(name):
    """study.paper_scale = true: the jobs are opal_fcc's sample (d = 15 nm, 4 x 2 cells, its tile) with
    study.paper_set, not study.set (whose coarse d = 110 or 30 nm undid the paper's sample, and whose tile
    of 380 nm at d = 110 nm was refused: `plan porosity --set study.paper_scale=true` failed)."""
    from opalflow.runs.plan import jobs_of

    spec = load_spec(WORKFLOWS / f"{name}.toml", ["study.paper_scale=true"])
    paper = load_spec(WORKFLOWS / "opal_fcc.toml")
    coarse = studies.job_spec(load_spec(WORKFLOWS / f"{name}.toml"))
    jobs = jobs_of(spec)                        # every job's spec made and validated
    job = studies.job_spec(spec)
    assert (job.pores.cells_x, job.pores.cells_y) == (paper.pores.cells_x, paper.pores.cells_y)
    assert job.packing.diameter_nm == 15.0 != coarse.packing.diameter_nm
    if name not in ("bulk_silica", "convergence"):        # (these two set each job's diameter)
        assert job.packing.tile_nm == paper.packing.tile_nm
        assert all(j.spec.packing.diameter_nm == 15.0 for j in jobs)
    if any(s.startswith("compression.strain_max") for s in spec.study.set):
        assert job.compression.strain_max == coarse.compression.strain_max


def test_a_porosity_study_at_another_resolution_changes_only_the_particles(tmp_path, capsys):
    """study.diameter_nm: the same paper-scale porosity study with d = 30 nm particles (the resolution study of
    issue 56): every job's diameter set, its labels, pores, seeds and run settings the d = 15 nm study's; 0 keeps
    the base's; a diameter out of range is refused in one line before anything is written."""
    from conftest import assert_refused
    from opalflow.runs.plan import jobs_of

    paper = ["study.paper_scale=true"]
    fine = jobs_of(load_spec(WORKFLOWS / "porosity_strength.toml", paper))
    coarse = jobs_of(load_spec(WORKFLOWS / "porosity_strength.toml", [*paper, "study.diameter_nm=30"]))
    assert [j.label for j in fine] == [j.label for j in coarse] and len(fine) == 18
    assert {j.spec.packing.diameter_nm for j in fine} == {15.0}
    assert {j.spec.packing.diameter_nm for j in coarse} == {30.0}
    for a, b in zip(fine, coarse):
        assert (a.at, a.spec.pores, a.spec.compression, a.spec.bonds) == (b.at, b.spec.pores, b.spec.compression,
                                                                          b.spec.bonds)
    assert_refused(capsys, ["run", "porosity_strength", "--out", str(tmp_path / "r")], ["study.diameter_nm=2"],
                   "study.diameter_nm", tmp_path / "r")


def test_bad_study_field_is_one_line(tmp_path, capsys):
    from conftest import assert_refused

    out = tmp_path / "run"
    assert_refused(capsys, ["run", "porosity", "--out", str(out)], ["study.porosities=[0.9]"],
                   "study.porosities", out)


def test_every_study_type_gives_its_jobs_and_reads_only_its_fields(tmp_path, capsys):
    """Each study type's jobs hook (what plan prices) on the shipped study workflows: jobs with distinct labels,
    placed in their sweep (``at``); a [study] field the type does not read is refused in one line."""
    from conftest import assert_refused

    from opalflow.runs.plan import jobs_of
    from opalflow.studies.spec import STUDY_TYPES

    seen = set()
    for path in sorted(WORKFLOWS.glob("*.toml")):
        spec = load_spec(path)
        if spec.kind == "study":
            got = jobs_of(spec)
            assert got and len({j.label for j in got}) == len(got), path.name
            seen.add(spec.study.type)
    assert seen == set(STUDY_TYPES)
    porosity = load_spec(WORKFLOWS / "porosity.toml")
    st = porosity.study
    assert [j.at for j in jobs_of(porosity)] == [(p, s) for p in st.porosities for s in st.seeds]
    calibration = jobs_of(load_spec(WORKFLOWS / "calibrate_silica.toml", ['study.jacobian="full"']))
    assert len(calibration) == 3                      # the start and one finite-difference point per parameter
    out = tmp_path / "run"
    assert_refused(capsys, ["run", "porosity", "--out", str(out)], ["study.target_E_GPa=2.0"], "study.target_E_GPa",
                   out)


def test_summary_json_of_a_study_is_written_last(tmp_path):
    """Jobs are marked by their record (run.json, state pending) before they run; a folder without
    summary.json is not finished, nor one whose record is another spec's."""
    from opalflow.runs.record import RunRecord

    job = lattice_jobs((20.0,))[0]
    folder = job.folder(tmp_path)
    jobs_mod.prepare([job], tmp_path)
    assert RunRecord.read(folder).state == "pending" and RunRecord.read(folder).spec_hash == job.key
    assert jobs_mod.finished(job, tmp_path) is None
    (folder / "summary.json").write_text("{}")
    assert jobs_mod.finished(job, tmp_path) == {}
    RunRecord.job(job.spec, job.label, "other").write(folder)
    assert jobs_mod.finished(job, tmp_path) is None


@pytest.mark.parametrize("damage", [b'{"youngs_modulus_GPa": 0.', b"\x89HDF\r\n\x1a\n\xff\xfe", b"[1, 2]", b""])
def test_a_damaged_job_summary_is_run_again(tmp_path, damage):
    """A job whose summary.json is cut short, binary, of the wrong shape or empty is not finished: the
    rerun runs it again (no traceback) and gets the numbers of the first run."""
    job = lattice_jobs((20.0,))[0]
    first = run_jobs([job], tmp_path, LOCAL1, say=lambda m: None)["a20"].summary
    (job.folder(tmp_path) / "summary.json").write_bytes(damage)
    (job.folder(tmp_path) / "run.json").write_bytes(damage[:3])
    assert jobs_mod.finished(job, tmp_path) is None
    again = run_jobs([job], tmp_path, LOCAL1, say=lambda m: None)["a20"].summary
    assert again["youngs_modulus_GPa"] == pytest.approx(first["youngs_modulus_GPa"], rel=1e-9)
    assert jobs_mod.finished(job, tmp_path)["peak_stress_MPa"] == pytest.approx(first["peak_stress_MPa"], rel=1e-9)


def test_a_failed_job_does_not_end_the_sweep(tmp_path):
    """A job whose LAMMPS run fails (an atom outside the box) is reported, left unfinished, and the
    other jobs complete."""
    from opalflow.lammps.datafile import write_data
    from opalflow.bpm.pipeline import build_structure

    good = lattice_jobs((20.0,))[0]
    s = build_structure(good.spec)
    s.positions[-1, 2] = 3 * s.box_hi[2]
    write_data(tmp_path / "bad.lmp", s)
    bad = sweep.Job("bad", load_spec(WORKFLOWS / "lattice_sc.toml", [
        *[kv for kv in LATTICE if not kv.startswith("lattice.")], "kind=datafile",
        f'datafile.path="{tmp_path / "bad.lmp"}"',
        'datafile.materials=["silica","substrate"]']))
    res = run_jobs([bad, good], tmp_path / "study", LOCAL1, say=lambda m: None)
    assert res["bad"].state == "failed" and "LAMMPS failed" in res["bad"].error
    assert res["a20"].ok and "youngs_modulus_GPa" in res["a20"].summary
    assert jobs_mod.finished(bad, tmp_path / "study") is None and (bad.folder(tmp_path / "study") / "log.lammps").exists()


def test_sweep_killed_at_random_times_completes_to_the_same_results(tmp_path):
    """SIGKILL of a sweep at three seeded random times (between jobs or inside a LAMMPS run), then a
    rerun: every job completes with the numbers of an uninterrupted sweep, finished jobs untouched."""
    import random

    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER.format(lattice=LATTICE))
    whole = tmp_path / "whole"
    subprocess.run([sys.executable, str(driver), str(whole)], capture_output=True, check=True)
    reference = {p.parent.name: json.loads(p.read_text())["youngs_modulus_GPa"]
                 for p in whole.glob("jobs/*/summary.json")}
    rng = random.Random(7)
    for n in range(3):
        root = tmp_path / f"killed{n}"
        proc = subprocess.Popen([sys.executable, str(driver), str(root)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(rng.uniform(1.0, 4.0))
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        before = {p.parent.name: p.stat().st_mtime_ns for p in root.glob("jobs/*/summary.json")}
        subprocess.run([sys.executable, str(driver), str(root)], capture_output=True, check=True)
        after = {p.parent.name: json.loads(p.read_text())["youngs_modulus_GPa"] for p in root.glob("jobs/*/summary.json")}
        assert after == pytest.approx(reference, rel=1e-4)   # a job resumed from its restart file: not bit-exact
        assert all((root / "jobs" / k / "summary.json").stat().st_mtime_ns == v for k, v in before.items())


def test_bulk_study_by_static_solves(tmp_path):
    """study.method = "static": K_E from one linear solve per diameter; no strength columns; the job's
    summary says method static; a calibration cannot be static."""
    spec = load_spec(WORKFLOWS / "bulk_silica.toml", ["study.method=static", "study.diameters_nm=[60.0]"])
    summary = studies.run(spec, tmp_path, say=lambda m: None).summary()     # (a study: the generic Result)
    row = summary["by_diameter"]["60"]
    assert row["strength_MPa"] is None and 0.5 < row["K_E"] < 6
    jobs = list((tmp_path / "jobs").iterdir())
    assert json.loads((jobs[0] / "summary.json").read_text())["method"] == "static"
    assert "| 60 |" in (tmp_path / "report.md").read_text() and "no strength" in (tmp_path / "report.md").read_text()
    from opalflow.spec import InputError
    with pytest.raises(InputError, match="study.method"):
        load_spec(WORKFLOWS / "calibrate_silica.toml", ["study.method=static"])


def test_porosity_study_by_quasistatic_jobs_fits_the_strength(tmp_path):
    """study.method = "quasistatic": every job a quasi-static fracture (strength at zero rate), so the
    porosity study fits eq. 26 (strength against porosity) as from dynamic runs."""
    spec = load_spec(WORKFLOWS / "porosity.toml", [
        "study.method=quasistatic", "study.porosities=[0.36, 0.49, 0.62]", "study.seeds=[1]",
        'study.set=["compression.strain_max=0.02","compression.snapshot_strains=[]","pores.cells_x=2",'
        '"packing.diameter_nm=110.0","pores.porosity_tolerance=0.04"]'])
    summary = studies.run(spec, tmp_path, say=lambda m: None).summary()     # (a study: the generic Result)
    assert "strength_exponential" in summary["fits"] and len(summary["runs"]) == 3
    assert all(r["strength_MPa"] > 0 for r in summary["runs"])
    job = json.loads(next((tmp_path / "jobs").glob("*/summary.json")).read_text())
    assert job["method"] == "quasistatic" and job["quasistatic"]["events"] >= 1


def test_coating_study_by_quasistatic_jobs_gives_the_strength_ratio(tmp_path):
    """The coating study with study.method = "quasistatic": each coating's strength against the uncoated
    sample's (the paper's Fig. 9: titania's stiffer and stronger bonds raise it)."""
    spec = load_spec(WORKFLOWS / "coating_strength.toml", [
        "study.base=opal_quick", 'study.set=["compression.strain_max=0.03","compression.snapshot_strains=[]",'
        '"bonds.smooth=false","compression.event_tolerance=0.2"]'])
    summary = studies.run(spec, tmp_path, say=lambda m: None).summary()     # (a study: the generic Result)
    rows = {r["case"]: r for r in summary["table"]}
    assert set(rows) == {"uncoated", "low", "mean", "high"}
    assert rows["uncoated"]["strength_vs_uncoated"] == 1.0
    ratio = rows["mean"]["strength_MPa"] / rows["uncoated"]["strength_MPa"]
    assert rows["mean"]["strength_vs_uncoated"] == pytest.approx(ratio) and ratio > 1.2
    assert rows["low"]["youngs_modulus_GPa"] < rows["mean"]["youngs_modulus_GPa"] < rows["high"]["youngs_modulus_GPa"]
    assert "vs uncoated" in (tmp_path / "report.md").read_text()
