"""The polycrystal of tetrahedral elements with 64-atom Tersoff samples (seed 003, eqs. 5-11).

Real parts only: the batched Tersoff is compared with LAMMPS pair_style tersoff, the samples'
stresses with the potential's own elastic constants, and the workflows run end to end on small
meshes (48-96 elements)."""
import dataclasses
import json

import numpy as np
import pytest

from opalflow.cli import main
from opalflow.runs.record import RunRecord
from opalflow.tersoff.parameters import load_parameters, write_tersoff
from opalflow.tersoff.polycrystal.check import compare_with_lammps
from opalflow.tersoff.polycrystal.crystal import single_crystal
from opalflow.tersoff.polycrystal.dynamics import Polycrystal, cubic_stiffness, rotated_stiffness
from opalflow.tersoff.polycrystal.mesh import block
from opalflow.tersoff.polycrystal.samples import Samples, random_rotations, relax_md, relax_minimize
from tests.conftest import assert_refused

POTENTIAL = "Si_zhuravlev2021.tersoff"


@pytest.fixture(scope="module")
def si():
    params = load_parameters(POTENTIAL, "Si")
    crystal = single_crystal(params, POTENTIAL)
    return params, crystal, Samples(params.values(), params.cutoff(), crystal.a0_A)


def test_batched_tersoff_equals_lammps(si, tmp_path):
    """Energy, forces and virial of random samples (rotation, strain up to 1 %, 0.05 A thermal
    displacements) equal LAMMPS pair_style tersoff within 1e-8 relative (acceptance 1)."""
    params, _, samples = si
    worst = compare_with_lammps(samples, params, tmp_path, count=3, strain=0.01, displacement_A=0.05, seed=11)
    assert samples.k == 4 and samples.n == 64
    for key in ("energy", "forces", "virial"):
        assert getattr(worst, f"max_relative_{key}") < 1e-8, worst


def _linear_stress(crystal, rotations, eps):
    c = rotated_stiffness(cubic_stiffness(*crystal.constants), rotations)
    return np.einsum("eijkl,ekl->eij", c, eps)


def _strains(size):
    """Uniaxial along x, y, z and [111], pure shears xy, yz, a mixed one: (7, 3, 3)."""
    n = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    e = [np.diag(v) for v in np.eye(3)] + [np.outer(n, n)]
    for a, b in ((0, 1), (1, 2)):
        s = np.zeros((3, 3))
        s[a, b] = s[b, a] = 0.5
        e.append(s)
    e.append(np.array([[0.3, 0.2, -0.1], [0.2, -0.4, 0.25], [-0.1, 0.25, 0.5]]))
    return size * np.array(e)


@pytest.mark.parametrize("size, tol_gpa", [(1e-2, 0.5), (1e-4, 2e-3)])
def test_one_element_stress_is_the_rotated_crystal_tensor(si, size, tol_gpa):
    """A relaxed sample under strain along several directions gives C_rot : eps with the relaxed C44
    (acceptance 2: within 0.5 GPa at 1 % strain); at 1e-4 the difference is below 2e-3 GPa, well under
    what the unrelaxed C44^0 would give."""
    _, crystal, samples = si
    eps = _strains(size)
    rot = random_rotations(len(eps), 5)
    cells = np.einsum("eab,ebc->eac", np.eye(3) + eps, samples.reference_cells(rot))
    relaxed = relax_minimize(samples, samples.positions(cells), cells, rot, force_tol=1e-7)
    diff = np.abs(relaxed.evaluation.stress - _linear_stress(crystal, rot, eps)).max()
    assert diff < tol_gpa
    if size < 1e-3:     # in the linear range the relaxed C44 is told apart from the unrelaxed C44^0
        unrelaxed = dataclasses.replace(crystal, C44_GPa=crystal.C44_0_GPa)
        assert np.abs(relaxed.evaluation.stress - _linear_stress(unrelaxed, rot, eps)).max() > 3 * diff


def test_minimisation_and_damped_md_reach_the_same_steady_state(si):
    _, _, samples = si
    rot = random_rotations(4, 2)
    eps = _strains(3e-3)[[0, 4, 6, 3]]
    cells = np.einsum("eab,ebc->eac", np.eye(3) + eps, samples.reference_cells(rot))
    x = samples.positions(cells)
    mini = relax_minimize(samples, x, cells, rot, force_tol=1e-5)
    md, v = relax_md(samples, x, cells, force_tol=1e-5)
    assert mini.evaluations < 10 < 100 < md.evaluations
    assert np.abs(mini.evaluation.stress - md.evaluation.stress).max() < 1e-3


def test_mesh_is_conforming_with_the_paper_element_counts():
    for cubes, count in (((4, 4, 4), 384), ((8, 8, 8), 3072), ((4, 4, 40), 3840)):
        assert block(cubes, 5.0, (True, False, False)).elements == count
    m = block((3, 2, 4), 2.0, (True, True, False))
    v = m.volumes()
    assert np.allclose(v, 8.0 / 6) and v.sum() == pytest.approx(3 * 2 * 4 * 8.0)
    assert len(m.boundary_faces()) == 2 * (3 * 2) * 2        # the z faces only: 2 faces x 6 squares x 2 triangles
    closed = block((3, 2, 4), 2.0, (False, False, False))
    assert len(closed.boundary_faces()) == 2 * 2 * (3 * 2 + 3 * 4 + 2 * 4)
    thin = block((2, 2, 3), 1.0, (True, True, False))           # two cubes wide: same vertex ids in two images
    assert len(thin.boundary_faces()) == 2 * 2 * 4


def test_uniform_stress_gives_eq11_face_forces_and_interior_equilibrium(si):
    """The vertex forces -V S Ds^-T equal eq. 11 (S n per face, a third to each vertex); a uniform
    stress leaves every interior vertex in equilibrium and loads the surface with the traction S n."""
    _, crystal, samples = si
    mesh = block((2, 2, 2), 3.0, (False, False, False))
    pc = Polycrystal(mesh, samples, random_rotations(mesh.elements, 1), crystal.constants)
    stress = np.array([[1.0, 0.3, -0.2], [0.3, -0.5, 0.1], [-0.2, 0.1, 0.7]])
    pc.element_stresses = lambda deformation: np.broadcast_to(stress, (mesh.elements, 3, 3))
    f = pc.forces()
    face = np.zeros_like(f)
    for tet in mesh.tets:
        p = mesh.vertices[tet]
        centre = p.mean(0)
        for loc in ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)):
            a, b, c = p[list(loc)]
            n = 0.5 * np.cross(b - a, c - a)
            n = n if np.dot(n, a - centre) > 0 else -n          # outward
            for v in loc:
                face[tet[v]] -= stress @ n / 3.0
    assert np.allclose(f, face, atol=1e-12)
    inner = np.all((mesh.vertices > 0) & (mesh.vertices < 6.0), axis=1)
    assert inner.sum() == 1 and np.abs(f[inner]).max() < 1e-12
    centre_top = np.all(mesh.vertices == [3.0, 3.0, 6.0], axis=1)     # a third of 6 triangles of 4.5 nm^2: 9 nm^2
    assert f[centre_top][0] == pytest.approx(-stress @ np.array([0, 0, 9.0]), abs=1e-12)
    assert np.abs(f.sum(0)).max() < 1e-12


def _run(tmp_path, workflow, *sets):
    out = tmp_path / "run"
    argv = ["run", workflow, "--out", str(out)]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 0
    return out, json.loads((out / "summary.json").read_text())


def test_tension_workflow_static_and_dynamic(tmp_path):
    """48 elements, two seeds: E inside the bounds of the orientations drawn, nu near 0.22, the
    seed's dynamic scheme and the static solver agree; outputs with units; --resume skips the runs."""
    import h5py
    import meshio
    common = ["tension.cubes=[2]", "tension.cube_nm=[5.0]", "samples.seeds=[1, 2]", "samples.lammps_check=1",
              "tension.max_strain=0.001"]
    out, s = _run(tmp_path, "polycrystal_tension", *common)
    runs = [json.loads(p.read_text()) for p in sorted((out / "jobs").glob("*/summary.json"))]
    assert len(runs) == 2
    for j in runs:
        b = j["bounds_realised"]
        assert b["reuss"]["E_GPa"] < j["youngs_modulus_GPa"] < b["voigt"]["E_GPa"]
    assert 0.20 < s["poisson_ratio"] < 0.24 and s["lammps_check"]["max_relative_forces"] < 1e-8
    assert {"youngs_modulus_GPa", "poisson_ratio", "wall_s"} <= set(s)
    with h5py.File(out / "results.h5") as h:
        def walk(name, obj):
            if isinstance(obj, h5py.Dataset):
                assert "units" in obj.attrs, name
        h.visititems(walk)
        assert list(h["tension_48el_5nm_seed1/curve"].attrs["columns"])[:2] == ["strain", "sxx_GPa"]
    grid = meshio.read(out / "mesh_48el_5nm.vtu")
    assert grid.cells[0].data.shape == (48, 4) and grid.cell_data["stress_GPa"][0].shape == (48, 9)
    for name in ("report.md", "stress_strain.png", "volume_strain.png", "mesh.png"):
        assert (out / name).stat().st_size > 0
    _, st = _run(tmp_path / "static", "polycrystal_tension", *common, 'tension.method="static"')
    assert st["youngs_modulus_GPa"] == pytest.approx(s["youngs_modulus_GPa"], rel=2e-3)
    assert st["poisson_ratio"] == pytest.approx(s["poisson_ratio"], abs=2e-3)
    assert main(["run", "--out", str(out), "--resume"]) == 2     # a finished run is not resumed
    record = RunRecord.read(out)                # killed before its summary: --resume skips the finished samples
    record.state = "running"
    record.write(out)
    (out / "summary.json").unlink()
    assert main(["run", "--out", str(out), "--resume"]) == 0
    again = json.loads((out / "summary.json").read_text())
    assert again["youngs_modulus_GPa"] == s["youngs_modulus_GPa"] and again["wall_s"] < s["wall_s"]


def test_the_experiments_are_jobs_keyed_by_their_spec_that_status_lists(tmp_path, capsys):
    """Each experiment of a polycrystal run is a runs.jobs.Job: a folder named by its label and the hash of its own
    spec (one mesh and seed), with its record and its result, so status lists them (it showed the run alone) and a
    stored result is reused only for the same inputs: the hash of seed 1's experiment is not seed 2's, and a result
    whose record names other inputs runs again on --resume."""
    from opalflow.runs.jobs import spec_hash
    from opalflow.tersoff.polycrystal.run import tension_jobs

    common = ["tension.cubes=[2]", "tension.cube_nm=[5.0]", "samples.seeds=[1, 2]", "samples.lammps_check=0",
              "tension.max_strain=0.001", 'tension.method="static"']
    out, s = _run(tmp_path, "polycrystal_tension", *common)
    spec = RunRecord.read(out).spec
    from opalflow.registry import spec_from_dict

    jobs = tension_jobs(spec_from_dict(spec))
    assert [j.folder(out).name[:-13] for j in jobs] == ["tension_48el_5nm_seed1", "tension_48el_5nm_seed2"]
    assert all(j.folder(out).is_dir() for j in jobs) and len({spec_hash(j.spec) for j in jobs}) == 2
    capsys.readouterr()
    assert main(["status", str(out)]) == 0
    shown = capsys.readouterr().out
    assert "tension_48el_5nm_seed1" in shown and "tension_48el_5nm_seed2" in shown and "2 finished" in shown
    # the first experiment's record now names other inputs: --resume runs it again, keeps the second
    record = RunRecord.read(out)
    record.state = "running"
    record.write(out)
    (out / "summary.json").unlink()
    first = RunRecord.read(jobs[0].folder(out))
    first.spec_hash = "0" * 64
    first.write(jobs[0].folder(out))
    stamp = (jobs[1].folder(out) / "summary.json").stat().st_mtime_ns
    assert main(["run", "--out", str(out), "--resume"]) == 0
    assert RunRecord.read(jobs[0].folder(out)).spec_hash == jobs[0].key
    assert (jobs[1].folder(out) / "summary.json").stat().st_mtime_ns == stamp
    assert json.loads((out / "summary.json").read_text())["youngs_modulus_GPa"] == s["youngs_modulus_GPa"]


def test_plate_wave_speed_within_the_bounds(tmp_path):
    """A plane P wave in a short periodic column: the front speed lies within 3 % of the potential's
    Hill plate speed and the report holds the references."""
    out, s = _run(tmp_path, "polycrystal_waves", 'waves.experiments=["plate"]', "waves.cubes=[2, 2, 16]",
                  "samples.lammps_check=0")
    hill = s["bounds"]["hill"]["wave_speed_plate_m_s"]
    assert s["wave_speed_plate_m_s"] == pytest.approx(hill, rel=0.03)
    assert "8850" in (out / "report.md").read_text() and (out / "wavefront.png").exists()


@pytest.mark.parametrize("sets, field", [
    (["tension.cubes=[0]", "tension.cube_nm=[5.0]"], "tension.cubes[0]"),
    (["tension.cubes=[-4]", "tension.cube_nm=[5.0]"], "tension.cubes[0]"),
    (["tension.cube_nm=[5.0]"], "tension.cube_nm"),
    (["tension.strain_rate_per_ns=5.0"], "tension.strain_rate_per_ns"),
    (['samples.relaxation="fire"'], "samples.relaxation"),
    (["tension.max_strain=0.5"], "tension.max_strain"),
])
def test_bad_tension_input_is_refused_in_one_line(tmp_path, capsys, sets, field):
    assert_refused(capsys, ["run", "polycrystal_tension", "--out", str(tmp_path / "x")], sets, field, tmp_path / "x")


def test_waves_bad_input_and_an_unstable_potential_are_refused(tmp_path, capsys):
    assert_refused(capsys, ["run", "polycrystal_waves", "--out", str(tmp_path / "x")], ["waves.cubes=[4, 0, 40]"],
                   "waves.cubes[1]", tmp_path / "x")
    # a set whose diamond crystal does not bind: B (the attraction) 100 times weaker
    bad = load_parameters(POTENTIAL, "Si").replace(B=1.1317)
    write_tersoff(tmp_path / "unbound.tersoff", bad)
    assert_refused(capsys, ["run", "polycrystal_tension", "--out", str(tmp_path / "y")],
                   [f'tersoff.potential="{tmp_path / "unbound.tersoff"}"'], "tersoff.potential", tmp_path / "y")
