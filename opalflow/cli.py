"""Command line: ``python -m opalflow info | list | build | run | check | analyze``; what each kind does comes from
:mod:`opalflow.registry`."""
from __future__ import annotations

import argparse
import errno
import json
import sys
import tomllib
from pathlib import Path

from opalflow import registry
from opalflow.resources import WORKFLOWS
from opalflow.spec import InputError, SpecError
from opalflow.version import __version__


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
    print("workflow kinds (kind = ... in a workflow file):")
    for kind in registry.kinds().values():
        print(f"  {kind.name:<19} {kind.summary} [{kind.run.partition(':')[0]}]")
    return 0


def cmd_list(args) -> int:
    """The workflows in workflows/: name, kind, description."""
    for path in sorted(WORKFLOWS.glob("*.toml")):
        raw = tomllib.loads(path.read_text())
        print(f"{path.stem:<20} {raw.get('kind', registry.DEFAULT_KIND):<19} {raw.get('description', '')}")
    return 0


def cmd_build(args) -> int:
    """Everything a run writes before it runs (structure, deck, run.sh, summary.json); no run."""
    spec = registry.load_spec(workflow_path(args.workflow), args.set)
    registry.get(spec.kind).build_workflow(spec, _out_folder(args.out), say=_say)
    return 0


def _out_folder(path: str) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise SpecError("--out", str(out), "exists and is not a folder")
    return out


def cmd_run(args) -> int:
    from opalflow.lammps.engine import EngineError

    out = _out_folder(args.out)
    if args.resume:
        spec = registry.spec_from_dict(_run_json(out, "--resume")["spec"])
    elif args.workflow is None:
        raise SpecError("workflow", None, "give a workflow file or name (or --resume with --out)")
    else:
        spec = registry.load_spec(workflow_path(args.workflow), args.set)
    if args.np < 1:
        raise SpecError("--np", args.np, "must be >= 1")
    if args.suffix:
        from opalflow.lammps.engine import lammps_info

        usable = lammps_info()["accelerators"]
        if args.suffix not in usable:
            raise SpecError("--suffix", args.suffix, f"this LAMMPS build offers {', '.join(usable) or 'none'}")
    try:
        summary = registry.get(spec.kind).run_workflow(spec, out, np_=args.np, resume=args.resume, say=_say,
                                                        suffix=args.suffix)
    except EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(f"run folder kept: {out}", file=sys.stderr)
        return 1
    print(f"{summary['headline']}, {summary['wall_s']:.1f} s -> {out}/report.md")
    return 0


def cmd_check(args) -> int:
    """A short run of the scene's real deck judged for numerical stability (exit 1 if unstable)."""
    if args.steps < 100:
        raise SpecError("--steps", args.steps, "must be >= 100")
    if not 0 < args.timestep_factor <= 100:
        raise SpecError("--timestep-factor", args.timestep_factor, "must be in (0, 100]")
    if args.strain is not None and not 0 < args.strain <= 0.9:
        raise SpecError("--strain", args.strain, "must be in (0, 0.9] (compress the sample this far)")
    spec = registry.load_spec(workflow_path(args.workflow), args.set)
    summary = registry.get(spec.kind).check_workflow(spec, _out_folder(args.out), say=_say, steps=args.steps,
                                                     timestep_factor=args.timestep_factor, bisect=args.bisect,
                                                     strain=args.strain)
    print(f"{summary['headline']} -> {args.out}/stability.md")
    return 0 if summary["passed"] else 1


def _run_json(out: Path, field: str) -> dict:
    """The run.json of a prepared run folder."""
    path = out / "run.json"
    if not path.exists():
        raise SpecError(field, str(out), "no run.json: this folder holds no prepared run")
    try:
        info = json.loads(path.read_text())
        info["spec"]["kind"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise SpecError(field, str(out), f"run.json is damaged ({type(exc).__name__}: {exc}); build the "
                        "folder again") from None
    return info


def cmd_analyze(args) -> int:
    out = Path(args.folder)
    kind = _run_json(out, "folder")["spec"].get("kind", registry.DEFAULT_KIND)
    summary = registry.get(kind).analyze_folder(out)
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
    c = sub.add_parser("check", help="numerical stability of a bonded-particle scene: a short run of its deck")
    c.add_argument("workflow", help="workflow file or name in workflows/")
    c.add_argument("--out", required=True, help="folder for the check's runs, stability.json and stability.md")
    c.add_argument("--steps", type=int, default=3000, help="time steps of each short run (default 3000)")
    c.add_argument("--timestep-factor", type=float, default=1.0,
                   help="run at this multiple of the deck's time step (3: a deliberately unstable run)")
    c.add_argument("--strain", type=float, default=None,
                   help="instead of --steps, run until the plate has compressed the sample this far (e.g. 0.5)")
    c.add_argument("--bisect", action="store_true", help="also find the largest stable time step by bisection")
    c.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    c.set_defaults(func=cmd_check)
    a = sub.add_parser("analyze", help="analyze a run folder's LAMMPS output (e.g. after bash run.sh)")
    a.add_argument("folder")
    a.set_defaults(func=cmd_analyze)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise
        print(f"error: cannot write {exc.filename or 'a result file'}: {exc.strerror}; files written before "
              "are intact (every result is written under a temporary name, then renamed)", file=sys.stderr)
        return 1
