"""Executors: where many jobs run.  Each takes job folders (prepared by :mod:`opalflow.runs.jobs`) and
returns each one's outcome; a job's result lives in its folder, so the executor adds no state of its own
and a rerun through any executor does only what is missing.

- :class:`LocalExecutor`: spawned processes on this machine, one per job (no server).
- :class:`DaskExecutor`: any ``distributed`` scheduler (``executor.address``), or an embedded LocalCluster.
- :class:`SlurmExecutor`: one SLURM job array per call (``sbatch --array=0-N%workers``); the array's
  script (``slurm/array-*.sh`` in the study folder) is plain bash a user can read and resubmit.  Each task
  runs ``python -m opalflow job FOLDER``; a task signalled before its time limit writes a restart file and
  requeues itself.  Completion is read from the job folders; ``squeue`` only tells which tasks are still
  queued, and a controller that does not answer for a while (restarted) is waited for.
"""
from __future__ import annotations

import functools
import multiprocessing
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from multiprocessing.connection import wait
from pathlib import Path

from opalflow.runs.jobs import STOP_NOTE, Outcome, file_tail, job_record, outcome, run_job, settle
from opalflow.runs.spec import ExecutorSpec
from opalflow.spec import InputError

Collected = tuple[str, Outcome]          # (job folder, what it came to)


class LocalExecutor:
    """``workers`` spawned processes on this machine (0: cores / ranks per job)."""

    name = "local"

    def __init__(self, spec: ExecutorSpec, np_: int = 1):
        self.np, self.threads = np_, spec.cpus_per_rank
        self.workers = spec.workers or max(1, (os.cpu_count() or 1) // (np_ * spec.cpus_per_rank))

    def run(self, folders: list[str], say: Callable[[str], None]) -> Iterator[Collected]:
        workers = max(1, min(self.workers, len(folders)))
        # a fresh spawned process per job, one worker too: its peak memory is its own (its record), nothing leaks
        # to the next job, and a process that dies (killed, out of memory) fails its job alone, the others run on
        # (in a ProcessPoolExecutor it broke the pool, and the study with it).  Was: one worker ran its jobs in
        # the study's own process, whose freed memory stayed with it: the d = 15 nm porosity study's process
        # reached 19.90 GiB by its fourth job (the largest job alone 17.80), and each job's recorded peak was the
        # study's so far (two jobs of 15.93 GiB to the last digit)
        spawn = multiprocessing.get_context("spawn")
        waiting, running = list(folders), {}
        main = threading.current_thread() is threading.main_thread()
        # the study killed (SIGTERM: kill, a scheduler) stops its jobs too, as Ctrl-C does (measured: a study's
        # process killed left its two jobs running, one holding its folder's lock against the next study)
        before = signal.getsignal(signal.SIGTERM) if main else None
        if main:
            signal.signal(signal.SIGTERM, functools.partial(_on_term, before))
        try:
            while waiting or running:
                while waiting and len(running) < workers:
                    proc = spawn.Process(target=run_job, args=(waiting[0], self.np, self.threads))
                    proc.start()
                    running[proc.sentinel] = (proc, waiting.pop(0))
                for sentinel in wait(list(running)):
                    proc, folder = running.pop(sentinel)
                    proc.join()
                    yield folder, ended(folder, proc.exitcode)
        finally:
            for proc, _ in running.values():          # the study stopped: its jobs asked to stop (a restart file
                proc.terminate()                      # where their method writes one), then ended
            for proc, _ in running.values():
                proc.join(TERM_GRACE_S)
                if proc.is_alive():
                    proc.kill()
            if main:
                signal.signal(signal.SIGTERM, before)


#: seconds a job has to stop after its study was stopped (SIGTERM), before it is killed
TERM_GRACE_S = 30.0


def _on_term(before, signum, frame) -> None:
    """The study killed: its jobs are stopped as it leaves (:meth:`LocalExecutor.run`'s ``finally``); the handler
    it had before says how it ends (the command line's: its one line, exit 143), else exit 128 + SIGTERM."""
    if callable(before):
        before(signum, frame)
    raise SystemExit(128 + signum)


def ended(folder: str, exitcode: int) -> Outcome:
    """The outcome of a job whose process has ended: what its folder holds, or failed where the process died
    without writing it (a signal: killed, out of memory)."""
    got = outcome(folder)
    if got.state in ("finished", "failed", "requeued") or exitcode == 0:
        return got
    how = f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
    error = f"its process ended by {how} while it ran (killed, or out of memory); run the study again to retry it"
    settle(Path(folder), "failed", error=error)
    return Outcome("failed", str(folder), error=error, log_tail=got.log_tail)


class DaskExecutor:
    """Jobs as tasks of a Dask cluster: the scheduler at ``address``, else the ``distributed.Client`` this
    process already has (made by the user), else a LocalCluster of ``workers`` single-threaded worker
    processes started here (and closed after)."""

    name = "dask"

    def __init__(self, spec: ExecutorSpec, np_: int = 1):
        self.spec, self.np = spec, np_

    def run(self, folders: list[str], say: Callable[[str], None]) -> Iterator[Collected]:
        try:
            from distributed import Client, LocalCluster, as_completed as dask_completed
        except ImportError:
            raise InputError("executor.type = 'dask': the 'distributed' package is not installed "
                             "(pip install distributed)") from None
        cluster, own = None, True
        if self.spec.address:
            client = Client(self.spec.address)
        elif _default_client() is not None:          # a Client the user made in this process (Python API)
            client, own = _default_client(), False
        else:
            workers = self.spec.workers or max(1, (os.cpu_count() or 1) // self.np)
            cluster = LocalCluster(n_workers=min(workers, len(folders)), threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=40)
            client = Client(cluster)
        say(f"dask: {client.scheduler.address if client.scheduler else self.spec.address}, "
            f"{len(client.scheduler_info().get('workers', {}))} workers")
        try:
            futures = {client.submit(run_job, f, self.np, self.spec.cpus_per_rank, pure=False,
                                     key=f"opalflow-{Path(f).name}-{time.time_ns()}"): f for f in folders}
            for fut in dask_completed(futures):
                yield futures[fut], fut.result()
        finally:
            if own:
                client.close()
            if cluster is not None:
                cluster.close()


def _default_client():
    from distributed import default_client

    try:
        return default_client()
    except ValueError:
        return None


class SlurmExecutor:
    """One SLURM job array per call; see the module docstring."""

    name = "slurm"

    def __init__(self, spec: ExecutorSpec, np_: int = 1):
        self.spec, self.np = spec, np_
        if not shutil.which("sbatch"):
            raise InputError("executor.type = 'slurm': no sbatch on PATH (bash scripts/local-slurm.sh start makes "
                             "a one-node SLURM on this machine)")

    def script(self, root: Path, listing: Path, n: int) -> str:
        """The array's batch script: one task per line of ``listing``."""
        s = self.spec
        name = re.sub(r"[^A-Za-z0-9_.-]", "_", root.name)[:60]
        lines = ["#!/usr/bin/env bash", f"#SBATCH --job-name=opalflow-{name}",
                 f"#SBATCH --array=0-{n - 1}" + (f"%{s.workers}" if s.workers else ""),
                 f"#SBATCH --ntasks={self.np}", f"#SBATCH --cpus-per-task={s.cpus_per_rank}",
                 f"#SBATCH --mem={max(1, round(s.mem_gb * 1024))}M", f"#SBATCH --time={s.time_min}",
                 f"#SBATCH --output={root}/slurm/%A_%a.out", "#SBATCH --open-mode=append",
                 "#SBATCH --requeue", f"#SBATCH --signal=B:USR1@{s.signal_s}"]
        if s.partition:
            lines.append(f"#SBATCH --partition={s.partition}")
        if s.account:
            lines.append(f"#SBATCH --account={s.account}")
        lines += ["# written by opalflow: task i runs the job folder on line i+1 of the listing; a task signalled",
                  "# before its time limit writes a restart file and requeues itself (scontrol requeue)",
                  "set -euo pipefail",
                  f'folder=$(sed -n "$((SLURM_ARRAY_TASK_ID + 1))p" {shlex.quote(str(listing))})',
                  "# SLURM's USR1 may come while Python is still starting (its default would kill the job): the job",
                  "# starts with USR1 ignored, this shell notes the signal in the folder and passes it on, and the job",
                  "# reads the note once its own handler is in place",
                  f'rm -f "$folder/{STOP_NOTE}"',
                  "trap '' USR1",
                  f'{shlex.quote(sys.executable)} -m opalflow job "$folder" --np {self.np} '
                  f'--threads {s.cpus_per_rank} &',
                  "job=$!",
                  f"""trap 'touch "$folder/{STOP_NOTE}"; kill -USR1 "$job" 2> /dev/null || true' USR1""",
                  'while true; do wait "$job" && exit 0 || rc=$?; kill -0 "$job" 2> /dev/null || exit "$rc"; done',
                  ""]
        return "\n".join(lines)

    def run(self, folders: list[str], say: Callable[[str], None]) -> Iterator[Collected]:
        first = Path(folders[0]).resolve()
        root = first.parent.parent if first.parent.name == "jobs" else first     # a study's, or one run's
        (root / "slurm").mkdir(exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        listing = root / "slurm" / f"jobs-{stamp}.txt"
        listing.write_text("".join(f"{Path(f).resolve()}\n" for f in folders))
        script = root / "slurm" / f"array-{stamp}.sh"
        script.write_text(self.script(root, listing, len(folders)))
        res = _slurm(["sbatch", "--parsable", str(script)])
        if res.returncode:
            why = "sbatch refused the array: " + "; ".join(x.strip() for x in res.stderr.strip().splitlines())
            for f in folders:                    # status shows the refusal, not a job pending forever
                settle(Path(f), "failed", error=f"not submitted ({why}); run the study again to submit it")
            raise InputError(f"executor.type = 'slurm': {why}")
        array = res.stdout.strip().split(";")[0]
        with open(root / "slurm" / "arrays.txt", "a") as f:      # for status and for scancel by hand
            f.write(f"{array} {len(folders)} {script.name}\n")
        say(f"slurm: submitted array {array} ({len(folders)} tasks) with {script}")
        yield from self._wait(array, folders, say, root / "slurm")

    def _wait(self, array: str, folders: list[str], say, outputs: Path) -> Iterator[Collected]:
        left = {str(Path(f).resolve()): k for k, f in enumerate(folders)}
        missing: dict[str, int] = {}
        said: dict[str, float] = {}             # the session after which each requeued task was announced
        quiet_since = None
        while left:
            for f in list(left):
                rec = job_record(f)
                state = rec.state if rec is not None else "pending"
                if state in ("finished", "failed"):
                    del left[f]
                    yield f, outcome(f)
                elif state == "requeued" and said.get(f) != rec.attempted:
                    said[f] = rec.attempted
                    task = rec.sessions[-1].slurm_job if rec.sessions and rec.sessions[-1].slurm_job else array
                    say(f"slurm: task {task} requeued itself from its restart file; SLURM "
                        "starts it again once its job credential has expired (AuthInfo cred_expire, 120 s by "
                        "default)")
            if not left:
                return
            queued = _queued(array)
            if queued is None:                       # the controller does not answer: wait for it
                quiet_since = quiet_since or time.time()
                if time.time() - quiet_since > 600:
                    raise InputError(f"executor.type = 'slurm': the controller has not answered for 10 minutes; "
                                     f"array {array} may still run: rerun the study later to collect it")
            else:
                quiet_since = None
                for f, k in list(left.items()):
                    rec = job_record(f)
                    gone = k not in queued and (rec is None or rec.state not in ("finished", "failed"))
                    missing[f] = missing.get(f, 0) + 1 if gone else 0
                    # absent from the queue for three polls and 5 s: cancelled, killed or out of time (a task
                    # that just ended or is being requeued shows up again or settles its folder first)
                    if missing[f] >= 3 and missing[f] * self.spec.poll_s >= 5:
                        del left[f]
                        got = outcome(f)
                        got.state, got.error = "failed", (f"SLURM task {array}_{k} ended without a result (cancelled, "
                                                          f"killed or out of time; {got.error}); a rerun continues it")
                        got.log_tail = got.log_tail or file_tail(outputs / f"{array}_{k}.out")
                        yield f, got
            time.sleep(self.spec.poll_s)


def _slurm(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60)


def _queued(array: str) -> set[int] | None:
    """Task indices of the array still pending or running (None: the controller did not answer)."""
    try:
        res = _slurm(["squeue", "-h", "-r", "-j", array, "-o", "%K %T"])
    except subprocess.TimeoutExpired:
        return None
    if res.returncode:
        if "Invalid job id" in res.stderr:
            return set()
        return None
    out = set()
    for line in res.stdout.split("\n"):
        words = line.split()
        if len(words) == 2 and words[0].isdigit() and words[1] not in ("COMPLETED", "FAILED", "CANCELLED", "TIMEOUT"):
            out.add(int(words[0]))
    return out


EXECUTORS = {"local": LocalExecutor, "dask": DaskExecutor, "slurm": SlurmExecutor}


def executor(spec: ExecutorSpec, np_: int = 1):
    """The executor the spec names."""
    return EXECUTORS[spec.type](spec, np_)


def run_jobs(jobs, root: Path, ex: ExecutorSpec | None = None, *, np_: int = 1,
             say: Callable[[str], None] = print) -> dict[str, Outcome]:
    """Run every unfinished job of ``jobs`` (:class:`opalflow.runs.jobs.Job`) through the executor ``ex``
    (local by default) and return label -> :class:`opalflow.runs.jobs.Outcome` (finished with its result,
    failed with its reason and log tail).  Finished jobs are read from their folders."""
    from opalflow.runs.jobs import prepare

    ex = ex or ExecutorSpec()
    root = Path(root)
    done, todo = prepare(jobs, root)
    say(f"{len(jobs)} jobs: {len(done)} finished before, {len(todo)} to run ({ex.type} executor)")
    results = {j.label: Outcome.finished(j.folder(root).resolve(), j.spec.kind, done[j.label])
               for j in jobs if j.label in done}
    if todo:
        labels = {str(j.folder(root).resolve()): j.label for j in todo}
        t0 = time.perf_counter()
        for n, (folder, got) in enumerate(executor(ex, np_).run(list(labels), say), 1):
            label = labels[str(Path(folder).resolve())]
            results[label] = got
            say(f"job {label} {'done' if got.ok else got.state.upper() + ': ' + got.error} "
                f"({n}/{len(todo)}, {time.perf_counter() - t0:.0f} s)")
    return {j.label: results[j.label] for j in jobs}
