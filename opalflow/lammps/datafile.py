"""LAMMPS data files for ``atom_style bpm/sphere``: writer and reader; and LAMMPS text dumps (a writer).

Atoms lines are ``id molecule type diameter density x y z ix iy iz`` (LAMMPS ``read_data``,
atom style bpm/sphere; nm and attogram/nm^3 in ``units nano``, as the Structure
holds them; image flags from :meth:`Structure.image_flags`, so bonds are short when
unwrapped wherever a network does not wrap around the periodic box), Bonds lines
``id type atom1 atom2``.

Writing tens of millions of lines with ``%``-formatting costs minutes in Python; here
each column becomes fixed-width ASCII digits by integer arithmetic on numpy arrays
(``_digits``), written in blocks of 1 M rows.  Coordinates are written with six
decimals from their integer count of 1e-6 nm, so a Structure whose positions were
rounded the same way (:func:`opalflow.structure.quantize`) reads back bit for bit.
Diameters, densities and box bounds are written with ``repr`` (shortest round trip).
"""
from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

from opalflow.spec import InputError
from opalflow.structure import Structure
from opalflow.store import failpoint

DECIMALS = 6
BLOCK = 1 << 20


def _digits(values: np.ndarray, width: int) -> np.ndarray:
    """Non-negative integers as right-aligned ASCII digits, shape (n, width), uint8."""
    v = values.astype(np.int64)
    out = np.empty((len(v), width), np.uint8)
    for col in range(width - 1, -1, -1):
        out[:, col] = 48 + v % 10
        v = v // 10
    # blank the leading zeros (keep at least the last digit)
    lead = np.cumprod(out[:, :-1] == 48, axis=1).astype(bool)
    out[:, :-1][lead] = 32
    return out


def _width(maxval: int) -> int:
    return max(1, len(str(int(maxval))))


def _fixed(values: np.ndarray, decimals: int) -> np.ndarray:
    """Reals as right-aligned fixed-point ASCII with a sign where needed, (n, width) uint8."""
    k = np.round(values * 10.0**decimals).astype(np.int64)
    neg = k < 0
    k = np.abs(k)
    scale = 10**decimals
    ip, fp = k // scale, k % scale
    wi = _width(ip.max()) + 1 if len(k) else 2
    ints = _digits(ip, wi)
    n_int = np.where(ip > 0, np.floor(np.log10(np.maximum(ip, 1))).astype(int) + 1, 1)
    rows = np.flatnonzero(neg)
    ints[rows, wi - n_int[rows] - 1] = ord("-")
    fr = _digits(fp + scale, decimals + 1)[:, 1:]  # keep leading zeros of the fraction
    dot = np.full((len(k), 1), ord("."), np.uint8)
    return np.hstack([ints, dot, fr])


def _lookup(values: np.ndarray, text=lambda u: repr(float(u))) -> np.ndarray:
    """Few distinct values (diameters, densities, image flags) as right-aligned text, (n, width) uint8."""
    uniq, inv = np.unique(values, return_inverse=True)
    texts = [text(u) for u in uniq]
    w = max(len(t) for t in texts)
    table = np.array([list(t.rjust(w).encode()) for t in texts], dtype=np.uint8)
    return table[inv]


def _join(columns: list[np.ndarray]) -> bytes:
    sep = np.full((len(columns[0]), 1), 32, np.uint8)
    parts = []
    for c in columns:
        parts += [c, sep]
    parts[-1] = np.full((len(columns[0]), 1), 10, np.uint8)
    return np.hstack(parts).tobytes()


def write_data(path: str | os.PathLike, s: Structure, title: str = "opalflow") -> None:
    """Write ``s`` as a bpm/sphere data file (to ``path.tmp``, then renamed)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    n, m = s.n_particles, s.n_bonds
    lo, hi = s.box_lo, s.box_hi
    head = [f"LAMMPS data file: {title}", "",
            f"{n} atoms", f"{len(s.type_names) or int(s.types.max(initial=1))} atom types"]
    if m:
        head += [f"{m} bonds", f"{len(s.bond_type_names) or int(s.bond_types.max())} bond types"]
    head += [""]
    for k, ax in enumerate("xyz"):
        head.append(f"{float(lo[k])!r} {float(hi[k])!r} {ax}lo {ax}hi")
    head += ["", "Atoms # bpm/sphere", "", ""]
    names = " ".join(f"{t + 1}={nm}" for t, nm in enumerate(s.type_names))
    if names:
        head.insert(1, f"# atom types: {names}")
    flags = s.image_flags()
    if m and s.periodic.any():
        x, y, z = s.wrapping_bonds(flags)
        head.insert(1, f"# image flags: bonds that wrap around the periodic box (long when unwrapped, as in any "
                       f"infinite network): x {x}, y {y}, z {z}")
    with open(tmp, "wb") as f:
        f.write("\n".join(head).encode())
        wid = _width(n)
        for a in range(0, n, BLOCK):
            b = min(n, a + BLOCK)
            cols = [_digits(np.arange(a + 1, b + 1), wid),
                    _digits(s.molecules[a:b], _width(s.molecules.max(initial=1))),
                    _digits(s.types[a:b], _width(s.types.max(initial=1))),
                    _lookup(s.diameters[a:b]),
                    _lookup(s.densities[a:b])]
            cols += [_fixed(s.positions[a:b, k], DECIMALS) for k in range(3)]
            cols += [_lookup(flags[a:b, k], str) for k in range(3)]
            f.write(_join(cols))
        if m:
            f.write(b"\nBonds\n\n")
            wb = _width(m)
            for a in range(0, m, BLOCK):
                b = min(m, a + BLOCK)
                f.write(_join([_digits(np.arange(a + 1, b + 1), wb),
                               _digits(s.bond_types[a:b], _width(s.bond_types.max())),
                               _digits(s.bonds[a:b, 0] + 1, wid), _digits(s.bonds[a:b, 1] + 1, wid)]))
    failpoint()
    os.replace(tmp, path)


def write_dump(path: str | os.PathLike, s: Structure, columns: dict[str, np.ndarray]) -> None:
    """One snapshot of ``s`` as a LAMMPS text dump (``dump custom``; OVITO reads it): ``columns`` name -> (N,) or
    (N, k) values in atom order, integers as integers and reals with six decimals, formatted as :func:`write_data`
    formats (the paper's sample's 1.6 M particles, id type x y z radius broken_bonds: 1.5 s where numpy's
    ``savetxt`` took 4.7); box bounds ``pp`` along the periodic directions, ``ff`` along the others."""
    lo, hi = s.box_lo, s.box_hi
    bounds = " ".join("pp" if p else "ff" for p in s.periodic)
    names, parts = [], []
    for name, values in columns.items():
        values = np.asarray(values)
        names += [name] if values.ndim == 1 else [f"{name}[{k}]" for k in range(values.shape[1])]
        parts += [values] if values.ndim == 1 else list(values.T)
    head = ["ITEM: TIMESTEP", "0", "ITEM: NUMBER OF ATOMS", str(s.n_particles), f"ITEM: BOX BOUNDS {bounds}"]
    head += [f"{float(lo[k])!r} {float(hi[k])!r}" for k in range(3)] + ["ITEM: ATOMS " + " ".join(names), ""]
    with open(path, "wb") as f:
        f.write("\n".join(head).encode())
        for a in range(0, s.n_particles, BLOCK):
            b = min(s.n_particles, a + BLOCK)
            f.write(_join([_digits(v[a:b], _width(np.max(v, initial=1))) if v.dtype.kind in "iub"
                           else _fixed(v[a:b], DECIMALS) for v in parts]))


SECTION = re.compile(rb"^(Atoms|Velocities|Bonds|Masses|Pair Coeffs|PairIJ Coeffs|Bond Coeffs)\b(.*)$",
                     re.MULTILINE)
COUNT = re.compile(r"^\s*(\d+)\s+(atoms|bonds)\s*$", re.MULTILINE)


class DataFileError(InputError):
    """A data file that is not a readable bpm/sphere data file (one line: the file and what is wrong)."""

    def __init__(self, path, what: str):
        super().__init__(f"data file {path}: {what}")


def _table(path, name: str, body: bytes, ncols: tuple[int, ...], expected: int | None,
           layout: str = "id type atom1 atom2") -> np.ndarray:
    """Whitespace-separated numbers (comments stripped) as an (n, ncol) float64 array, ncol one of ``ncols``
    (the same on every line)."""
    if b"#" in body:
        body = re.sub(rb"#[^\n]*", b"", body)
    lines = [line for line in body.splitlines() if line.strip()]
    if not lines:
        return np.zeros((0, ncols[0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        try:
            values = np.fromstring(body.decode("ascii"), sep=" ")  # C parser; exact strtod
        except (DeprecationWarning, UnicodeDecodeError, ValueError):
            values = None
    if values is None or not np.all(np.isfinite(values)):
        raise DataFileError(path, f"the {name} section holds text that is not a finite number")
    ncol = values.size // max(len(lines), 1)
    if ncol not in ncols or len(lines) * ncol != values.size:
        raise DataFileError(path, f"the {name} section needs {' or '.join(map(str, ncols))} numbers on every line; "
                                  f"it has {values.size} numbers on {len(lines)} lines ({layout})")
    if expected is not None and len(lines) != expected:
        raise DataFileError(path, f"the header declares {expected} {name.lower()} but the section has "
                                  f"{len(lines)} lines (a truncated file?)")
    return values.reshape(-1, ncol)


#: per-atom fields of the Atoms section by atom style (LAMMPS read_data, "Atoms section" table)
STYLE_FIELDS = {
    "bpm/sphere": ("id", "molecule", "type", "diameter", "density", "x", "y", "z"),
    "sphere": ("id", "type", "diameter", "density", "x", "y", "z"),
}
#: fields each sub-style adds after ``id type x y z`` in an ``atom_style hybrid`` line (LAMMPS read_data:
#: a field an earlier sub-style already gave is not repeated, AtomVecHybrid's merged field list)
HYBRID_FIELDS = {
    "bpm/sphere": ("molecule", "diameter", "density"), "sphere": ("diameter", "density"),
    "dipole": ("q", "mux", "muy", "muz"), "charge": ("q",), "bond": ("molecule",), "angle": ("molecule",),
    "molecular": ("molecule",), "full": ("molecule", "q"), "atomic": (), "ellipsoid": ("ellipsoidflag", "density"),
    "sphere/dipole": ("diameter", "density", "q", "mux", "muy", "muz"),
}


def atom_fields(atom_style: str) -> tuple[str, ...]:
    """The fields of one Atoms line of ``atom_style`` ("bpm/sphere", "sphere", "hybrid bpm/sphere dipole", ...);
    InputError for a style without diameters and densities."""
    words = atom_style.split()
    if len(words) == 1 and words[0] in STYLE_FIELDS:
        return STYLE_FIELDS[words[0]]
    if len(words) >= 2 and words[0] == "hybrid":
        unknown = [w for w in words[1:] if w not in HYBRID_FIELDS]
        if unknown:
            raise InputError(f"datafile.atom_style = {atom_style!r}: sub-style {unknown[0]!r} is not one opalflow "
                             f"reads ({', '.join(HYBRID_FIELDS)})")
        fields = ["id", "type", "x", "y", "z"]
        for w in words[1:]:
            fields += [f for f in HYBRID_FIELDS[w] if f not in fields]
        if "diameter" not in fields:
            raise InputError(f"datafile.atom_style = {atom_style!r}: needs a sub-style with diameters and densities "
                             "(bpm/sphere or sphere)")
        return tuple(fields)
    raise InputError(f"datafile.atom_style = {atom_style!r}: must be bpm/sphere, sphere or 'hybrid SUB ...' with "
                     "bpm/sphere or sphere among the sub-styles")


def read_data(path: str | os.PathLike, periodic=(True, True, False), atom_style: str = "bpm/sphere") -> Structure:
    """Read a data file written by opalflow or LAMMPS (``write_data``) with diameters and densities:
    ``atom_style`` bpm/sphere (opalflow's), sphere, or hybrid with one of them among its sub-styles (as
    LAMMPS's read_data, the style is not in the file: the ``# hybrid`` comment names no sub-style).

    ``periodic`` is not stored in data files; pass the boundary of the deck.
    Sections other than Atoms and Bonds (Velocities, Coeffs) are skipped.  Anything that is not a
    whole data file of that style raises :class:`DataFileError` naming the file and what is wrong.
    """
    fields = atom_fields(atom_style)
    col = {f: k for k, f in enumerate(fields)}
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise DataFileError(path, f"cannot be read ({exc.strerror})") from None
    marks = list(SECTION.finditer(raw))
    if not marks or not any(m.group(1) == b"Atoms" for m in marks):
        raise DataFileError(path, "no Atoms section: not a LAMMPS data file")
    try:
        header_text = raw[: marks[0].start()].decode()
    except UnicodeDecodeError:
        raise DataFileError(path, "the header is not text") from None
    box, type_names = _header_box(path, header_text)
    counts = {word: int(n) for n, word in COUNT.findall(header_text)}
    bodies, styles = {}, {}
    for k, m in enumerate(marks):
        end = marks[k + 1].start() if k + 1 < len(marks) else len(raw)
        bodies[m.group(1).decode()] = raw[m.end():end]
        styles[m.group(1).decode()] = m.group(2).decode(errors="replace").strip().lstrip("#").strip()
    declared = styles["Atoms"].split()[0] if styles["Atoms"] else ""
    if declared and declared != atom_style.split()[0]:
        raise DataFileError(path, f"its Atoms section says atom style {styles['Atoms']!r}, not {atom_style!r} "
                                  "(datafile.atom_style names the style, as atom_style does before read_data)")
    atoms = _atoms(path, bodies["Atoms"], counts.get("atoms"), fields, atom_style)
    ids = atoms[:, 0]
    if "Bonds" in bodies:
        bonds, bond_types = _bonds(path, bodies["Bonds"], counts.get("bonds"), ids)
    elif counts.get("bonds"):
        raise DataFileError(path, f"the header declares {counts['bonds']} bonds but there is no Bonds section")
    else:
        bonds, bond_types = np.zeros((0, 2), np.int64), np.zeros(0, np.int32)
    molecules = atoms[:, col["molecule"]].astype(np.int32) if "molecule" in col else np.zeros(len(atoms), np.int32)
    return Structure(
        positions=atoms[:, [col["x"], col["y"], col["z"]]], diameters=atoms[:, col["diameter"]],
        types=atoms[:, col["type"]].astype(np.int32), densities=atoms[:, col["density"]], box_lo=box[:, 0],
        box_hi=box[:, 1], periodic=np.asarray(periodic), bonds=bonds, bond_types=bond_types, molecules=molecules,
        type_names=type_names,
    )


def _header_box(path, header_text: str) -> tuple[np.ndarray, list[str]]:
    """The box (3 x lo, hi) and the type names (opalflow's ``# atom types:`` comment) of a data file's header."""
    box = np.full((3, 2), np.nan)
    type_names: list[str] = []
    for line in header_text.splitlines()[1:]:
        if line.startswith("# atom types:"):
            type_names = [t.split("=", 1)[1] for t in line.split(":", 1)[1].split() if "=" in t]
        parts = line.split("#")[0].split()
        if len(parts) == 4 and parts[-1] in ("xhi", "yhi", "zhi"):
            try:
                box["xyz".index(parts[-1][0])] = [float(parts[0]), float(parts[1])]
            except ValueError:
                raise DataFileError(path, f"box line {line.strip()!r} needs two numbers") from None
    if not np.all(np.isfinite(box)) or np.any(box[:, 1] <= box[:, 0]):
        raise DataFileError(path, "the header needs 'xlo xhi', 'ylo yhi' and 'zlo zhi' lines with lo < hi")
    return box, type_names


def _atoms(path, body: bytes, count: int | None, fields: tuple, atom_style: str) -> np.ndarray:
    """The Atoms section as a table sorted by id, its ids, types, diameters and densities checked."""
    col = {f: k for k, f in enumerate(fields)}
    atoms = _table(path, "Atoms", body, (len(fields), len(fields) + 3), count,
                   f"atom style {atom_style}: {' '.join(fields)} [ix iy iz]")
    atoms = atoms[np.argsort(atoms[:, 0], kind="stable")]
    ids = atoms[:, 0]
    if len(ids) == 0:
        raise DataFileError(path, "the Atoms section is empty")
    if np.any(ids < 1) or np.any(ids != np.round(ids)) or np.any(np.diff(ids) == 0):
        raise DataFileError(path, "atom ids must be distinct integers >= 1")
    types = atoms[:, col["type"]]
    if np.any(types < 1) or np.any(types != np.round(types)):
        raise DataFileError(path, "atom types must be integers >= 1")
    if np.any(atoms[:, col["diameter"]] <= 0) or np.any(atoms[:, col["density"]] <= 0):
        raise DataFileError(path, f"every diameter and density must be > 0 (columns {col['diameter'] + 1} and "
                                  f"{col['density'] + 1} of atom style {atom_style})")
    return atoms


def _bonds(path, body: bytes, count: int | None, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Bonds section: each bond's two atoms (as indices of the sorted Atoms table) and its type."""
    braw = _table(path, "Bonds", body, (4,), count)
    if np.any(braw != np.round(braw)) or np.any(braw[:, 1] < 1):
        raise DataFileError(path, "bond lines must be integers 'id type atom1 atom2' with type >= 1")
    braw = braw.astype(np.int64)
    braw = braw[np.argsort(braw[:, 0], kind="stable")]
    id_to_index = np.full(int(ids.max()) + 1, -1, np.int64)
    id_to_index[ids.astype(np.int64)] = np.arange(len(ids))
    ends = braw[:, 2:4]
    if np.any(ends < 1) or np.any(ends > ids.max()) or np.any(id_to_index[np.clip(ends, 0, None)] < 0):
        raise DataFileError(path, "a bond names an atom id that is not in the Atoms section")
    if np.any(ends[:, 0] == ends[:, 1]):
        raise DataFileError(path, "a bond joins an atom to itself")
    return id_to_index[ends], braw[:, 1].astype(np.int32)
