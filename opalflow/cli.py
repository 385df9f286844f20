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
    """Structure + full deck (data.lmp, in.lmp, resume.lmp, run.sh) + summary.json; no run."""
    from opalflow.pipeline import prepare
    from opalflow.store import write_json_atomic

    spec = load_spec(workflow_path(args.workflow), args.set)
    if spec.kind.startswith("tersoff") or spec.kind == "study":
        raise SpecError("kind", spec.kind, "atomistic workflows and studies have no single deck to build: use 'run'")
    out = _out_folder(args.out)
    start = time.perf_counter()
    _say(f"building {spec.name} ({spec.kind})")
    deck = prepare(spec, out, progress=_say)
    summary = {"workflow": spec.name, "opalflow_version": __version__}
    if spec.kind == "opal":
        from opalflow.build.opal import structure_statistics

        stats = structure_statistics(deck.source)
        summary.update(stats)
        _say(f"{stats['n_particles']} particles, {stats['n_bonds']} bonds, porosity {stats['porosity']:.3f}, "
             f"{stats['particles_per_um3']:.0f} particles/um^3, {stats['bonds_per_um3']:.0f} bonds/um^3")
    else:
        summary.update({"n_particles": deck.structure.n_particles, "n_bonds": deck.structure.n_bonds})
    summary["deck"] = deck.info()
    summary["timings_s"] = {**deck.structure.meta.get("timings_s", {}),
                            "total": round(time.perf_counter() - start, 3)}
    summary["spec"] = spec.to_dict()
    write_json_atomic(out / "summary.json", summary)
    _say(f"wrote {out}/data.lmp, in.lmp, run.sh ({time.perf_counter() - start:.1f} s); "
         f"'bash {out}/run.sh' runs it with LAMMPS alone")
    return 0


def _out_folder(path: str) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise SpecError("--out", str(out), "exists and is not a folder")
    return out


def cmd_run(args) -> int:
    from opalflow.lammps.engine import EngineError
    from opalflow.pipeline import run_workflow

    out = _out_folder(args.out)
    if args.resume:
        import json as _json

        run_json = out / "run.json"
        if not run_json.exists():
            raise SpecError("--resume", str(out), "no run.json: this folder holds no prepared run")
        from opalflow.spec import spec_from_dict

        spec = spec_from_dict(_json.loads(run_json.read_text())["spec"])
    elif args.workflow is None:
        raise SpecError("workflow", None, "give a workflow file or name (or --resume with --out)")
    else:
        spec = load_spec(workflow_path(args.workflow), args.set)
    if args.np < 1:
        raise SpecError("--np", args.np, "must be >= 1")
    if spec.kind.startswith("tersoff") and (args.np > 1 or args.suffix or args.resume):
        raise SpecError("--np/--suffix/--resume", spec.kind, "atomistic workflows run in-process and take "
                        "seconds; stability.workers sets how many MD runs go at once")
    if spec.kind == "study" and (args.np > 1 or args.suffix or args.resume):
        raise SpecError("--np/--suffix/--resume", spec.kind, "a study sets study.np and study.workers; "
                        "rerunning it resumes it (finished jobs are kept)")
    if args.suffix:
        from opalflow.lammps.engine import lammps_info

        usable = lammps_info()["accelerators"]
        if args.suffix not in usable:
            raise SpecError("--suffix", args.suffix, f"this LAMMPS build offers {', '.join(usable) or 'none'}")
    try:
        summary = run_workflow(spec, out, np_=args.np, resume=args.resume, say=_say, suffix=args.suffix)
    except EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(f"run folder kept: {out}", file=sys.stderr)
        return 1
    print(f"{summary['headline']}, {summary['wall_s']:.1f} s -> {out}/report.md")
    return 0


def cmd_analyze(args) -> int:
    from opalflow.pipeline import analyze

    out = Path(args.folder)
    if not (out / "run.json").exists() or not (out / "curve.txt").exists():
        raise SpecError("folder", str(out), "needs run.json and curve.txt (a built folder after 'bash run.sh')")
    summary = analyze(out)
    print(f"{summary['headline']} -> {out}/report.md")
    return 0


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m opalflow", description=__doc__)
    ap.add_argument("--version", action="version", version=f"opalflow {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="opalflow and LAMMPS versions, packages, accelerators").set_defaults(func=cmd_info)
    sub.add_parser("list", help="workflows with one-line descriptions").set_defaults(func=cmd_list)
    b = sub.add_parser("build", help="write the structure and the full deck (data.lmp, in.lmp, run.sh)")
    b.add_argument("workflow", help="workflow file or name in workflows/")
    b.add_argument("--out", required=True, help="output folder")
    b.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a spec field (repeatable)")
    b.set_defaults(func=cmd_build)
    r = sub.add_parser("run", help="build, run LAMMPS, analyze: results.h5, summary.json, report.md, plots")
    r.add_argument("workflow", nargs="?", default=None, help="workflow file or name (not with --resume)")
    r.add_argument("--out", required=True, help="run folder")
    r.add_argument("--np", type=int, default=1, help="MPI processes (runs 'lmp' under mpiexec)")
    r.add_argument("--resume", action="store_true", help="continue from the newest restart file in --out")
    r.add_argument("--suffix", choices=["omp", "kk", "gpu"], default=None,
                   help="accelerator styles (-sf) where the LAMMPS build has them; bpm bonds have none")
    r.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    r.set_defaults(func=cmd_run)
    a = sub.add_parser("analyze", help="analyze a run folder's LAMMPS output (e.g. after bash run.sh)")
    a.add_argument("folder")
    a.set_defaults(func=cmd_analyze)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    from opalflow.build.pores import PoreError

    try:
        return args.func(args)
    except (SpecError, PoreError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
