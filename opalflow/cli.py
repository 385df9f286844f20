"""Command line: ``python -m opalflow info | list | build``."""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

from opalflow import __version__
from opalflow.resources import WORKFLOWS
from opalflow.spec import SpecError, load_spec


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def workflow_path(arg: str) -> Path:
    """A workflow file: a path, or the name of a file in workflows/ (with or without .toml)."""
    p = Path(arg)
    if p.exists():
        return p
    for cand in (WORKFLOWS / arg, WORKFLOWS / f"{arg}.toml"):
        if cand.exists():
            return cand
    raise SpecError("workflow", arg, f"no such file, nor a workflow in {WORKFLOWS} "
                    "(python -m opalflow list shows them)")


def cmd_info(args) -> int:
    from opalflow.lammps.engine import lammps_info

    info = lammps_info()
    print(f"opalflow {__version__}")
    print(f"LAMMPS {info['version']} (Python module)")
    for pkg, present in info["reported"].items():
        print(f"  {pkg:<9} {'yes' if present else 'no'}")
    print(f"accelerators usable: {', '.join(info['accelerators']) or 'none'}"
          f" (GPU device: {'yes' if info['has_gpu_device'] else 'no'})")
    print(f"MPI launcher: {info['mpi_launcher'] or 'not found'}")
    print(f"lmp executable: {info['lmp'] or 'not found'}")
    print(f"LIGGGHTS: {info['liggghts'] or 'not found'}")
    return 0


def cmd_list(args) -> int:
    for path in sorted(WORKFLOWS.glob("*.toml")):
        desc = tomllib.loads(path.read_text()).get("description", "")
        print(f"{path.stem:<24} {desc}")
    return 0


def cmd_build(args) -> int:
    from opalflow.build.opal import build_opal, structure_statistics
    from opalflow.lammps.datafile import write_data
    from opalflow.lammps.deck import check_deck
    from opalflow.store import write_json_atomic, write_text_atomic

    spec = load_spec(workflow_path(args.workflow), args.set)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise SpecError("--out", str(out), "exists and is not a folder")
    start = time.perf_counter()
    _say(f"building {spec.name}: {spec.pores.arrangement} pores, d = {spec.packing.diameter_nm:g} nm")
    structure, timings = build_opal(spec, progress=_say)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    write_data(out / "data.lmp", structure, title=f"opalflow {__version__} {spec.name}")
    write_text_atomic(out / "in.lmp", check_deck(structure, spec.name))
    timings["write"] = time.perf_counter() - t
    stats = structure_statistics(structure)
    timings["total"] = time.perf_counter() - start
    summary = {"workflow": spec.name, "opalflow_version": __version__, **stats,
               "timings_s": {k: round(v, 3) for k, v in timings.items()}, "spec": spec.to_dict()}
    write_json_atomic(out / "summary.json", summary)
    _say(f"{stats['n_particles']} particles, {stats['n_bonds']} bonds, porosity {stats['porosity']:.3f}, "
         f"{stats['particles_per_um3']:.0f} particles/um^3, {stats['bonds_per_um3']:.0f} bonds/um^3, "
         f"{timings['total']:.1f} s -> {out}")
    return 0


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m opalflow", description=__doc__)
    ap.add_argument("--version", action="version", version=f"opalflow {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="opalflow and LAMMPS versions, packages, accelerators").set_defaults(func=cmd_info)
    sub.add_parser("list", help="workflows with one-line descriptions").set_defaults(func=cmd_list)
    b = sub.add_parser("build", help="write data.lmp, in.lmp and summary.json for a workflow")
    b.add_argument("workflow", help="workflow file or name in workflows/")
    b.add_argument("--out", required=True, help="output folder")
    b.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a spec field (repeatable)")
    b.set_defaults(func=cmd_build)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except SpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
