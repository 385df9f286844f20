"""The SLURM executor against a real one-node SLURM started by the project's own script
(scripts/local-slurm.sh; .ci/run starts it): same numbers as the local pool, scancel and rerun, a
controller restart during a study, a time limit reached and requeued from the restart file, MPI ranks
inside a job.  Skipped, with the reason, only where that SLURM cannot start (not root, no apt-get)."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import opalflow
from opalflow.resources import ROOT
from opalflow.runs.executors import SlurmExecutor
from opalflow.runs.jobs import STOP_NOTE, spec_hash
from opalflow.runs.record import RunRecord
from opalflow.runs.spec import ExecutorSpec

SCRIPT = ROOT / "scripts" / "local-slurm.sh"
LATTICE_DYNAMIC = ["compression.strain_max=0.004", "compression.snapshot_strains=[]", "lattice.cells_z=8"]


@pytest.fixture(scope="module")
def slurm():
    """A SLURM that answers: the one running, or the one the script starts."""
    if shutil.which("sinfo") and subprocess.run(["sinfo"], capture_output=True).returncode == 0:
        return
    if os.geteuid() != 0:
        pytest.skip("no SLURM running and not root: scripts/local-slurm.sh needs root to start munged and SLURM")
    proc = subprocess.run(["bash", str(SCRIPT), "start"], capture_output=True, text=True, timeout=600)
    if proc.returncode:
        pytest.skip(f"scripts/local-slurm.sh could not start SLURM here: {proc.stderr.strip()[-300:]}")


def energies(root: Path) -> dict[str, float]:
    return {p.parent.name: json.loads(p.read_text())["youngs_modulus_GPa"] for p in root.glob("jobs/*/summary.json")
            if json.loads(p.read_text()).get("state") == "finished"}


def study_cmd(out: Path, executor: str, *sets: str) -> list[str]:
    """The porosity study on opal_quick with four porosities (one seed): four small jobs."""
    args = [sys.executable, "-m", "opalflow", "run", "porosity", "--out", str(out), "--executor", executor,
            "--set", "study.base=opal_quick", "--set", "study.porosities=[0.3, 0.4, 0.5, 0.6]",
            "--set", "study.seeds=[1]", "--set", "executor.poll_s=0.5"]
    for s in sets:
        args += ["--set", s]
    return args


STATIC4 = ["study.method=static", 'study.set=["pores.porosity_tolerance=0.1"]']
DYNAMIC4 = ['study.set=["pores.porosity_tolerance=0.1","compression.strain_max=0.003","compression.snapshot_strains=[]"]']


def test_slurm_array_gives_the_local_numbers(slurm, tmp_path):
    for executor in ("local", "slurm"):
        proc = subprocess.run(study_cmd(tmp_path / executor, executor, *STATIC4), capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
    local, on_slurm = energies(tmp_path / "local"), energies(tmp_path / "slurm")
    assert len(local) == 4 and local == on_slurm
    script = next((tmp_path / "slurm" / "slurm").glob("array-*.sh")).read_text()
    assert "#SBATCH --array=0-3" in script and "#SBATCH --signal=B:USR1@" in script and "#SBATCH --requeue" in script
    record = json.loads(next((tmp_path / "slurm").glob("jobs/*/run.json")).read_text())
    assert record["sessions"][-1]["slurm_job"] and record["state"] == "finished" and record["attempts"] == 1


def _wait_for(cond, timeout=120.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return True
        time.sleep(0.5)
    return False


def test_scancel_half_the_array_then_rerun_runs_only_the_missing_jobs(slurm, tmp_path):
    ref = tmp_path / "local"
    subprocess.run(study_cmd(ref, "local", *DYNAMIC4), capture_output=True, check=True)
    out = tmp_path / "slurm"
    study = subprocess.Popen(study_cmd(out, "slurm", *DYNAMIC4, "executor.workers=2"), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    assert _wait_for(lambda: (out / "slurm" / "arrays.txt").exists())
    time.sleep(1.0)
    array = (out / "slurm" / "arrays.txt").read_text().split()[0]
    subprocess.run(["scancel", f"{array}_[2-3]"], check=True)
    log, _ = study.communicate(timeout=300)
    assert "ended without a result" in log, log[-2000:]
    done_first = energies(out)
    assert 1 <= len(done_first) <= 3
    rerun = subprocess.run(study_cmd(out, "slurm", *DYNAMIC4), capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr[-2000:]
    assert f"{len(done_first)} finished before, {4 - len(done_first)} to run" in rerun.stderr
    assert energies(out) == energies(ref)


def test_a_refused_submission_shows_failed_with_the_reason(slurm, tmp_path):
    """A partition the cluster lacks: sbatch refuses the array; the study ends in one line, and status shows
    each job failed with sbatch's reason (it showed them pending, as if queued)."""
    out = tmp_path / "refused"
    proc = subprocess.run(study_cmd(out, "slurm", *STATIC4, 'executor.partition="nosuchpartition"'),
                          capture_output=True, text=True)
    last = proc.stderr.strip().splitlines()[-1]
    assert proc.returncode == 2 and last.startswith("error: executor.type = 'slurm': sbatch refused the array: "), last
    assert "Invalid partition" in last
    status = subprocess.run([sys.executable, "-m", "opalflow", "status", str(out)], capture_output=True, text=True)
    assert status.returncode == 0 and "4 failed" in status.stdout and "pending" not in status.stdout, status.stdout
    assert "not submitted (sbatch refused the array" in status.stdout


def test_a_study_survives_a_controller_restart(slurm, tmp_path):
    out = tmp_path / "slurm"
    study = subprocess.Popen(study_cmd(out, "slurm", *DYNAMIC4), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    assert _wait_for(lambda: (out / "slurm" / "arrays.txt").exists())
    subprocess.run(["bash", str(SCRIPT), "restart-controller", "5"], check=True, timeout=120)
    log, _ = study.communicate(timeout=600)
    assert study.returncode == 0, log[-2000:]
    assert len(energies(out)) == 4


def test_time_limit_requeues_from_the_restart_to_the_same_numbers(slurm, tmp_path):
    """The quickstart (bonds breaking) to half its strain under a 1-minute limit: SLURM signals it (USR1, 45 s
    before the limit, at its next time-limit check), it writes a restart file and requeues itself, SLURM
    starts it again after the credential hold, it continues; E, strength and broken bonds equal the run's without a
    limit, and the report counts the requeues."""
    sets = ["compression.strain_max=0.015", "compression.snapshot_strains=[]"]
    whole = opalflow.run("quickstart", tmp_path / "whole", set=sets, quiet=True)
    s = opalflow.run("quickstart", tmp_path / "limited", set=[*sets, "executor.time_min=1", "executor.signal_s=45"],
                     executor="slurm", quiet=True)
    record = RunRecord.read(tmp_path / "limited")
    if record.requeues == 0:
        pytest.skip(f"the run finished inside one limit ({whole['wall_s']:.0f} s here)")
    assert len(record.sessions) == record.requeues + 1
    assert [x.first_step for x in record.sessions[1:]] == [x.last_step for x in record.sessions[:-1]]
    for key in ("youngs_modulus_GPa", "strength_MPa", "strain_at_peak"):
        assert s[key] == pytest.approx(whole[key], rel=1e-4), key
    assert f"SLURM requeues: {record.requeues}" in (tmp_path / "limited" / "report.md").read_text()


def test_a_time_limit_warning_while_python_starts_requeues_the_job(slurm, tmp_path):
    """SLURM's USR1 can come before the job's Python has its handler (CI under load: the task died of USR1's
    default action and its folder stayed pending).  The array's script run by bash, the signal sent 0.3 s after
    it starts: the job still writes a restart file and settles requeued, and leaves no note behind."""
    spec = opalflow.load_workflow("quickstart", set=["compression.strain_max=0.015", "compression.snapshot_strains=[]"])
    folder = tmp_path / "jobs" / "quickstart"
    folder.mkdir(parents=True)
    RunRecord.job(spec, spec.name, spec_hash(spec)).write(folder)
    listing = tmp_path / "jobs.txt"
    listing.write_text(f"{folder}\n")
    script = tmp_path / "array.sh"
    script.write_text(SlurmExecutor(ExecutorSpec(type="slurm")).script(tmp_path, listing, 1))
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")} | {"SLURM_ARRAY_TASK_ID": "0"}
    task = subprocess.Popen(["bash", str(script)], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(0.3)
    task.send_signal(signal.SIGUSR1)
    said, _ = task.communicate(timeout=300)
    record = RunRecord.read(folder)
    assert task.returncode == 0 and record.state == "requeued", said[-2000:]
    assert record.sessions[-1].last_step > 0 and list(folder.glob("**/restart.*.bin")), said[-2000:]
    assert not (folder / STOP_NOTE).exists()


def test_mpi_ranks_inside_a_slurm_job(slurm, tmp_path):
    one = opalflow.run("lattice_sc", tmp_path / "one", set=LATTICE_DYNAMIC, quiet=True)
    two = opalflow.run("lattice_sc", tmp_path / "two", set=[*LATTICE_DYNAMIC, "executor.mem_gb=1"], np=2,
                       executor="slurm", quiet=True)
    log = (tmp_path / "two" / "log.lammps").read_text()
    assert "with 2 MPI tasks" in log and ("1 by 1 by 2 MPI processor grid" in log or "2 by 1 by 1 MPI" in log
                                          or "1 by 2 by 1 MPI" in log)
    assert "srun" in RunRecord.read(tmp_path / "two").sessions[-1].launcher
    assert two["youngs_modulus_GPa"] == pytest.approx(one["youngs_modulus_GPa"], rel=1e-4)
