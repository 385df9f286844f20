"""What users read and script: the Python API, results.h5 units, image flags, OVITO, ASE and MDAnalysis
readers, Ctrl-C."""
import json
import signal

import numpy as np
import pytest

import opalflow
from opalflow.cli import main
from opalflow.structure import Structure

SMALL = {"compression.strain_max": 0.002, "compression.snapshot_strains": [0.001, 0.002]}


@pytest.fixture(scope="module")
def api_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "sc"
    return out, opalflow.run("lattice_sc", out, set=SMALL, quiet=True)


def test_python_api_gives_the_cli_numbers(api_run, tmp_path, capsys):
    out, summary = api_run
    assert main(["run", "lattice_sc", "--out", str(tmp_path / "cli"),
                 *[a for k, v in SMALL.items() for a in ("--set", f"{k}={json.dumps(v)}")]]) == 0
    cli = json.loads((tmp_path / "cli" / "summary.json").read_text())
    for key in ("youngs_modulus_GPa", "strength_MPa", "steps", "n_bonds"):
        assert summary[key] == cli[key]
    res = opalflow.load_results(out)
    assert res.summary["youngs_modulus_GPa"] == summary["youngs_modulus_GPa"]
    assert res.units("curve/stress_MPa") == "MPa"
    stress = res["curve/stress_MPa"]
    assert len(stress) == len(res["curve/strain"]) and np.max(stress) == pytest.approx(summary["peak_stress_MPa"])
    step = next(k.split("/")[1] for k in res.keys() if k.startswith("snapshots/"))
    assert res.columns(f"snapshots/{step}/sigma_MPa") == ["xx", "yy", "zz", "xy", "xz", "yz"]
    assert set(res.table(f"snapshots/{step}/position_nm")) == {"x", "y", "z"}


def test_the_api_gives_typed_results_that_read_as_summary_json(api_run, tmp_path):
    """opalflow.run gives the kind's result class, typed down to its nested parts, and reads as summary.json's
    table (the file's keys and values, nested parts as tables); build, check, workflows and info are typed too."""
    from opalflow.bpm.result import CompressionResult
    from opalflow.bpm.stability import StabilityCheck

    out, result = api_run
    on_disk = json.loads((out / "summary.json").read_text())
    assert isinstance(result, CompressionResult) and result.method == "dynamic"
    assert result.youngs_modulus_GPa == on_disk["youngs_modulus_GPa"] and result.n_bonds == on_disk["n_bonds"]
    assert dict(result) == on_disk and result == on_disk and set(result) == set(on_disk)
    assert result["state"] == "finished" and "sessions" in result and isinstance(result["sessions"][0], dict)
    assert all(type(s).__name__ == "Session" for s in result.sessions)          # typed where read
    built = opalflow.build("opal_quick", tmp_path / "built", quiet=True)
    assert type(built).__name__ == "OpalResult" and built["state"] == "built" and built.n_particles > 1000
    check = opalflow.check("lattice_sc", tmp_path / "check", steps=200, quiet=True)
    assert isinstance(check, StabilityCheck) and check.passed and check.run.steps == 200
    names = [w.name for w in opalflow.workflows()]
    assert "quickstart" in names and next(w for w in opalflow.workflows() if w.name == "quickstart").kind == "opal"
    assert opalflow.info().lammps.version >= 20250722 and "study" in opalflow.info().kinds


def test_quiet_means_no_progress_lines(tmp_path, capsys):
    """Was: ``quiet=True`` left LAMMPS's progress lines ("step N/M (..%), ... steps/s, ... s left") on stderr."""
    opalflow.run("lattice_sc", tmp_path / "quiet", set=SMALL, quiet=True)
    assert capsys.readouterr().err == ""
    opalflow.run("lattice_sc", tmp_path / "said", set=SMALL)
    err = capsys.readouterr().err
    assert "steps/s" in err and "100 %" in err


def test_every_dataset_of_results_h5_has_units(api_run, tmp_path):
    """Walk every dataset of the dynamic, static and aggregation results: each has units, each 2-D one columns."""
    import h5py

    out, _ = api_run
    static = opalflow.run("lattice_sc", tmp_path / "static", set={"compression.method": "static"}, quiet=True)
    agg = opalflow.run("aerogel_dlca", tmp_path / "agg", set={"aggregate.particles": 300}, quiet=True)
    assert static and agg
    missing = []
    for folder in (out, tmp_path / "static", tmp_path / "agg"):
        with h5py.File(folder / "results.h5", "r") as h:
            def visit(name, obj):
                if isinstance(obj, h5py.Dataset):
                    if "units" not in obj.attrs or (obj.ndim == 2 and "columns" not in obj.attrs):
                        missing.append(f"{folder.name}:{name}")
            h.visititems(visit)
    assert not missing


def test_bad_api_input_is_one_line_before_anything_is_written(tmp_path):
    with pytest.raises(opalflow.spec.InputError, match=r"^compression.strain_max = -1.0: "):
        opalflow.run("lattice_sc", tmp_path / "x", set={"compression.strain_max": -1.0})
    with pytest.raises(opalflow.spec.InputError, match=r"^--np = 0: "):
        opalflow.run("lattice_sc", tmp_path / "x", np=0)
    assert not (tmp_path / "x").exists()


def test_image_flags_make_a_cluster_whole_and_leave_a_wrapping_chain_on_the_face():
    """A ring of particles across the x face is made whole; a chain around the box keeps one long bond."""
    box = np.array([10.0, 10.0, 10.0])
    ring = np.array([[9.0, 5.0, 5.0], [0.5, 5.0, 5.0], [0.5, 6.0, 5.0], [9.0, 6.0, 5.0]])
    chain = np.array([[x, 2.0, 2.0] for x in np.arange(0.5, 10.0, 1.0)])
    s = Structure(positions=np.vstack([ring, chain]), diameters=np.ones(14), types=np.ones(14), densities=np.ones(14),
                  box_lo=np.zeros(3), box_hi=box, periodic=np.array([True, True, False]),
                  bonds=[[0, 1], [1, 2], [2, 3], [0, 3]] + [[4 + k, 4 + (k + 1) % 10] for k in range(10)])
    flags = s.image_flags()
    assert abs(flags[0, 0] - flags[1, 0]) == 1 and flags[0, 0] == flags[3, 0]
    assert np.all(flags[4:] == 0)
    assert list(s.wrapping_bonds(flags)) == [1, 0, 0]                  # the chain's bond over the face
    assert list(s.wrapping_bonds(np.zeros_like(flags))) == [3, 0, 0]   # without flags, the ring's two too


def test_ovito_reads_data_file_with_bonds_and_a_dump(api_run):
    ovito_io = pytest.importorskip("ovito.io", reason="the ovito package (PyPI) is not installed")
    out, _ = api_run
    from opalflow.lammps.datafile import read_data

    s = read_data(out / "data.lmp")
    data = ovito_io.import_file(str(out / "data.lmp"), atom_style="bpm/sphere").compute()
    assert data.particles.count == s.n_particles and data.particles.bonds.count == s.n_bonds
    order = np.argsort(data.particles["Particle Identifier"])
    assert np.allclose(np.asarray(data.particles["Position"])[order], s.positions, atol=1e-6)
    assert np.allclose(np.asarray(data.particles["Radius"])[order], s.diameters / 2)
    dump = sorted((out / "snapshots").glob("particles.*.dump"))[-1]
    frame = ovito_io.import_file(str(dump)).compute()
    atoms = opalflow.io.read_ase(out, step=int(dump.name.split(".")[1]))
    order = np.argsort(frame.particles["Particle Identifier"])
    assert frame.particles.count == len(atoms)
    assert np.allclose(np.asarray(frame.particles["Position"])[order], atoms.positions / 10 + atoms.info["origin_nm"],
                       atol=1e-4)
    assert {"sigma_zz", "broken_bonds", "Radius"} <= set(frame.particles.keys())


def test_lammps_reads_the_image_flags_without_warning_where_nothing_wraps(tmp_path):
    """Open sides: no bond crosses a face, LAMMPS prints no image-flag warning; periodic sides: the
    infinite network's face bonds are counted in the data file's header."""
    out = tmp_path / "open"
    opalflow.run("lattice_sc", out, set={**SMALL, "boundary.sides": "open"}, quiet=True)
    assert "Inconsistent image flags" not in (out / "log.lammps").read_text()


def test_ase_and_mdanalysis_readers_give_radii_and_bonds(api_run):
    out, summary = api_run
    atoms = opalflow.io.read_ase(out)
    assert len(atoms) == summary["n_particles"] and len(atoms.info["bonds"]) == summary["n_bonds"]
    assert np.allclose(atoms.arrays["radius"], 100.0)                  # d = 20 nm = 200 A
    i, j = atoms.info["bonds"].T
    from ase.geometry import find_mic
    lengths = np.linalg.norm(find_mic(atoms.positions[j] - atoms.positions[i], atoms.cell, atoms.pbc)[0], axis=1)
    assert np.allclose(lengths, 200.0, atol=1e-3)                      # sc spacing 20 nm
    assert sum(len(b.split(",")) for b in atoms.arrays["bonds"] if b) == summary["n_bonds"]
    snap = opalflow.io.read_ase(out, step=-1)
    assert snap.arrays["sigma_MPa"].shape == (len(atoms), 6) and "broken_bonds" in snap.arrays
    u = opalflow.io.read_mdanalysis(out)
    assert len(u.atoms) == len(atoms) and len(u.bonds) == summary["n_bonds"]
    assert np.allclose(u.atoms.radii, 100.0) and len(u.trajectory) == 2
    assert np.allclose(u.bonds.values(pbc=True), 200.0, rtol=2e-3)


def test_ctrl_c_prints_one_line_exits_130_and_resumes(tmp_path, capsys):
    from conftest import signalled_run

    out = tmp_path / "qs"
    code, err = signalled_run(out, signal.SIGINT)
    assert code == 130
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted at step ") and f"--out {out} --resume" in last
    assert "Traceback" not in err
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume"]) == 0
    said = capsys.readouterr()
    step = int(last.split()[3].rstrip(";,"))
    text = said.out + said.err                  # (a stop on a restart step itself runs nothing again)
    assert "resuming from restart." in text and (f"the run had reached step {step}" in text or f"(step {step} of" in text)
    assert json.loads((out / "summary.json").read_text())["complete"]


def test_report_names_inputs_and_explains_large_errors(api_run):
    from opalflow.bpm.report import SECTIONS, why

    out, _ = api_run
    text = (out / "report.md").read_text()
    for section in SECTIONS:
        assert f"\n{section}\n" in text
    for row in ("| particles |", "| bonds |", "| material silica |", "| bond coefficients |", "| time step |"):
        assert row in text
    reason = why("youngs_modulus_GPa", -0.88, 60.0)                  # the quickstart's E against the experiment
    assert reason.startswith("resolution: d = 60 nm is 4.0 x the paper's 15 nm") and "2.074 GPa (d = 15 nm)" in reason
    assert "9.37 MPa (d = 45 nm)" in why("strength_MPa", -0.97, 60.0)
    assert why("youngs_modulus_GPa", 0.05, 60.0) == ""


def test_every_dump_and_data_file_of_each_method_opens_in_ovito_and_ase(api_run, tmp_path):
    """OVITO and ASE open every dump and data file of a dynamic, a static, a quasi-static and a resumed
    quasi-static run, with every particle and the box the data file has (the quasi-static dumps' box lines
    were ``np.float64(0.0) np.float64(762.0)`` under numpy 2: OVITO's "Invalid box size in line 7")."""
    ovito_io = pytest.importorskip("ovito.io", reason="the ovito package (PyPI) is not installed")
    import ase.io

    from opalflow.lammps import engine
    from opalflow.lammps.datafile import read_data

    quick = {"compression.method": "quasistatic", "compression.snapshot_strains": [], "compression.strain_max": 0.03}
    folders = {"dynamic": api_run[0]}
    opalflow.run("lattice_sc", tmp_path / "static", set={"compression.method": "static"}, quiet=True)
    folders["static"] = tmp_path / "static"
    opalflow.run("quickstart", tmp_path / "quasistatic", set=quick, quiet=True)
    folders["quasistatic"] = tmp_path / "quasistatic"
    engine.request_stop("SIGUSR1")
    with pytest.raises(engine.Preempted):
        opalflow.run("quickstart", tmp_path / "resumed", set=quick, quiet=True)
    opalflow.run(None, tmp_path / "resumed", resume=True, quiet=True)
    folders["resumed quasistatic"] = tmp_path / "resumed"
    opened = []
    for method, folder in folders.items():
        built = read_data(folder / "data.lmp")
        data = ovito_io.import_file(str(folder / "data.lmp"), atom_style="bpm/sphere").compute()
        assert data.particles.count == built.n_particles and data.particles.bonds.count == built.n_bonds, method
        assert np.allclose(np.diag(np.asarray(data.cell)[:, :3]), built.box_lengths), method
        dumps = sorted(folder.rglob("*.dump"))
        assert dumps or method == "static", method
        for dump in dumps:
            frame = ovito_io.import_file(str(dump)).compute()
            assert frame.particles.count == built.n_particles, dump
            assert np.allclose(np.diag(np.asarray(frame.cell)[:, :3]), built.box_lengths), dump
            atoms = ase.io.read(dump, format="lammps-dump-text")
            assert len(atoms) == built.n_particles and np.allclose(atoms.cell.lengths(), built.box_lengths), dump
            opened.append(f"{method}:{dump.name}")
    assert {"quasistatic:fracture.peak.dump", "resumed quasistatic:fracture.end.dump"} <= set(opened)


def test_one_result_class_gives_each_method_its_keys(api_run, tmp_path):
    """summary.json of a dynamic, a static and a quasi-static run: the keys :class:`CompressionResult` lists for
    the method (no other method's), the same summary in results.h5's attributes, the Results table its rows."""
    import dataclasses

    import h5py

    from opalflow.bpm.result import CompressionResult
    from opalflow.store import json_text

    fields = {f.name: f.metadata for f in dataclasses.fields(CompressionResult) if "cases" in f.metadata}
    folders = {"dynamic": api_run[0]}
    for method in ("static", "quasistatic"):
        opalflow.run("lattice_sc", tmp_path / method, quiet=True, set={
            **SMALL, "compression.method": method, "bonds.breakable": method == "quasistatic"})
        folders[method] = tmp_path / method
    for method, folder in folders.items():
        summary = json.loads((folder / "summary.json").read_text())
        mine = {k for k, m in fields.items() if method in m["cases"]}
        assert {k for k in mine if not fields[k]["optional"]} <= set(summary), method
        assert not set(summary) & (set(fields) - mine), method          # no other method's key
        assert summary["method"] == method and summary["loading"] == "plate"
        with h5py.File(folder / "results.h5", "r") as h:
            assert h.attrs["method"] == method and h.attrs["youngs_modulus_GPa"] == summary["youngs_modulus_GPa"]
            assert set(json.loads(h.attrs["summary"])) <= set(summary) and "provenance" in h
        report = (folder / "report.md").read_text()
        assert f"| Young's modulus{', plate strain' if method == 'dynamic' else ''} (GPa) | " in report, method
        assert ("| compressive strength (MPa) | " in report) == (method != "static"), method
        # read back as the same class: every key an attribute, summary.json again from it
        back = CompressionResult.read(folder)
        assert isinstance(back, CompressionResult) and back.case == method, method
        assert back.youngs_modulus_GPa == summary["youngs_modulus_GPa"], method
        assert json.loads(json_text(back.summary())) == summary, method           # (typed parts as their tables)
        assert json.loads(json_text(opalflow.load_results(folder).result.summary())) == summary, method


def test_the_sample_facts_are_read_back_typed_and_a_foreign_fact_is_one_line(api_run):
    """run.json's deck is SampleFacts (bpm/facts.py), the spec rebuilt typed from the record (RunFacts); a fact this
    opalflow does not know (a newer record) is refused in one line, not read as a dict."""
    from opalflow.bpm.facts import RunFacts, SampleFacts
    from opalflow.runs.record import RunRecord
    from opalflow.runs.result import table_of
    from opalflow.spec import InputError

    record = RunRecord.read(api_run[0])
    run = RunFacts.of(record)
    assert run.spec.bonds.breakable is False and run.spec.kind == "lattice" and run.sample.steps > 0
    assert run.sample.bond_types[0].kr_pN > 0 and table_of(run.sample) == record.deck
    with pytest.raises(InputError, match="unknown facts surprise"):
        SampleFacts.from_dict({**record.deck, "surprise": 1})
