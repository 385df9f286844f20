"""bpm/sphere data files: exact round trip, real LAMMPS and MDAnalysis read them."""
import numpy as np

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
