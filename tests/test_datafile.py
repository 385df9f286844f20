"""bpm/sphere data files: exact round trip, real LAMMPS and MDAnalysis read them."""
import json
from pathlib import Path

import numpy as np
import pytest

from opalflow.opal.scene import build_opal
from opalflow.lammps.datafile import read_data, write_data
from opalflow.bpm.deck import compression_deck
from opalflow.lammps.engine import new_lammps
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec

FIELDS = ["positions", "diameters", "types", "densities", "box_lo", "box_hi", "bonds",
          "bond_types", "molecules"]


def test_round_trip_is_exact(tmp_path, coated_quick):
    _, s = coated_quick
    write_data(tmp_path / "data.lmp", s)
    r = read_data(tmp_path / "data.lmp")
    for f in FIELDS:
        assert np.array_equal(getattr(s, f), getattr(r, f)), f
    assert r.type_names == s.type_names == ["silica", "substrate", "titania"]
    assert not (tmp_path / "data.lmp.tmp").exists()


def test_negative_coordinates_round_trip(tmp_path, quick_structure):
    s = quick_structure.select(np.arange(quick_structure.n_particles) < 50)
    s.box_lo = s.box_lo - 100.0
    s.positions[:5] -= np.array([99.5, 0.25, 0.000001])
    s.positions = np.round(s.positions * 1e6) / 1e6
    write_data(tmp_path / "d.lmp", s)
    r = read_data(tmp_path / "d.lmp")
    assert np.array_equal(r.positions, s.positions)


def test_lammps_reads_data_and_runs_zero_steps(tmp_path, coated_quick):
    """The real compression deck, its run replaced by 'run 0', reads the file with its bonds."""
    spec, s = coated_quick
    deck = compression_deck(spec, s)
    write_data(tmp_path / "data.lmp", deck.structure)
    (tmp_path / "snapshots").mkdir()
    lines = [ln for ln in deck.in_lmp.splitlines() if not ln.startswith("restart ")
             and not (ln.startswith("run ") and "upto" in ln)]
    (tmp_path / "in.lmp").write_text("\n".join(lines + ["run 0"]) + "\n")
    lmp = new_lammps(log=tmp_path / "log.lammps")
    try:
        import os
        cwd = os.getcwd()
        os.chdir(tmp_path)
        try:
            lmp.file("in.lmp")
        finally:
            os.chdir(cwd)
        assert lmp.get_natoms() == s.n_particles
        assert lmp.extract_global("nbonds") == s.n_bonds
        assert lmp.extract_setting("nbondtypes") == len(deck.bins.lengths) > 2
        assert lmp.extract_setting("ntypes") == 3
        # LAMMPS keeps what we wrote: positions and diameters of every atom
        x = np.array(lmp.gather_atoms("x", 1, 3)).reshape(-1, 3)
        rad = np.array(lmp.gather_atoms("radius", 1, 1))
        assert np.allclose(x, s.positions, atol=1e-9)
        assert np.allclose(2 * rad, s.diameters)
    finally:
        lmp.close()


def test_mdanalysis_reads_data(tmp_path, quick_structure):
    import MDAnalysis as mda

    write_data(tmp_path / "data.lmp", quick_structure)
    u = mda.Universe(str(tmp_path / "data.lmp"), format="DATA",
                     atom_style="id resid type diameter density x y z")
    assert len(u.atoms) == quick_structure.n_particles
    assert len(u.bonds) == quick_structure.n_bonds
    assert np.allclose(u.atoms.positions, quick_structure.positions, atol=1e-3)


def test_same_spec_same_bytes_other_seed_other_file(tmp_path):
    spec = load_spec(WORKFLOWS / "opal_quick.toml")
    other = load_spec(WORKFLOWS / "opal_quick.toml", ["packing.seed=2"])
    for name, sp in (("a", spec), ("b", spec), ("c", other)):
        write_data(tmp_path / f"{name}.lmp", build_opal(sp)[0])
    a, b, c = ((tmp_path / f"{n}.lmp").read_bytes() for n in "abc")
    assert a == b
    assert a != c


def _malformed(good: bytes) -> dict[str, bytes]:
    text = good.decode()
    lines = text.splitlines(keepends=True)
    first = next(k for k, line in enumerate(lines) if len(line.split()) == 11 and line.split()[0] == "1")

    def row(change) -> bytes:
        words = lines[first].split()
        change(words)
        return "".join(lines[:first] + [" ".join(words) + "\n"] + lines[first + 1:]).encode()

    return {
        "empty": b"",
        "garbage": bytes(range(256)) * 40,
        "truncated": good[: len(good) // 2],
        "atomic_style": text.replace("Atoms # bpm/sphere", "Atoms # atomic").encode(),
        "no_box": "".join(line for line in lines if "xlo" not in line).encode(),
        "text_in_atoms": row(lambda w: w.__setitem__(3, "sixty")),
        "short_atom_line": row(lambda w: w.pop()),
        "negative_diameter": row(lambda w: w.__setitem__(3, "-60.0")),
        "duplicate_id": row(lambda w: w.__setitem__(0, "2")),
        "bond_to_nobody": text.rstrip("\n").rsplit("\n", 1)[0].encode() + b"\n99999 1 1 999999\n",
    }


def test_every_malformed_data_file_is_one_line_naming_it(tmp_path, capsys):
    """kind = "datafile" with a broken file: exit 2, one error line naming the file and what is wrong, no
    traceback, nothing written."""
    from opalflow.bpm.pipeline import build_structure
    from opalflow.cli import main

    spec = load_spec(WORKFLOWS / "lattice_sc.toml")
    write_data(tmp_path / "good.lmp", build_structure(spec))
    cases = _malformed((tmp_path / "good.lmp").read_bytes())
    for name, content in cases.items():
        path = tmp_path / f"{name}.lmp"
        path.write_bytes(content)
        out = tmp_path / f"run_{name}"
        code = main(["build", "lattice_sc", "--out", str(out), "--set", "kind=datafile",
                     "--set", f'datafile.path="{path}"', "--set", 'datafile.materials=["silica","substrate"]'])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2, name
        # after the progress line 'building ...': one error line, the last
        assert [line for line in err if "error" in line.lower()] == err[-1:], (name, err)
        assert err[-1].startswith(f"error: data file {path}: "), (name, err)
        assert not out.exists(), name


def rod_frame(path, cells: int = 2, step: float = 0.1) -> tuple[int, int]:
    """A frame of rods in LAMMPS's own format for its BPM examples (examples/bpm/metamaterial): ``atom_style
    hybrid bpm/sphere dipole``, lj units, nodes (type 2, magnetic) on a cubic grid of spacing 1 joined along x,
    y and z by rods of spheres (type 1) of diameter ``step``; a bond between neighbours along each rod.
    Atoms lines: id type x y z molecule diameter density q mux muy muz."""
    import itertools

    atoms, bonds, node = [], [], {}
    grid = range(cells + 1)
    for p in itertools.product(grid, grid, grid):
        atoms.append((2, p, (1.0, 0.0, 0.0)))
        node[p] = len(atoms)
    n = int(round(1 / step))
    for p in itertools.product(grid, grid, grid):
        for axis in range(3):
            if p[axis] == cells:
                continue
            prev = node[p]
            for k in range(1, n):
                x = list(map(float, p))
                x[axis] += k * step
                atoms.append((1, tuple(x), (0.0, 0.0, 0.0)))
                bonds.append((prev, len(atoms)))
                prev = len(atoms)
            q = list(p)
            q[axis] += 1
            bonds.append((prev, node[tuple(q)]))
    lines = ["LAMMPS data file", "", f"{len(atoms)} atoms", f"{len(bonds)} bonds", "", "2 atom types", "1 bond types", ""]
    lines += [f"-0.5 {cells + 0.5} {a}lo {a}hi" for a in "xyz"] + ["", "Atoms # hybrid", ""]
    lines += [f"{i} {t} {x[0]:.6f} {x[1]:.6f} {x[2]:.6f} 1 {step:.6f} 1.000000 0.0 {m[0]} {m[1]} {m[2]}"
              for i, (t, x, m) in enumerate(atoms, 1)]
    lines += ["", "Bonds", ""] + [f"{k} 1 {a} {b}" for k, (a, b) in enumerate(bonds, 1)]
    Path(path).write_text("\n".join(lines) + "\n")
    return len(atoms), len(bonds)


RODS = ['kind="datafile"', 'datafile.atom_style="hybrid bpm/sphere dipole"', 'datafile.units="lj"',
        "datafile.length_unit_nm=100.0", 'datafile.substrate="z < 0.05"', "datafile.periodic_sides=false",
        "contacts.enabled=false"]


def test_a_lammps_hybrid_lj_data_file_runs_with_its_substrate_and_length_unit(tmp_path):
    """LAMMPS's BPM examples write ``atom_style hybrid bpm/sphere dipole`` in lj units: read with the style and
    a length unit, the substrate chosen explicitly, densities from the material, the stress on the frame's
    footprint, and the report says which columns, units and bonds were used."""
    from opalflow.api import run

    path = tmp_path / "frame.data"
    n_atoms, n_bonds = rod_frame(path)
    sets = {k: v for k, v in (s.split("=", 1) for s in RODS)}
    from opalflow.spec import parse_value

    sets = {k: parse_value(v) for k, v in sets.items()} | {"datafile.path": str(path)}
    s = run("lattice_sc", tmp_path / "static", set=sets | {"compression.method": "static"}, quiet=True)
    assert s["n_particles"] == n_atoms and s["n_bonds"] == n_bonds and s["youngs_modulus_GPa"] > 0
    info = json.loads((tmp_path / "static" / "run.json").read_text())["deck"]
    frame = (2 * 100.0 + 10.0) ** 2               # 2 cells of 100 nm plus a rod diameter: not the box's 300 nm
    assert info["area_nm2"] == pytest.approx(frame, rel=1e-6)
    report = (tmp_path / "static" / "report.md").read_text()
    assert "atom style hybrid bpm/sphere dipole, units lj, 1 length unit = 100 nm" in report
    assert f"bonds: the file's {n_bonds}, typed by material (silica)" in report
    from opalflow.lammps.datafile import read_data
    from opalflow.materials import material

    silica = material("silica").density_kg_m3

    data = read_data(tmp_path / "static" / "data.lmp", periodic=(False, False, False))
    assert np.allclose(data.densities * 1e6, silica, rtol=0.01) and np.allclose(data.diameters, 10.0)
    d = run("lattice_sc", tmp_path / "dynamic", set=sets | {"compression.strain_max": 0.002,
                                                            "compression.snapshot_strains": [0.001]}, quiet=True)
    # the dynamic plate run of the slender-rod frame (0.1 m/s, strain 0.002) measured 16 % under the zero-rate solve
    assert d["youngs_modulus_specimen_GPa"] == pytest.approx(s["youngs_modulus_GPa"], rel=0.25)
    bonds_row = next(line for line in (tmp_path / "dynamic" / "report.md").read_text().splitlines()
                     if line.startswith("| bonds |"))
    assert "from the data file" in bonds_row and "cutoff" not in bonds_row


@pytest.mark.parametrize("change,field", [
    ({"datafile.atom_style": "bpm/sphere"}, "data file"),
    ({"datafile.atom_style": "hybrid dipole"}, "datafile.atom_style"),
    ({"datafile.atom_style": "hybrid bpm/sphere body"}, "datafile.atom_style"),
    ({"datafile.length_unit_nm": 0.0}, "datafile.length_unit_nm"),
    ({"datafile.density": "file"}, "datafile.density"),
    ({"datafile.substrate": "z < -1"}, "datafile.substrate"),
    ({"datafile.substrate": "z < 0.1; shell rm"}, "datafile.substrate"),
    ({"datafile.substrate": ""}, "datafile.substrate"),
    ({"datafile.substrate": "type 7"}, "datafile.substrate"),
])
def test_a_data_file_workflow_that_cannot_be_read_is_one_line(tmp_path, capsys, change, field):
    from opalflow.cli import main

    path = tmp_path / "frame.data"
    rod_frame(path, cells=1)
    sets = RODS + [f'datafile.path="{path}"'] + [f"{k}={json.dumps(v)}" for k, v in change.items()]
    out = tmp_path / "out"
    assert main(["build", "lattice_sc", "--out", str(out), *[x for s in sets for x in ("--set", s)]]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.startswith("error")]
    assert len(err) == 1 and err[0].startswith(f"error: {field}"), err
    assert not out.exists()
