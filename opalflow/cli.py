"""Command line: ``python -m opalflow info | list | build | run | check | analyze | status | plan | job | regress``: each verb parses its
arguments and calls the Python API of the same name (:mod:`opalflow.api`); what each kind does comes from
:mod:`opalflow.registry`.  Bad input: one line, exit 2; a failed LAMMPS run: its log tail, exit 1; Ctrl-C:
one line saying where it stopped and how to resume, exit 130 (SIGTERM: the same, exit 143); a closed pipe
(``list | head``): quiet, exit 0."""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys

from opalflow import STARTED, api, registry
from opalflow.spec import InputError
from opalflow.store import RESULTS, SUMMARY
from opalflow.version import __version__


def cmd_info(args) -> int:
    from opalflow.lammps.engine import accelerator_args

    facts = api.info()
    info = facts.lammps
    print(f"opalflow {facts.opalflow_version}")
    where = f"OPALFLOW_LAMMPS={info.prefix}" if info.prefix else "the installed lammps module"
    print(f"LAMMPS {info.version} (Python module {info.module}: {where})")
    for pkg, present in info.reported.items():
        backends = f" ({', '.join(info.kokkos_backends)})" if pkg == "KOKKOS" and present else ""
        print(f"  {pkg:<9} {'yes' if present else 'no'}{backends}")
    print(f"accelerators usable: {', '.join(info.accelerators) or 'none'}"
          f" (GPU device: {'yes' if info.has_gpu_device else 'no'}; --suffix kk runs with "
          f"{' '.join(accelerator_args('kk', gpu=info.has_gpu_device))})")
    print(f"MPI launcher: {info.mpi_launcher or 'not found'}")
    print(f"lmp executable: {info.lmp or 'not found'}")
    print(f"LIGGGHTS: {info.liggghts or 'not found'}")
    print("workflow kinds (kind = ... in a workflow file):")
    for kind in registry.kinds().values():
        print(f"  {kind.name:<19} {kind.summary} [{kind.run.partition(':')[0]}]")
    return 0


def cmd_list(args) -> int:
    """The workflows in workflows/: name, kind, description."""
    for w in api.workflows():
        print(f"{w.name:<20} {w.kind:<19} {w.description}")
    return 0


def cmd_build(args) -> int:
    """Everything a run writes before it runs (structure, deck, run.sh, summary.json); no run."""
    api.build(args.workflow, args.out, set=args.set)
    return 0


def cmd_run(args) -> int:
    from opalflow.lammps.engine import EngineError
    from opalflow.runs.record import command_run

    command_run(args.out, STARTED)

    try:
        result = api.run(args.workflow, args.out, set=args.set, np=args.np, resume=args.resume, suffix=args.suffix,
                         executor=args.executor)
    except EngineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print(f"run folder kept: {args.out}", file=sys.stderr)
        return 1
    print(f"{result['headline']}, {result['wall_s']:.1f} s -> {args.out}/report.md")
    return 0


def cmd_check(args) -> int:
    """A short run of the scene's real deck judged for numerical stability (exit 1 if unstable)."""
    check = api.check(args.workflow, args.out, set=args.set, steps=args.steps, timestep_factor=args.timestep_factor,
                      strain=args.strain, bisect=args.bisect)
    print(f"{check.headline} -> {args.out}/stability.md")
    return 0 if check.passed else 1


def cmd_job(args) -> int:
    """One job folder (its run.json), as a SLURM array task runs it: exit 0 finished or requeued, 1 failed."""
    from opalflow.runs.jobs import run_job

    got = run_job(args.folder, args.np, args.threads)
    if got.state == "failed":
        print(f"error: {got.error}\n{got.log_tail}", file=sys.stderr)
        return 1
    print(got.summary.get("headline", "done") if got.ok else got.state)
    return 0


def cmd_status(args) -> int:
    """Jobs of a study folder (or one run folder): pending / running / finished / failed, progress, time left."""
    from opalflow.runs.status import status_lines

    for line in status_lines(args.folder, tail=args.tail):
        print(line)
    return 0


def cmd_plan(args) -> int:
    """Predicted core-hours, memory and time per job, and the SLURM resources to ask for."""
    from opalflow.runs.plan import plan, plan_lines

    spec = api.load_workflow(args.workflow, args.set)
    p = plan(spec, ranks=args.np, sample=args.sample, against=args.measured,
             say=lambda m: print(m, file=sys.stderr, flush=True))
    for line in plan_lines(p):
        print(line)
    return 0


def cmd_analyze(args) -> int:
    result = api.analyze(args.folder)
    print(f"{result['headline']} -> {args.folder}/report.md")
    return 0


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a shutdown): stops the run as Ctrl-C does (restart files kept, lock released)."""


def _terminate(signum, frame):
    raise Terminated()


def cmd_regress(args) -> int:
    """The workflows' outputs against data/regression/: a table per reference, exit 1 on a regression."""
    import shutil
    import time

    from opalflow import regress

    t = time.perf_counter()
    checks, out = regress.regress(args.names, out=args.out, fast=args.fast, update=args.why if args.update else None,
                                  say=lambda m: print(m, flush=True))
    failed = any(c.failed for c in checks) and not args.update
    if args.update:
        print(f"regress --update: {len({c.name for c in checks})} references rewritten in data/regression/ ({args.why})")
    else:
        print("\n".join(regress.verdict_lines(checks, out, time.perf_counter() - t)))
    if not failed and args.out is None:
        shutil.rmtree(out, ignore_errors=True)
    return 1 if failed else 0


def interrupted(args, exc: KeyboardInterrupt, terminated: bool = False) -> str:
    """The one line Ctrl-C (or SIGTERM) prints: where the run stopped and how to go on; the resume line only
    where a restart file exists to resume from."""
    step = getattr(exc, "step", None)
    what = "terminated (SIGTERM)" if terminated else "interrupted"
    where = f"{what} at step {step}" if step is not None else what
    out = getattr(args, "out", None)
    if args.command != "run" or out is None:
        return where
    from opalflow.runs.status import how_to_go_on

    return f"{where}; {how_to_go_on(out)}"


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors in one line, as every other refusal (argparse prints the usage block first):
    ``error: argument --set: expected one argument (python -m opalflow build --help)``, exit 2."""

    def error(self, message):
        self.exit(2, f"error: {message} ({self.prog} --help)\n")


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m opalflow", description=__doc__)
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
    r = sub.add_parser("run", help=f"build, run LAMMPS, analyze: {RESULTS}, {SUMMARY}, report.md, plots")
    r.add_argument("workflow", nargs="?", default=None, help="workflow file or name (not with --resume)")
    r.add_argument("--out", required=True, help="run folder")
    r.add_argument("--np", type=int, default=1, help="MPI processes (runs 'lmp' under mpiexec)")
    r.add_argument("--resume", action="store_true", help="continue from the newest restart file in --out")
    r.add_argument("--suffix", choices=["omp", "kk", "gpu"], default=None,
                   help="accelerator styles (-sf) where the LAMMPS build has them; bpm bonds have none")
    r.add_argument("--executor", choices=["local", "dask", "slurm"], default=None,
                   help="where the runs go (else the workflow's [executor]): a study's jobs, or this run as one job")
    r.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    r.set_defaults(func=cmd_run)
    st = sub.add_parser("status", help="a study's jobs (or a run): pending, running, finished, failed, time left")
    st.add_argument("folder")
    st.add_argument("--tail", type=int, default=8, help="log lines shown per failed job (default 8)")
    st.set_defaults(func=cmd_status)
    pl = sub.add_parser("plan", help="core-hours, memory and time per job of a run or study, and its SLURM request")
    pl.add_argument("workflow", help="workflow file or name in workflows/")
    pl.add_argument("--np", type=int, default=1, help="MPI ranks per job")
    pl.add_argument("--sample", type=int, default=3, help="jobs whose structure is built (0: all; default 3)")
    pl.add_argument("--measured", default=None, help="a finished run or study folder: measured figures beside")
    pl.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    pl.set_defaults(func=cmd_plan)
    j = sub.add_parser("job", help="run one prepared job folder (what a SLURM array task runs)")
    j.add_argument("folder")
    j.add_argument("--np", type=int, default=1, help="MPI ranks")
    j.add_argument("--threads", type=int, default=1, help="BLAS/OpenMP threads of the job (default 1)")
    j.set_defaults(func=cmd_job)
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
    g = sub.add_parser("regress", help="run workflows and compare their outputs with data/regression/ (exit 1 on a "
                                           "regression)")
    g.add_argument("names", nargs="*", help="references (default: all; see data/regression/)")
    g.add_argument("--fast", action="store_true", help="only the references that run in under 30 s here")
    g.add_argument("--out", default=None, help="folder for the runs (default: a temporary one, kept on failure)")
    g.add_argument("--update", action="store_true", help="rewrite the stored values with this run's (needs --why)")
    g.add_argument("--why", default="", help="the reason for --update, recorded in the reference's history")
    g.set_defaults(func=cmd_regress)
    a = sub.add_parser("analyze", help="analyze a run folder's LAMMPS output (e.g. after bash run.sh)")
    a.add_argument("folder")
    a.set_defaults(func=cmd_analyze)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        code = args.func(args)
        sys.stdout.flush()           # here, where a closed pipe is caught, not at the interpreter's exit
        return code
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated) or isinstance(exc.__context__, Terminated)
        print(interrupted(args, exc, terminated), file=sys.stderr)
        return 128 + signal.SIGTERM if terminated else 130
    except BrokenPipeError:
        # the reader went away (``list | head``): no traceback; Python's exit flush must not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR):
            # a folder or file this user cannot use: theirs to change, as bad input is
            print(f"error: {exc.filename or 'a file'}: {exc.strerror}; choose a folder you can write to (or make "
                  "it writable)", file=sys.stderr)
            return 2
        if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise
        print(f"error: cannot write {exc.filename or 'a result file'}: {exc.strerror}; files written before "
              "are intact (every result is written under a temporary name, then renamed)", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)
